"""The ros2 service: a cdpr session on ROS 2's own Zenoh wire format (rmw_zenoh), docs/ros2.md."""
