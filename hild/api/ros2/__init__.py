"""ROS 2 over Zenoh (rmw_zenoh's wire protocol): the daemon as a ros2_control-like node, no ROS install needed.

The only room that imports ``rosbags`` (CDR and RIHS01 type hashes) and ``xxhash`` (GIDs). ``definitions`` holds
the message types rosbags lacks, ``types`` the typestore, ``wire`` the key layout, attachment and liveliness
tokens, ``face`` the node's plumbing and its topics, ``manager`` the controller_manager services, ``action`` a
joint_trajectory controller's follow_joint_trajectory action (docs/ros2.md).
"""
