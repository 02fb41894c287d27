"""Import a ros2_control robot (URDF/xacro + controller_manager YAML) as a hild config on the MuJoCo twin.

Entry points: :func:`hild.importers.ros2_control.importer.import_ros2_control` (Python) and
``hild import ros2-control`` (``cli.py``). Nothing is imported here, so registering the command stays cheap.
"""
