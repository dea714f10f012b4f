"""
Single-view ground truth: whole meshes on a table, one partial view each, and real scans.

Issue 15's measuring instrument. Each shared mesh (:data:`TABLE_MODELS`) is turned upright
(its up axis to world +z by a proper rotation), scaled to metres, centred in x and y and set on
a table (resting on z = 0): a :class:`TableObject`. :func:`single_views` renders it with the
virtual depth camera (:mod:`mvbb_ros.evaluation.camera`) from random viewpoints 30-70 degrees
above the table, 0.5-1.0 m away, any azimuth, with Kinect-like noise and perfect segmentation
(only the object's pixels). A :class:`SingleView` holds what the node would receive (the cloud,
float32, metres, in the camera optical frame), what a robot would know (the camera pose and the
up direction in the camera frame) and the ground truth (the whole mesh), and measures boxes
(:mod:`mvbb_ros.evaluation.coverage`) and grasps (:mod:`mvbb_ros.evaluation.grasp_judge`)
against it. :meth:`SingleView.frame` renders the same view again with fresh sensor noise (for
steadiness).

:func:`real_scans` reads every real single-view scan of the shared ``scans`` folder as a cloud
whose viewpoint is its frame's origin (see there for the bunny range scans).

World frame: z up, the table top is z = 0, the object's footprint centre at the origin. All
lengths in metres. Everything is deterministic for a seed.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
import math
import os
from pathlib import Path
from typing import Any
import zlib

from mvbb_ros.arrays import cross, Float32Array, FloatArray, IndexArray
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
from mvbb_ros.evaluation.coverage import (
    box_metrics,
    BoxMetrics,
    convex_hull_volume,
    sample_surface,
)
from mvbb_ros.evaluation.grasp_judge import judge_grasps, PadGripper, simulated_epsilon, Verdicts
from mvbb_ros.evaluation.mesh import GraspTarget, load_mesh
from mvbb_ros.geometry.box import Box
import numpy as np
from numpy.typing import ArrayLike
import open3d as o3d
from scipy.spatial.transform import Rotation

#: Viewpoint ranges of :func:`single_views`: elevation above the table (degrees) and distance
#: from the object's bounding-box centre (metres).
ELEVATION_RANGE_DEG = (30.0, 70.0)
DISTANCE_RANGE = (0.5, 1.0)


@dataclass(frozen=True)
class TableModel:
    """
    How to stand one shared mesh on the table.

    :ivar name: short name (``'mug'``, ``'bunny'``, ...).
    :ivar file: the mesh file in the shared ``models`` folder.
    :ivar up: the model's up axis in its own frame.
    :ivar units: metres per model unit (0.001 for millimetres).
    :ivar height: when set, scale so the object is this tall (metres), instead of `units`.
    :ivar length: when set, scale so its longest extent is this (metres), instead of `units`.
    """

    name: str
    file: str
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    units: float = 1.0
    height: float | None = None
    length: float | None = None


_Y_UP = (0.0, 1.0, 0.0)

#: The shared meshes of the single-view benchmark: the six household objects (metres, z up), the
#: GraspIt! mug (mm, y up) and flask (mm, z up), Homer (unitless, y up: 0.20 m tall), the rubber
#: duck (unitless, y up: 0.12 m long) and the Stanford bunny (metres, y up, 0.155 m).
TABLE_MODELS: tuple[TableModel, ...] = (
    TableModel('bottle', 'household_bottle_mesh.ply'),
    TableModel('bread', 'household_bread_mesh.ply'),
    TableModel('can', 'household_can_mesh.ply'),
    TableModel('cereal', 'household_cereal_mesh.ply'),
    TableModel('lemon', 'household_lemon_mesh.ply'),
    TableModel('milk', 'household_milk_mesh.ply'),
    TableModel('mug', 'graspit_mug_mesh.ply', up=_Y_UP, units=0.001),
    TableModel('flask', 'graspit_flask_mesh.ply', units=0.001),
    TableModel('homer', 'homer_mesh.ply', up=_Y_UP, height=0.20),
    TableModel('duck', 'rubber_duck_mesh.ply', up=_Y_UP, length=0.12),
    TableModel('bunny', 'bunny_bun_zipper.ply', up=_Y_UP),
)
MODEL_BY_NAME: dict[str, TableModel] = {model.name: model for model in TABLE_MODELS}


def rotation_to_z(up: ArrayLike) -> FloatArray:
    """Return the proper rotation (3, 3) that turns the direction `up` onto +z (shortest arc)."""
    axis = np.asarray(up, dtype=np.float64)
    norm = float(np.linalg.norm(axis))
    if not norm > 0.0:
        raise ValueError('rotation_to_z: the up direction is zero')
    axis = axis / norm
    z = np.array([0.0, 0.0, 1.0])
    turn = cross(axis, z)
    sin, cos = float(np.linalg.norm(turn)), float(axis @ z)
    if sin < 1e-12:
        # Already up, or upside down: half a turn about x.
        return np.eye(3) if cos > 0.0 else np.diag([1.0, -1.0, -1.0])
    return Rotation.from_rotvec(turn / sin * math.atan2(sin, cos)).as_matrix()


@dataclass(eq=False)
class TableObject:
    """
    A whole mesh standing on the table, in the world frame, with its ground truth.

    :ivar name: the model's name.
    :ivar vertices: (V, 3) mesh vertices in the world frame, metres.
    :ivar triangles: (T, 3) vertex indices.
    :ivar surface: (S, 3) points sampled uniformly by area on the whole surface (world).
    :ivar hull_volume: volume of the mesh's convex hull, cubic metres.
    :ivar center: (3,) centre of the mesh's axis-aligned bounding box (world); the cameras look
        at it.
    """

    name: str
    vertices: FloatArray
    triangles: IndexArray
    surface: FloatArray
    hull_volume: float
    center: FloatArray
    _camera: DepthCamera | None = field(default=None, repr=False)
    _target: GraspTarget | None = field(default=None, repr=False)

    @classmethod
    def from_mesh(cls, name: str, mesh: o3d.geometry.TriangleMesh) -> TableObject:
        """Wrap a world-frame mesh that already stands on the table."""
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        triangles = np.asarray(mesh.triangles, dtype=np.intp)
        return cls(
            name=name,
            vertices=vertices,
            triangles=triangles,
            surface=sample_surface(vertices, triangles),
            hull_volume=convex_hull_volume(vertices),
            center=(vertices.min(axis=0) + vertices.max(axis=0)) / 2.0,
        )

    @property
    def mesh(self) -> o3d.geometry.TriangleMesh:
        """Return the world-frame mesh as an Open3D triangle mesh."""
        return o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(self.vertices),
            o3d.utility.Vector3iVector(self.triangles.astype(np.int32)),
        )

    @property
    def camera(self) -> DepthCamera:
        """Return the depth camera's world: this object (label 0) on a table (background)."""
        if self._camera is None:
            self._camera = DepthCamera([self.mesh, table_mesh()])
        return self._camera

    @property
    def target(self) -> GraspTarget:
        """Return the whole mesh prepared for grasp simulation, in the world frame."""
        if self._target is None:
            self._target = GraspTarget(self.vertices, self.triangles)
        return self._target


