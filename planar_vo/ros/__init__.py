"""The ROS 2 side: the node (`planar_vo.ros.node`, the only module importing rclpy) and the
duck-typed message conversions it shares with bag I/O (`planar_vo.ros.messages`, which imports
neither rclpy nor rosbags).

Import `planar_vo.ros.node` explicitly; this package does not, so that bag tools run without
ROS."""
