"""A cdpr session on ROS 2's own wire: rmw_zenoh's key expressions, CDR payloads and graph tokens.

:mod:`cdpr.ros2.cdr` (the encoding), :mod:`cdpr.ros2.graph` (keys, liveliness tokens, type hashes,
attachments), :mod:`cdpr.ros2.messages` (the messages a session publishes and reads) and
:mod:`cdpr.ros2.topics` (which topics, from which of the session's messages) are pure; the ``ros2`` node
(``services/ros2/cdpr_ros2``) puts them on Zenoh and ``cdpr convert --to rosbag2`` in a bag. docs/ros2.md.
"""
