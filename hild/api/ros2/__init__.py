"""ROS 2 over Zenoh (rmw_zenoh's wire protocol): the daemon as a ros2_control-like node, no ROS install needed.

The only room that imports ``rosbags`` (CDR and RIHS01 type hashes) and ``xxhash`` (GIDs). ``definitions`` holds
the message types rosbags lacks, ``types`` the typestore, ``wire`` the key layout, attachment and liveliness
tokens, ``face`` the node's plumbing and its topics, ``controller_manager`` (list, switch), ``lifecycle`` (load,
configure, unload, reload, types) and ``hardware`` the controller manager's services, ``parameters`` the six
parameter services of the manager (``manager_parameters``, ``params_files``) and of each controller's node,
``parameter_values`` their value conversions, ``follow_joint_trajectory`` a joint_trajectory controller's action
(docs/ros2.md).
"""
