"""
The primitive baseline of the physics benchmark: one box per view, grasped from above.

What ROS's ``simple_grasping`` does with a tabletop object, on the view's segmented cloud: fit the
object's minimum-volume box (:func:`mvbb_ros.geometry.boxfit.fit.minimum_bounding_box`) to the
cloud in the world frame (z up, table top z = 0), take the box axis closest to vertical as its
height and the other two, made horizontal, as its sides. The rule (:func:`primitive_grasps`):

* the hand comes straight down (approach = world -z) over the box's centre;
* it closes across the narrowest horizontal side first, then across the other side; a side
  wider than the hand's opening (measured as the cloud's extent along it) gives no grasp;
* the fingertips go :data:`FINGER_DEPTH` below the cloud's top, or half its height when it is
  lower than twice that, never closer than :data:`TABLE_CLEARANCE` to the table top.
"""

from __future__ import annotations

from mvbb_ros.arrays import FloatArray
from mvbb_ros.evaluation.physics.views import grasp_matrix
from mvbb_ros.geometry.boxfit.fit import minimum_bounding_box
import numpy as np
from numpy.typing import ArrayLike

#: How far below the object's top the fingertips go, metres.
FINGER_DEPTH = 0.03
#: The fingertips stay this far above the table top, metres.
TABLE_CLEARANCE = 0.01


def primitive_grasps(world_points: ArrayLike, opening: float) -> list[FloatArray]:
    """
    Return the primitive baseline's grasp poses (4x4, world frame), best first.

    :param world_points: (N, 3) segmented object points in the world frame (z up, metres).
    :param opening: the hand's largest opening, metres.
    :return: at most two poses (narrowest side first); none when both sides exceed `opening`.
    """
    points = np.asarray(world_points, dtype=np.float64).reshape(-1, 3)
    if len(points) < 4:
        return []
    box = minimum_bounding_box(points)
    vertical = int(np.argmax(np.abs(box.rotation[2, :])))
    sides = []
    for axis in range(3):
        if axis == vertical:
            continue
        direction = box.rotation[:, axis].copy()
        direction[2] = 0.0
        norm = float(np.linalg.norm(direction))
        if norm < 1e-6:
            continue
        direction /= norm
        along = points @ direction
        sides.append((float(along.max() - along.min()), direction))
    sides.sort(key=lambda side: side[0])
    top = float(points[:, 2].max())
    height = top - max(float(points[:, 2].min()), 0.0)
    tip_z = max(top - min(FINGER_DEPTH, height / 2.0), TABLE_CLEARANCE)
    center = np.array([box.center[0], box.center[1], tip_z])
    return [
        grasp_matrix(center, (0.0, 0.0, -1.0), direction)
        for width, direction in sides
        if width <= opening
    ]