def table_mesh(size: float = 2.0, thickness: float = 0.03) -> o3d.geometry.TriangleMesh:
    """Return the table: a square slab whose top is z = 0, centred on the origin (metres)."""
    mesh = o3d.geometry.TriangleMesh.create_box(size, size, thickness)
    mesh.translate([-size / 2.0, -size / 2.0, -thickness])
    return mesh


def stand_on_table(
    mesh: o3d.geometry.TriangleMesh, model: TableModel
) -> o3d.geometry.TriangleMesh:
    """
    Return a copy of a model's mesh turned upright, scaled to metres and set on the table.

    The model's up axis is turned onto +z (:func:`rotation_to_z`), the mesh scaled (by
    `units`, or to `height` / `length`), its bounding box centred on x = y = 0 and its lowest
    point put on z = 0.
    """
    vertices = np.asarray(mesh.vertices, dtype=np.float64) @ rotation_to_z(model.up).T
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    scale = model.units
    if model.height is not None:
        scale = model.height / float(extent[2])
    elif model.length is not None:
        scale = model.length / float(extent.max())
    vertices = vertices * scale
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    vertices -= np.array([(low[0] + high[0]) / 2.0, (low[1] + high[1]) / 2.0, low[2]])
    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(vertices),
        o3d.utility.Vector3iVector(np.asarray(mesh.triangles, dtype=np.int32)),
    )


