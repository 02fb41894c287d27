"""The recording room: episodes and the flight recorder on disk (docs/recording.md).

The cycle writes every cycle into the cycle log (``hild/crossing/cyclelog.py``); everything else about recording
runs here, never on the cycle:

- ``model``      what an episode is: its metadata, its files' names, ``Episode`` (rows + events read back)
- ``mcap_files`` episodes and black boxes as MCAP with ROS 2 message encoding (rosbag2's storage): writing in
                 chunks that are valid alone, reading back, ``recover`` (the ``mcap`` library); beside it
                 ``topics`` and ``cdr_templates`` (a row as the face's CDR and back), ``mcap_out`` /
                 ``mcap_scan`` (one MCAP written / read up to its damage), ``bag_metadata`` (metadata.yaml)
- ``frames``     which cycle a reader sampling at a fixed rate would have seen (zero-order hold)
- ``lerobot``    LeRobotDataset v3.0 export, frames resampled from the cycle log (``pyarrow``)
- ``swap``       a directory tree replaced all at once (the export's crash safety)
- ``recorder``   the client domain's handle: starts the recorder process, episodes, triggers the black box
- ``worker``     the recorder process: reads the cycle log, writes the files
- ``replay``     an episode's measured path sent back as one joint_trajectory goal, after the safety checks
- ``cli``        ``hild record export|view|recover|replay|list``

``mcap`` and ``pyarrow`` are imported in this room only; the CDR bytes and type hashes are the ROS 2 face's
(``hild.api.ros2.types``), so a recording carries exactly what the face publishes.
"""
