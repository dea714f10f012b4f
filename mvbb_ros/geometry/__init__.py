"""
Geometry: boxes, the minimum-volume box fit, fit-and-split, and grasp hypotheses.

numpy, scipy and numba kernels only: no ROS, no Open3D, no files. The modules in pipeline
order: :mod:`~mvbb_ros.geometry.box` (the value type), :mod:`~mvbb_ros.geometry.hull`,
:mod:`~mvbb_ros.geometry.rectangle` and :mod:`~mvbb_ros.geometry.search` (the parts of)
:mod:`~mvbb_ros.geometry.fit` (the minimum-volume box), :mod:`~mvbb_ros.geometry.split` (the
split measure theta), :mod:`~mvbb_ros.geometry.decomposition` (the fit-and-split tree) and
:mod:`~mvbb_ros.geometry.grasps` (face-approach grasps). Every default here is the paper's;
``docs/architecture.md`` says where the node's defaults differ.
"""

# First: every numba kernel of the package is cached with the stamp kernel_cache.py gives it,
# and compile_time clocks the compiles of the kernels that this package's modules compile.
from mvbb_ros import compile_time, kernel_cache  # noqa: F401