def load_table_object(models_dir: str | os.PathLike[str], model: TableModel) -> TableObject:
    """Read a model's mesh from the shared ``models`` folder and stand it on the table."""
    mesh = load_mesh(Path(models_dir) / model.file)
    return TableObject.from_mesh(model.name, stand_on_table(mesh, model))


@dataclass(frozen=True, eq=False)
class SingleView:
    """
    One view of a whole object on the table, as the node receives it, with its ground truth.

    :ivar obj: the object (whole mesh, world frame).
    :ivar index: the view's number for this object.
    :ivar points: (N, 3) float32 object points in the camera optical frame, metres.
    :ivar camera_pose: (4, 4) T_world_camera.
    :ivar elevation_deg: camera elevation above the table, degrees.
    :ivar azimuth_deg: camera azimuth about the object, degrees.
    :ivar distance: camera distance from the object's bounding-box centre, metres.
    :ivar noise: the sensor model.
    :ivar seed: seed of frame 0's noise (frame k uses ``(seed, k)``).
    """

    obj: TableObject
    index: int
    points: Float32Array
    camera_pose: FloatArray
    elevation_deg: float
    azimuth_deg: float
    distance: float
    noise: DepthNoise
    seed: int

    @property
    def name(self) -> str:
        """``'<model>/<index>'``."""
        return f'{self.obj.name}/{self.index}'

    @property
    def up(self) -> FloatArray:
        """Return the world's +z in the camera frame: what a robot sets as ``up_direction``."""
        return self.camera_pose[2, :3].copy()

    @property
    def world_from_camera(self) -> tuple[FloatArray, FloatArray]:
        """(rotation, translation) taking camera-frame points to the world."""
        return self.camera_pose[:3, :3], self.camera_pose[:3, 3]

    def to_camera(self, world: ArrayLike) -> FloatArray:
        """Map world points (..., 3) into the camera optical frame."""
        rotation, translation = self.world_from_camera
        return (np.asarray(world, dtype=np.float64) - translation) @ rotation

    def to_world(self, camera: ArrayLike) -> FloatArray:
        """Map camera-frame points (..., 3) to the world."""
        rotation, translation = self.world_from_camera
        return np.asarray(camera, dtype=np.float64) @ rotation.T + translation

    def mesh_in_camera(self) -> tuple[FloatArray, IndexArray]:
        """Return the whole mesh in the camera frame: (vertices, triangles)."""
        return self.to_camera(self.obj.vertices), self.obj.triangles

    def surface_in_camera(self) -> FloatArray:
        """Return the whole-surface sample in the camera frame."""
        return self.to_camera(self.obj.surface)

    def frame(self, number: int) -> Float32Array:
        """Render this view again with fresh sensor noise: frame `number` (0 is :attr:`points`)."""
        if number == 0:
            return self.points
        return _render(self.obj, self.camera_pose, self.noise, [self.seed, number])

    def box_metrics(self, boxes: Sequence[Box]) -> BoxMetrics:
        """Measure boxes in the camera frame against the whole object."""
        rotation, translation = self.world_from_camera
        world = [box.transformed(rotation, translation) for box in boxes]
        return box_metrics(world, self.obj.surface, self.obj.hull_volume)

    def grasps_in_world(self, grasps: Sequence[Any]) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Return camera-frame grasps as world (positions, approaches, closings), (G, 3) each."""
        rotation, _ = self.world_from_camera
        positions, approaches, closings = (
            np.array([np.asarray(getattr(g, name), dtype=np.float64) for g in grasps]).reshape(
                -1, 3
            )
            for name in ('position', 'approach', 'closing')
        )
        return self.to_world(positions), approaches @ rotation.T, closings @ rotation.T

    def judge_grasps(self, grasps: Sequence[Any], max_width: float) -> Verdicts:
        """
        Judge camera-frame grasps on the whole object standing on the table.

        :func:`~mvbb_ros.evaluation.grasp_judge.judge_grasps` with a :class:`PadGripper` of
        opening `max_width`, the table top (z = 0) as the support plane.
        """
        return judge_grasps(
            self.obj.target,
            self.grasps_in_world(grasps),
            PadGripper(max_width=max_width),
            support=(np.array([0.0, 0.0, 1.0]), 0.0),
        )

    def simulated_epsilon(self, grasps: Sequence[Any], max_width: float) -> FloatArray:
        """Return the Figure 6 simulator's epsilon of camera-frame grasps on the whole object."""
        return simulated_epsilon(self.obj.target, self.grasps_in_world(grasps), max_width)


