"""
Single views of an object resting where the physics engine settled it, for the physics benchmark.

The object (:class:`~mvbb_ros.evaluation.physics.objects.PhysicsObject`, its mesh in its own frame)
rests on the table in the pose :func:`~mvbb_ros.evaluation.physics.trial.settle` gave it (world
frame: z up, table top z = 0, metres). :func:`physics_views` renders it with the project's depth
camera (:mod:`mvbb_ros.evaluation.camera`) from seeded random viewpoints as
:func:`mvbb_ros.evaluation.views.single_views` does: 30-70 degrees above the table, 0.5-1.0 m from
the centre of the object's bounding box, any azimuth, a 640 x 480, f = 525 px camera with
Kinect-like noise. Each :class:`PhysicsView` holds the segmented cloud (object pixels only), the
raw scene (object and the table around it), both float32 in the camera optical frame, the camera
pose and the up direction in the camera frame.

Grasp poses here are 4x4 matrices in the project's convention (README, "Grasp pose convention"):
the origin is the point between the fingertips, z the approach direction, y the closing
direction, x = y x z.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
import math
from typing import Any
import zlib

from mvbb_ros.arrays import Float32Array, FloatArray, IndexArray
from mvbb_ros.evaluation.camera import (
    camera_intrinsics,
    DEFAULT_HEIGHT,
    DEFAULT_WIDTH,
    DepthCamera,
    DepthNoise,
    image_window,
    KINECT_NOISE,
    orbit_pose,
)
from mvbb_ros.evaluation.views import table_mesh
import numpy as np
from numpy.typing import ArrayLike
import open3d as o3d

#: Viewpoint ranges: elevation above the table (degrees), distance from the box centre (metres).
ELEVATION_RANGE_DEG = (30.0, 70.0)
DISTANCE_RANGE = (0.5, 1.0)
#: The raw scene keeps the table this far around the object's footprint, metres.
SCENE_MARGIN = 0.10
#: Views whose segmented cloud has fewer points than this are drawn again.
MIN_VIEW_POINTS = 50
#: Label of the table in the rendered label image.
TABLE_LABEL = 1


def stable_seed(*parts: int | str) -> int:
    """Return a seed from names and numbers that does not depend on Python's hash salt."""
    return zlib.crc32(repr(parts).encode()) & 0x7FFFFFFF


