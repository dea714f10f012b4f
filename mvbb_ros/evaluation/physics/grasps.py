"""
A primitive grasp from the object's box, for baselines and sanity checks of the trial.

:func:`top_down_grasp` is what a simple table-top grasper does with a known object (the
``simple_grasping`` idea): take the object's footprint rectangle (the smallest-area rectangle
around its vertices seen from above), come straight down over its centre and close across its
narrower side. It reads the whole mesh in its resting pose: it is a reference, not a contender
that sees only a view.
"""

from __future__ import annotations

import math

from mvbb_ros.arrays import FloatArray
from mvbb_ros.evaluation.physics.hand import FRANKA, Hand
from mvbb_ros.evaluation.physics.objects import PhysicsObject
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull

#: Lowest height (metres) of the fingertips above the table for a top-down grasp.
TABLE_CLEARANCE = 0.005


def footprint_rectangle(points_xy: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """
    Return the smallest-area rectangle around 2-D points: (centre (2,), axes (2, 2), sizes (2,)).

    The rectangle has a side along an edge of the points' convex hull (rotating calipers, every
    edge tried); the rows of `axes` are its unit side directions, `sizes` the lengths along them,
    the smaller first.
    """
    points = np.asarray(points_xy, dtype=np.float64)
    hull = points[ConvexHull(points).vertices]
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.arctan2(edges[:, 1], edges[:, 0])
    best: tuple[float, FloatArray, FloatArray, FloatArray] | None = None
    for angle in angles:
        axes = np.array([[math.cos(angle), math.sin(angle)], [-math.sin(angle), math.cos(angle)]])
        local = hull @ axes.T
        low, high = local.min(axis=0), local.max(axis=0)
        area = float(np.prod(high - low))
        if best is None or area < best[0]:
            best = (area, axes, low, high)
    assert best is not None
    _, axes, low, high = best
    centre = ((low + high) / 2.0) @ axes
    sizes = high - low
    order = np.argsort(sizes, kind='stable')
    return centre, axes[order], sizes[order]


def top_down_grasp(
    obj: PhysicsObject, object_pose: ArrayLike, hand: Hand = FRANKA, depth: float | None = None
) -> FloatArray:
    """
    Return the 4x4 world grasp pose of a top-down grasp across the footprint's narrower side.

    :param obj: the object.
    :param object_pose: its 4x4 world pose (resting on the table, top of the table z = 0).
    :param hand: the hand (its finger depth sets the default depth).
    :param depth: how far below the object's top the fingertips close (metres); default the
        finger depth less 1 cm. The fingertips stay :data:`TABLE_CLEARANCE` above the table.
    :return: the grasp pose (origin between the fingertips, z down, y across the narrower side).
    """
    pose = np.asarray(object_pose, dtype=np.float64)
    world = obj.vertices @ pose[:3, :3].T + pose[:3, 3]
    centre, axes, _ = footprint_rectangle(world[:, :2])
    reach = hand.finger_depth - 0.01 if depth is None else depth
    top = float(world[:, 2].max())
    closing = np.array([axes[0, 0], axes[0, 1], 0.0])
    approach = np.array([0.0, 0.0, -1.0])
    grasp = np.eye(4)
    grasp[:3, 0] = np.cross(closing, approach)
    grasp[:3, 1] = closing
    grasp[:3, 2] = approach
    grasp[:3, 3] = [centre[0], centre[1], max(top - reach, TABLE_CLEARANCE)]
    return grasp
