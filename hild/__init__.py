"""hild: a hardware-in-the-loop bridge daemon for robot arms.

What a user imports: the Python client (:mod:`hild.client`) and, to write a driver or a controller, the plugin
contracts beside it (:mod:`hild.hardware`, :mod:`hild.controller`, :mod:`hild.interfaces`, :mod:`hild.arrays`,
:mod:`hild.modes`, :mod:`hild.action`, :mod:`hild.plugins`); each lists its public names in ``__all__``. The
sub-packages are the processes' rooms (docs/architecture.md), not an interface.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("hild")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

__all__ = ["__version__"]