def transform_points(pose: ArrayLike, points: ArrayLike) -> FloatArray:
    """Apply a 4x4 rigid transform to (..., 3) points."""
    matrix = np.asarray(pose, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ matrix[:3, :3].T + matrix[:3, 3]


def invert_pose(pose: ArrayLike) -> FloatArray:
    """Return the inverse of a 4x4 rigid transform."""
    matrix = np.asarray(pose, dtype=np.float64)
    inverse = np.eye(4)
    inverse[:3, :3] = matrix[:3, :3].T
    inverse[:3, 3] = -matrix[:3, :3].T @ matrix[:3, 3]
    return inverse


def grasp_matrix(center: ArrayLike, approach: ArrayLike, closing: ArrayLike) -> FloatArray:
    """
    Return the 4x4 grasp pose of fingertip centre `center`, `approach` and `closing` directions.

    z is the approach, y the closing direction made orthogonal to it, x = y x z.

    :raises ValueError: when the directions are zero or parallel.
    """
    z = np.asarray(approach, dtype=np.float64)
    z = z / np.linalg.norm(z)
    y = np.asarray(closing, dtype=np.float64)
    y = y - (y @ z) * z
    norm = float(np.linalg.norm(y))
    if not norm > 1e-9:
        raise ValueError('grasp_matrix: the closing direction is parallel to the approach')
    y /= norm
    pose = np.eye(4)
    pose[:3, 0] = np.cross(y, z)
    pose[:3, 1] = y
    pose[:3, 2] = z
    pose[:3, 3] = np.asarray(center, dtype=np.float64)
    return pose


@dataclass(eq=False)
class PlacedObject:
    """
    An object resting on the table: its mesh in the world frame and the depth camera's scene.

    :ivar obj: the physics object (its mesh in its own frame).
    :ivar pose: (4, 4) world pose the engine settled it into.
    :ivar vertices: (V, 3) world-frame vertices, metres.
    :ivar triangles: (T, 3) vertex indices.
    """

    obj: Any
    pose: FloatArray
    vertices: FloatArray
    triangles: IndexArray
    _camera: DepthCamera | None = None

    @classmethod
    def place(cls, obj: Any, pose: ArrayLike) -> PlacedObject:
        """Put `obj` (``.vertices``, ``.triangles`` in its own frame) at the world `pose`."""
        matrix = np.asarray(pose, dtype=np.float64)
        return cls(
            obj,
            matrix,
            transform_points(matrix, obj.vertices),
            np.asarray(obj.triangles, dtype=np.intp),
        )

    @property
    def name(self) -> str:
        """Return the object's name."""
        return str(self.obj.name)

    @property
    def low(self) -> FloatArray:
        """Return the lower corner of the world-frame axis-aligned bounding box."""
        return self.vertices.min(axis=0)

    @property
    def high(self) -> FloatArray:
        """Return the upper corner of the world-frame axis-aligned bounding box."""
        return self.vertices.max(axis=0)

    @property
    def center(self) -> FloatArray:
        """Return the centre of the axis-aligned world bounding box: the cameras aim there."""
        return (self.low + self.high) / 2.0

    @property
    def mesh(self) -> o3d.geometry.TriangleMesh:
        """Return the object as an Open3D triangle mesh in the world frame."""
        return o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(self.vertices),
            o3d.utility.Vector3iVector(self.triangles.astype(np.int32)),
        )

    @property
    def camera(self) -> DepthCamera:
        """Return the depth camera's world: this object (label 0) on the table (label 1)."""
        if self._camera is None:
            self._camera = DepthCamera([self.mesh, table_mesh()])
        return self._camera

    def contains(self, points: ArrayLike, margin: float) -> np.ndarray:
        """Tell which world points lie in the bounding box grown by `margin` metres."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.all((pts >= self.low - margin) & (pts <= self.high + margin), axis=1)


@dataclass(frozen=True, eq=False)
class PhysicsView:
    """
    One view of a resting object, as a robot's camera sees it.

    :ivar placed: the object on the table (world frame).
    :ivar index: the view's number for this object.
    :ivar points: (N, 3) float32 object points in the camera optical frame, metres.
    :ivar scene_points: (M, 3) float32 object and table points in the camera optical frame.
    :ivar camera_pose: (4, 4) T_world_camera.
    :ivar elevation_deg: camera elevation above the table, degrees.
    :ivar azimuth_deg: camera azimuth about the object, degrees.
    :ivar distance: camera distance from the object's bounding-box centre, metres.
    :ivar seed: seed of the view's sensor noise.
    """

    placed: PlacedObject
    index: int
    points: Float32Array
    scene_points: Float32Array
    camera_pose: FloatArray
    elevation_deg: float
    azimuth_deg: float
    distance: float
    seed: int

    @property
    def name(self) -> str:
        """``'<object>/<index>'``."""
        return f'{self.placed.name}/{self.index}'

    @property
    def up(self) -> FloatArray:
        """Return the world's +z in the camera frame: what a robot sets as ``up_direction``."""
        return self.camera_pose[2, :3].copy()

    def to_world(self, camera: ArrayLike) -> FloatArray:
        """Map camera-frame points (..., 3) to the world."""
        return transform_points(self.camera_pose, camera)

    def to_camera(self, world: ArrayLike) -> FloatArray:
        """Map world points (..., 3) into the camera optical frame."""
        return transform_points(invert_pose(self.camera_pose), world)

    def poses_to_world(self, poses: ArrayLike) -> FloatArray:
        """Map camera-frame 4x4 poses (..., 4, 4) to the world: T_world_camera @ pose."""
        return np.einsum('ij,...jk->...ik', self.camera_pose, np.asarray(poses, dtype=np.float64))


def _render(
    placed: PlacedObject, pose: FloatArray, noise: DepthNoise | None, seed: int
) -> tuple[Float32Array, Float32Array]:
    """Render the object and the table around it; return (object points, scene points)."""
    intrinsics = camera_intrinsics(DEFAULT_WIDTH, DEFAULT_HEIGHT)
    size = (DEFAULT_WIDTH, DEFAULT_HEIGHT)
    low = placed.low - [SCENE_MARGIN, SCENE_MARGIN, 0.0]
    high = placed.high + [SCENE_MARGIN, SCENE_MARGIN, 0.0]
    low[2] = min(low[2], 0.0)
    corners = np.array([[(low, high)[k >> i & 1][i] for i in range(3)] for k in range(8)])
    window = image_window(corners, pose, intrinsics, size)
    points, labels = placed.camera.render(
        pose, intrinsics, size, noise, np.random.default_rng(seed), window=window
    )
    scene = points[labels >= 0]
    # Keep only the table around the object, as a tabletop segmenter's crop would.
    world = transform_points(pose, scene)
    near = np.all((world[:, :2] >= low[:2]) & (world[:, :2] <= high[:2]), axis=1)
    return (
        np.ascontiguousarray(points[labels == 0]),
        np.ascontiguousarray(scene[near], dtype=np.float32),
    )


