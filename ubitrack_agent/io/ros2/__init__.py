"""ROS 2 tf over rmw_zenoh (Jazzy and later): publish relations on /tf and /tf_static, and
read a robot's tf tree into the SRG (``docs/ros2.md``). Needs the ``ros2`` extra (rosbags)."""
