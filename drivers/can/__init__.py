"""CAN servo drives: pure codecs (`protocol`), firmware-faithful emulators (`emulator`) and host drivers.

python-can is imported only inside this package, so the rest of hild never depends on it.
"""
