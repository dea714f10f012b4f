"""Meshes, poses and the gripper that the evaluation's tests grasp with: a cube and an L."""

from __future__ import annotations

from dataclasses import dataclass

from mvbb_ros.evaluation.gripper import ParallelJawGripper
import numpy as np
import open3d as o3d

# A unit cube centred on the origin, grasped from above across its +-x faces by a gripper that
# opens 1.5 and reaches 0.6 deep: the palm stops on the top face (z = 0.5) and the fingers
# close at half a finger depth below it, z = 0.5 - 0.3 + retreat ... on the face centres' line.
CUBE_GRIPPER = ParallelJawGripper(max_width=1.5, finger_depth=0.6, finger_width=0.1, retreat=0.01)


@dataclass
class Pose:
    position: np.ndarray
    approach: np.ndarray
    closing: np.ndarray


def cube_mesh(side: float = 1.0) -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh.create_box(side, side, side)
    return mesh.translate((-side / 2, -side / 2, -side / 2))


def top_grasp(x: float = 0.0, y: float = 0.0, closing=(1.0, 0.0, 0.0)) -> Pose:
    return Pose(
        position=np.array([x, y, 1.5]),
        approach=np.array([0.0, 0.0, -1.0]),
        closing=np.asarray(closing, dtype=float),
    )


def l_shape_mesh() -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh.create_box(1.0, 0.3, 0.3)
    mesh += o3d.geometry.TriangleMesh.create_box(0.3, 0.3, 0.8).translate((0.0, 0.0, 0.3))
    return mesh.subdivide_midpoint(2)  # enough vertices for the decomposition's min_points
