"""ROS 2 over Zenoh (rmw_zenoh's wire protocol): the daemon as a ros2_control-like node, no ROS install needed.

The only room that imports ``rosbags`` (CDR and RIHS01 type hashes). ``types`` holds the typestore and the
definitions rosbags lacks, ``wire`` the key layout, attachment and liveliness tokens, ``face`` what the daemon
offers under ros2_control's names (docs/ros2.md).
"""