def physics_views(
    placed: PlacedObject,
    count: int,
    *,
    seed: int = 0,
    noise: DepthNoise | None = KINECT_NOISE,
    elevation_deg: tuple[float, float] = ELEVATION_RANGE_DEG,
    distance: tuple[float, float] = DISTANCE_RANGE,
) -> Iterator[PhysicsView]:
    """
    Render `count` single views of a resting object from seeded random viewpoints.

    Each camera looks at the centre of the object's bounding box from a distance and elevation
    drawn uniformly from the ranges and an azimuth uniform in [0, 360) degrees. Views whose
    segmented cloud has fewer than :data:`MIN_VIEW_POINTS` points are drawn again (at most
    ``10 * count`` draws in all).

    :param placed: the object on the table.
    :param count: how many views.
    :param seed: the seed; views depend on it and on the object's name only.
    :param noise: the sensor model (default Kinect-like); None for exact hits.
    :param elevation_deg: (low, high) elevation range, degrees.
    :param distance: (low, high) distance range, metres.
    """
    rng = np.random.default_rng(stable_seed(placed.name, seed))
    index = draws = 0
    while index < count and draws < 10 * max(count, 1):
        draws += 1
        elevation = float(rng.uniform(*elevation_deg))
        azimuth = float(rng.uniform(0.0, 360.0))
        radius = float(rng.uniform(*distance))
        pose = orbit_pose(placed.center, radius, azimuth, elevation)
        view_seed = stable_seed(placed.name, seed, index, draws)
        points, scene = _render(placed, pose, noise, view_seed)
        if len(points) < MIN_VIEW_POINTS:
            continue
        yield PhysicsView(
            placed, index, points, scene, pose, elevation, azimuth, radius, view_seed
        )
        index += 1


def view_frames(
    view: PhysicsView,
    count: int,
    *,
    drift: float = 0.0,
    noise: DepthNoise | None = KINECT_NOISE,
) -> Iterator[PhysicsView]:
    """
    Render the same view `count` times again, each with fresh sensor noise: a static scene.

    With `drift` (metres per frame), frame k's camera is moved k * `drift` along its image's x
    axis, so the object drifts slowly across the image as a slowly moving object would (the
    grasps, in the world frame, should stay where they were). Frame 0 is the view's own pose.
    """
    for frame in range(count):
        pose = np.array(view.camera_pose, dtype=np.float64)
        pose[:3, 3] += frame * drift * pose[:3, 0]
        frame_seed = stable_seed(view.placed.name, view.seed, 'frame', frame)
        points, scene = _render(view.placed, pose, noise, frame_seed)
        yield PhysicsView(
            view.placed,
            view.index,
            points,
            scene,
            pose,
            view.elevation_deg,
            view.azimuth_deg,
            view.distance,
            frame_seed,
        )


def wilson_interval(
    successes: int, trials: int, z: float = 1.959963984540054
) -> tuple[float, float]:
    """
    Return the Wilson score interval of a success rate (95 % with the default z).

    (0, 1) when there are no trials.

    :raises ValueError: when the counts are negative or successes exceed trials.
    """
    if trials < 0 or successes < 0 or successes > trials:
        raise ValueError(
            f'wilson_interval: need 0 <= successes <= trials, got {successes}/{trials}'
        )
    if trials == 0:
        return 0.0, 1.0
    p = successes / trials
    z2 = z * z
    centre = (p + z2 / (2.0 * trials)) / (1.0 + z2 / trials)
    half = (
        z * math.sqrt(p * (1.0 - p) / trials + z2 / (4.0 * trials * trials)) / (1.0 + z2 / trials)
    )
    # No successes (all successes) put the bound exactly at 0 (1), not a rounding error from it.
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == trials else min(1.0, centre + half)
    return low, high
