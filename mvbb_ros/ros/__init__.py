"""
ROS: the decomposer node, its messages, and bags. The only layer that imports rclpy or messages.

:mod:`~mvbb_ros.ros.decomposer` (the ``decomposer`` executable), :mod:`~mvbb_ros.ros.node` (its
node), :mod:`~mvbb_ros.ros.messages` (results to
MarkerArray and PoseArray), :mod:`~mvbb_ros.ros.encode` (points to PointCloud2),
:mod:`~mvbb_ros.ros.bag` (reading and writing bags), :mod:`~mvbb_ros.ros.offline` (`mvbb bag
process`), :mod:`~mvbb_ros.ros.bag_play` (`mvbb bag play`) and
:mod:`~mvbb_ros.ros.demo_graph` (the ROS side of `mvbb demo`).
"""
