"""
What the tests share: the repository's paths and shared data, shapes, and a real rclpy graph.

:mod:`support.data` (the repository root, the shared real data and skipping clearly without it,
the clouds the filter tests use), :mod:`support.shapes` (small synthetic clouds),
:mod:`support.ros_graph` (a node and its peers in a real rclpy graph on a private domain),
:mod:`support.cloud_source` (the publisher process that graph starts) and
:mod:`support.pointcloud2` (a point-by-point PointCloud2 reference codec). ``test/`` is on
pytest's ``pythonpath``, so tests import them as ``support.<module>``.
"""
