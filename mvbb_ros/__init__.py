"""
mvbb_ros: minimum-volume bounding box decomposition and grasp hypotheses.

The geometry is plain numpy/scipy and importable without ROS::

    from mvbb_ros import Box, minimum_bounding_box, decompose, grasp_hypotheses

Huebner, Ruthotto and Kragic, "Minimum Volume Bounding Box Decomposition for Shape Approximation
in Robot Grasping", ICRA 2008.
"""

from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition import decompose, Decomposition
from mvbb_ros.geometry.fit import minimum_bounding_box
from mvbb_ros.geometry.grasps import Grasp, grasp_hypotheses

__all__ = [
    'Box',
    'Decomposition',
    'Grasp',
    'decompose',
    'grasp_hypotheses',
    'minimum_bounding_box',
]
__version__ = '0.1.0'