def _render(
    obj: TableObject, pose: FloatArray, noise: DepthNoise, seed: int | list[int]
) -> Float32Array:
    intrinsics = camera_intrinsics(DEFAULT_WIDTH, DEFAULT_HEIGHT)
    size = (DEFAULT_WIDTH, DEFAULT_HEIGHT)
    low, high = obj.vertices.min(axis=0), obj.vertices.max(axis=0)
    corners = np.array([[(low, high)[k >> i & 1][i] for i in range(3)] for k in range(8)])
    window = image_window(corners, pose, intrinsics, size)
    points, labels = obj.camera.render(
        pose, intrinsics, size, noise, np.random.default_rng(seed), window=window
    )
    return np.ascontiguousarray(points[labels == 0])


def _stable_seed(*parts: int | str) -> int:
    """Return a seed from names and numbers that does not depend on Python's hash salt."""
    return zlib.crc32(repr(parts).encode()) & 0x7FFFFFFF


def single_views(
    obj: TableObject,
    count: int,
    *,
    seed: int = 0,
    noise: DepthNoise = KINECT_NOISE,
    elevation_deg: tuple[float, float] = ELEVATION_RANGE_DEG,
    distance: tuple[float, float] = DISTANCE_RANGE,
) -> Iterator[SingleView]:
    """
    Render `count` single views of an object from random viewpoints.

    Each camera looks at the centre of the object's bounding box from a distance and elevation
    drawn uniformly from the ranges and an azimuth drawn uniformly from [0, 360) degrees; the
    image is 640 x 480 with f = 525 px (a VGA RGB-D camera). Only the object's pixels are kept
    (perfect segmentation). Views whose cloud has fewer than 50 points are drawn again.

    :param obj: the object on the table.
    :param count: how many views.
    :param seed: the seed; views depend on it and on the object's name only.
    :param noise: the sensor model (default Kinect-like: depth noise, disparity steps, dropout).
    :param elevation_deg: (low, high) elevation range, degrees.
    :param distance: (low, high) distance range, metres.
    :return: an iterator of views, index 0 to count - 1.
    """
    rng = np.random.default_rng(_stable_seed(obj.name, seed))
    index = 0
    while index < count:
        elevation = float(rng.uniform(*elevation_deg))
        azimuth = float(rng.uniform(0.0, 360.0))
        radius = float(rng.uniform(*distance))
        pose = orbit_pose(obj.center, radius, azimuth, elevation)
        view_seed = _stable_seed(obj.name, seed, index)
        points = _render(obj, pose, noise, [view_seed, 0])
        if len(points) < 50:
            continue
        yield SingleView(
            obj=obj,
            index=index,
            points=points,
            camera_pose=pose,
            elevation_deg=elevation,
            azimuth_deg=azimuth,
            distance=radius,
            noise=noise,
            seed=view_seed,
        )
        index += 1


