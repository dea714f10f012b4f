"""
Geometry: boxes, the minimum-volume box fit, fit-and-split, single views and grasps.

numpy, scipy and numba kernels only: no ROS, no Open3D, no files. :mod:`~mvbb_ros.geometry.box`
is the value type every part uses; the subsystems, each a subpackage, in pipeline order:

* :mod:`~mvbb_ros.geometry.boxfit`: the minimum-volume box of a point set;
* :mod:`~mvbb_ros.geometry.decomposition`: the split measure and the fit-and-split tree;
* :mod:`~mvbb_ros.geometry.views`: objects in one cloud and the hidden side of a single view;
* :mod:`~mvbb_ros.geometry.grasping`: face-approach grasps and their refinement on the points.

Every default here is the paper's; ``docs/architecture.md`` says where the node's defaults
differ.
"""

# First: every numba kernel of the package is cached with the stamp kernel_cache.py gives it,
# and compile_time clocks the compiles of the kernels that this package's modules compile.
from mvbb_ros import compile_time, kernel_cache  # noqa: F401
