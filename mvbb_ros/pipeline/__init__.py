"""
Pipeline: one cloud from message to boxes and grasps, and the settings of every step.

No rclpy here (messages are read duck-typed), so the node, the bag tools and the command line
share it: :mod:`~mvbb_ros.pipeline.decode` (PointCloud2 -> points),
:mod:`~mvbb_ros.pipeline.filtering` (crop, voxel, outliers), :mod:`~mvbb_ros.pipeline.process`
(the per-cloud function), :mod:`~mvbb_ros.pipeline.specs` (every tunable, its default and range)
and :mod:`~mvbb_ros.pipeline.settings` (the settings object they fill). Importing this package
imports none of them (the filters load Open3D).
"""

# First: every numba kernel of the package is cached with the stamp kernel_cache.py gives it,
# and compile_time clocks the compiles of the kernels that this package's modules compile.
from mvbb_ros import compile_time, kernel_cache  # noqa: F401