# Real scans --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RealScan:
    """
    One real single-view scan, in a frame whose origin is the sensor.

    :ivar name: the file's stem.
    :ivar points: (N, 3) float32 points, metres; the viewpoint is the origin.
    :ivar up: the up direction in that frame when known (the bunny), else None.
    """

    name: str
    points: Float32Array
    up: FloatArray | None = None


#: How far the bunny range scans' scanner is placed from the scan's centroid, metres.
BUNNY_SCANNER_DISTANCE = 1.0


def _bunny_poses(conf: Path) -> dict[str, FloatArray]:
    """Return the scanner rotation R of each range scan (``bmesh`` lines of bun.conf)."""
    poses = {}
    for line in conf.read_text().splitlines():
        parts = line.split()
        if len(parts) == 9 and parts[0] == 'bmesh':
            quaternion = [float(v) for v in parts[5:9]]  # qx qy qz qw
            poses[Path(parts[1]).stem] = Rotation.from_quat(quaternion).as_matrix()
    return poses


def bunny_scan_in_scanner_frame(
    points: ArrayLike, rotation: ArrayLike, distance: float = BUNNY_SCANNER_DISTANCE
) -> tuple[Float32Array, FloatArray]:
    """
    Move a bunny range scan from the model frame into a frame whose origin is the scanner.

    The scans were put into the complete bunny's frame with p' = R^T p + t, so the scanner
    looked along its own z axis, R^T z in the model frame: the viewpoint is `distance` along R^T z
    from the scan's centroid (the scan points face it). The new frame is camera-like: z from the
    viewpoint towards the centroid, x along R^T x, y = z x x.

    :param points: (N, 3) scan points in the model frame.
    :param rotation: (3, 3) R of the scan's ``bmesh`` line.
    :param distance: viewpoint distance from the centroid, metres.
    :return: ``(points, up)``: float32 points in the scanner frame and the model's up (+y)
        there.
    """
    pts = np.asarray(points, dtype=np.float64)
    r_t = np.asarray(rotation, dtype=np.float64).T
    viewpoint = pts.mean(axis=0) + distance * r_t[:, 2]
    axes = r_t @ np.diag([1.0, -1.0, -1.0])  # columns: the new frame's axes in the model frame
    local = (pts - viewpoint) @ axes
    return local.astype(np.float32), axes.T @ np.array([0.0, 1.0, 0.0])


def real_scans(scans_dir: str | os.PathLike[str]) -> list[RealScan]:
    """
    Read every real single-view scan (``*.npy``) of the shared ``scans`` folder, sorted by name.

    The RGB-D and stereo scans are in their camera's optical frame: the viewpoint is the origin
    and up is unknown. The bunny range scans (``bunny_rangescan_*``) are in the complete
    bunny's model frame; they are moved into their scanner's frame
    (:func:`bunny_scan_in_scanner_frame`, with the poses of ``bunny_bun.conf``) so that every
    scan reaches the pipeline as a sensor delivers it, and their up (the model's +y) is known.
    """
    folder = Path(scans_dir)
    conf = folder / 'bunny_bun.conf'
    poses = _bunny_poses(conf) if conf.is_file() else {}
    scans = []
    for path in sorted(folder.glob('*.npy')):
        points = np.load(path).astype(np.float32)
        stem = path.stem
        key = stem.removeprefix('bunny_rangescan_')
        if stem.startswith('bunny_rangescan_'):
            if key not in poses:
                raise ValueError(f'{path.name}: no bmesh pose for {key} in {conf}')
            moved, up = bunny_scan_in_scanner_frame(points, poses[key])
            scans.append(RealScan(stem, moved, up))
        else:
            scans.append(RealScan(stem, points))
    return scans


def views_of(
    models_dir: str | os.PathLike[str],
    models: Sequence[TableModel] = TABLE_MODELS,
    count: int = 6,
    *,
    seed: int = 0,
) -> Iterator[SingleView]:
    """Yield `count` single views of each model, model by model (see :func:`single_views`)."""
    for model in models:
        yield from single_views(load_table_object(models_dir, model), count, seed=seed)
