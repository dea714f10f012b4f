"""
Sample data of our own: household objects on a table, seen by a simulated depth camera.

Meshes are built here with Open3D (no external model files), placed on a table and ray-cast by
the virtual depth camera of :mod:`mvbb_ros.evaluation.camera` (noise models, poses, intrinsics
and ray casting live there), so the clouds are single partial views with realistic sensor noise,
like a segmented RGB-D object cloud; :func:`table_top_frame` gives whole raw frames instead
(table, objects, a wall behind the table and the floor), with the table's plane as truth.

Conventions:

* Lengths are in metres.
* World frame: z up, the table top is the plane z = 0, the table centre is the origin.
* Object frame (:func:`make_object_mesh`): the object stands on z = 0, its axis is +z and a mug's
  handle points along +x.
* Camera optical frame (ROS ``*_optical_frame``): x right, y down, z forward. A camera pose is the
  4x4 transform T_world_camera, i.e. ``world = pose[:3, :3] @ camera + pose[:3, 3]``.
* Clouds returned by the render functions are in the camera optical frame, float32, NaN where the
  ray hit nothing (or the sensor dropped the pixel).
* Label images hold the index of the object each pixel saw, and :data:`BACKGROUND` (-1) for the
  table, for no hit and for dropped pixels.

Everything is deterministic for a given ``seed``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
import math

from mvbb_ros.arrays import cross, Float32Array, FloatArray, IntArray
from mvbb_ros.evaluation.camera import (
    BACKGROUND,
    camera_intrinsics,
    DEFAULT_FOCAL,
    DEFAULT_HEIGHT,
    DEFAULT_NOISE,
    DEFAULT_WIDTH,
    DepthCamera,
    DepthNoise,
    orbit_pose,
    render_depth_cloud,
)
import numpy as np
from numpy.typing import ArrayLike, NDArray
import open3d as o3d

#: Object kinds :func:`make_object_mesh` builds.
OBJECT_KINDS: tuple[str, ...] = ('mug', 'can', 'box', 'bottle')


# Meshes ------------------------------------------------------------------------------------------


def _mesh(vertices: ArrayLike, triangles: ArrayLike) -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(vertices, dtype=np.float64)),
        o3d.utility.Vector3iVector(np.asarray(triangles, dtype=np.int32)),
    )
    mesh.compute_vertex_normals()
    return mesh


def _revolve(profile: ArrayLike, segments: int) -> o3d.geometry.TriangleMesh:
    """
    Build the surface of revolution about +z of a polyline of (radius, z) points (metres).

    Points with radius 0 become a single pole vertex. Walking the profile from the bottom centre
    outwards and up gives outward-facing triangles.
    """
    prof = np.asarray(profile, dtype=np.float64)
    angles = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    vertices: list[FloatArray] = []
    rings: list[NDArray[np.int64]] = []  # vertex indices of each profile point (1 for a pole)
    for radius, z in prof:
        start = sum(len(v) for v in vertices)
        if radius <= 0.0:
            vertices.append(np.array([[0.0, 0.0, z]]))
            rings.append(np.array([start]))
        else:
            vertices.append(np.column_stack([radius * ring, np.full(segments, z)]))
            rings.append(start + np.arange(segments))
    nxt = np.roll(np.arange(segments), -1)
    triangles = []
    for low, high in zip(rings[:-1], rings[1:], strict=True):
        if len(low) == 1 and len(high) == 1:
            continue
        if len(low) == 1:  # fan from a pole below
            triangles.append(np.column_stack([np.full(segments, low[0]), high, high[nxt]]))
        elif len(high) == 1:  # fan to a pole above
            triangles.append(np.column_stack([low, low[nxt], np.full(segments, high[0])]))
        else:
            triangles.append(np.column_stack([low, low[nxt], high[nxt]]))
            triangles.append(np.column_stack([low, high[nxt], high]))
    return _mesh(np.concatenate(vertices), np.concatenate(triangles))


def _tube(centerline: ArrayLike, radius: float, segments: int) -> o3d.geometry.TriangleMesh:
    """Build an open tube of the given radius (metres) around a polyline in the x-z plane."""
    path = np.asarray(centerline, dtype=np.float64)
    tangent = np.gradient(path, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    binormal = np.array([0.0, 1.0, 0.0])
    normal = cross(binormal, tangent)
    angles = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    offsets = (
        np.cos(angles)[None, :, None] * normal[:, None, :]
        + np.sin(angles)[None, :, None] * binormal[None, None, :]
    )
    vertices = (path[:, None, :] + radius * offsets).reshape(-1, 3)
    index = np.arange(len(path) * segments).reshape(len(path), segments)
    low, high = index[:-1], index[1:]
    low_next, high_next = np.roll(low, -1, axis=1), np.roll(high, -1, axis=1)
    triangles = np.concatenate(
        [
            np.stack([low, high, high_next], axis=-1).reshape(-1, 3),
            np.stack([low, high_next, low_next], axis=-1).reshape(-1, 3),
        ]
    )
    return _mesh(vertices, triangles)


def _mug(resolution: int) -> o3d.geometry.TriangleMesh:
    radius, height, wall, base = 0.040, 0.100, 0.004, 0.006
    body = _revolve(
        [
            (0.0, 0.0),
            (radius - 0.002, 0.0),
            (radius, 0.002),
            (radius, height),
            (radius - wall, height),
            (radius - wall, base),
            (0.0, base),
        ],
        resolution,
    )
    # Handle: a half ellipse in the x-z plane whose ends sit inside the wall (so they are hidden).
    phi = np.linspace(-np.pi / 2.0, np.pi / 2.0, max(resolution // 2, 12))
    attach_x, reach, half_span, mid_z = radius - wall / 2.0, 0.030, 0.031, 0.054
    centerline = np.column_stack(
        [attach_x + reach * np.cos(phi), np.zeros_like(phi), mid_z + half_span * np.sin(phi)]
    )
    handle = _tube(centerline, 0.0055, max(resolution // 4, 8))
    return _merge([body, handle])


def _can(resolution: int) -> o3d.geometry.TriangleMesh:
    # A 330 ml drinks can: 66 mm diameter, 122 mm tall, with bevels and a recessed lid.
    return _revolve(
        [
            (0.0, 0.0),
            (0.027, 0.0),
            (0.033, 0.008),
            (0.033, 0.110),
            (0.0295, 0.1205),
            (0.0295, 0.122),
            (0.0275, 0.122),
            (0.0275, 0.117),
            (0.0, 0.117),
        ],
        resolution,
    )


def _bottle(resolution: int) -> o3d.geometry.TriangleMesh:
    # A 0.5 l bottle: 72 mm diameter body, rounded shoulder, 26 mm neck, cap, 250 mm tall.
    shoulder = np.linspace(0.0, np.pi / 2.0, 8)
    shoulder_profile = [
        (0.013 + 0.023 * np.cos(a), 0.150 + 0.045 * np.sin(a)) for a in shoulder[1:-1]
    ]
    return _revolve(
        [
            (0.0, 0.0),
            (0.033, 0.0),
            (0.036, 0.004),
            (0.036, 0.150),
            *shoulder_profile,
            (0.013, 0.195),
            (0.013, 0.228),
            (0.015, 0.228),
            (0.015, 0.250),
            (0.0, 0.250),
        ],
        resolution,
    )


def _box() -> o3d.geometry.TriangleMesh:
    # A cereal/cracker box: 158 x 60 x 210 mm (like the YCB cracker box).
    size = np.array([0.158, 0.060, 0.210])
    mesh = o3d.geometry.TriangleMesh.create_box(*size)
    mesh.translate([-size[0] / 2.0, -size[1] / 2.0, 0.0])
    mesh.compute_vertex_normals()
    return mesh


def _merge(meshes: Sequence[o3d.geometry.TriangleMesh]) -> o3d.geometry.TriangleMesh:
    merged = o3d.geometry.TriangleMesh()
    for mesh in meshes:
        merged += mesh
    merged.compute_vertex_normals()
    return merged


def make_object_mesh(kind: str, *, resolution: int = 64) -> o3d.geometry.TriangleMesh:
    """
    Build a household object mesh in its object frame (metres, base on z = 0, axis +z).

    Kinds (sizes of real objects):

    * ``'mug'``: 80 mm diameter, 100 mm tall, 4 mm wall, hollow, with a handle along +x reaching
      34 mm out of the wall (the mug is open: its inside is visible from above);
    * ``'can'``: 66 mm diameter, 122 mm tall drinks can with bevelled rims;
    * ``'box'``: 158 x 60 x 210 mm cereal box (x by y by z), centred on the z axis;
    * ``'bottle'``: 72 mm diameter, 250 mm tall bottle with shoulder, neck and cap.

    :param kind: one of :data:`OBJECT_KINDS`.
    :param resolution: segments around the axis of round objects (>= 8).
    :return: the triangle mesh, with vertex normals.
    :raises ValueError: for an unknown kind or a resolution below 8.
    """
    if resolution < 8:
        raise ValueError(f'resolution must be >= 8, got {resolution}')
    builders = {
        'mug': lambda: _mug(resolution),
        'can': lambda: _can(resolution),
        'box': _box,
        'bottle': lambda: _bottle(resolution),
    }
    if kind not in builders:
        raise ValueError(f'unknown object kind {kind!r}; expected one of {OBJECT_KINDS}')
    return builders[kind]()


def make_table_mesh(
    size: tuple[float, float] = (1.2, 0.8), thickness: float = 0.03
) -> o3d.geometry.TriangleMesh:
    """Build a table top slab (metres) centred on the world origin, its top face on z = 0."""
    mesh = o3d.geometry.TriangleMesh.create_box(size[0], size[1], thickness)
    mesh.translate([-size[0] / 2.0, -size[1] / 2.0, -thickness])
    mesh.compute_vertex_normals()
    return mesh


#: The room around the table (metres): the floor's height, and the wall behind the table (its
#: near face's y, its width and height from the floor).
FLOOR_Z = -0.75
WALL_Y = 0.5
WALL_SIZE = (2.4, 1.6)


def make_room_meshes(*, wall: bool = True, floor: bool = True) -> list[o3d.geometry.TriangleMesh]:
    """Build the wall behind the table (at y = :data:`WALL_Y`) and the floor below it."""
    meshes = []
    if wall:
        width, height = WALL_SIZE
        mesh = o3d.geometry.TriangleMesh.create_box(width, 0.05, height)
        mesh.translate([-width / 2.0, WALL_Y, FLOOR_Z])
        meshes.append(mesh)
    if floor:
        mesh = o3d.geometry.TriangleMesh.create_box(4.0, 4.0, 0.05)
        mesh.translate([-2.0, -2.0, FLOOR_Z - 0.05])
        meshes.append(mesh)
    for mesh in meshes:
        mesh.compute_vertex_normals()
    return meshes


def pose_matrix(translation: ArrayLike = (0.0, 0.0, 0.0), yaw: float = 0.0) -> FloatArray:
    """Return the 4x4 transform: a rotation of `yaw` radians about +z, then a translation (m)."""
    pose = np.eye(4)
    cos, sin = math.cos(yaw), math.sin(yaw)
    pose[:2, :2] = [[cos, -sin], [sin, cos]]
    pose[:3, 3] = np.asarray(translation, dtype=np.float64)
    return pose


# Scenes ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SceneObject:
    """
    One object placed in a scene.

    :ivar name: unique name in the scene (the kind, numbered when a kind repeats).
    :ivar kind: the :func:`make_object_mesh` kind.
    :ivar pose: (4, 4) object-to-world transform (metres).
    :ivar mesh: the mesh in the world frame (already moved by `pose`).
    """

    name: str
    kind: str
    pose: FloatArray
    mesh: o3d.geometry.TriangleMesh


@dataclass(frozen=True)
class Scene:
    """
    Objects standing on a table; the label of object ``objects[i]`` is ``i``.

    :ivar objects: the placed objects.
    :ivar table: the table slab mesh (world frame, top face on z = 0), or None for no table.
    :ivar room: further background meshes (a wall behind the table, the floor).
    """

    objects: tuple[SceneObject, ...]
    table: o3d.geometry.TriangleMesh | None = field(default_factory=make_table_mesh)
    room: tuple[o3d.geometry.TriangleMesh, ...] = ()

    @property
    def meshes(self) -> list[o3d.geometry.TriangleMesh]:
        """World-frame meshes of the objects, in label order."""
        return [obj.mesh for obj in self.objects]

    @property
    def names(self) -> list[str]:
        """Object names, in label order."""
        return [obj.name for obj in self.objects]

    @property
    def poses(self) -> list[FloatArray]:
        """Object-to-world transforms (4, 4), in label order."""
        return [obj.pose for obj in self.objects]

    def labelled_meshes(self) -> list[tuple[int, o3d.geometry.TriangleMesh]]:
        """Return (label, mesh) pairs for the camera: objects by index, the table as background."""
        labelled = list(enumerate(self.meshes))
        if self.table is not None:
            labelled.append((BACKGROUND, self.table))
        labelled.extend((BACKGROUND, mesh) for mesh in self.room)
        return labelled

    def label_of(self, name: str) -> int:
        """Return the label (index) of the object called `name`."""
        return self.names.index(name)


def place_objects(
    kinds: Sequence[str],
    poses: Sequence[ArrayLike],
    *,
    table: bool = True,
    resolution: int = 64,
) -> Scene:
    """Build a scene with one object of each kind at the given object-to-world poses (4x4, m)."""
    if len(kinds) != len(poses):
        raise ValueError(f'got {len(kinds)} kinds but {len(poses)} poses')
    objects: list[SceneObject] = []
    for kind, pose in zip(kinds, poses, strict=True):
        transform = np.asarray(pose, dtype=np.float64)
        if transform.shape != (4, 4):
            raise ValueError(f'an object pose must be a 4x4 matrix, got shape {transform.shape}')
        mesh = make_object_mesh(kind, resolution=resolution).transform(transform)
        count = sum(obj.kind == kind for obj in objects)
        name = kind if kinds.count(kind) == 1 else f'{kind}{count + 1}'
        objects.append(SceneObject(name=name, kind=kind, pose=transform, mesh=mesh))
    return Scene(objects=tuple(objects), table=make_table_mesh() if table else None)


def make_scene(
    seed: int = 0,
    kinds: Sequence[str] = ('mug', 'can', 'box', 'bottle'),
    *,
    area: tuple[float, float] = (0.45, 0.35),
    resolution: int = 64,
) -> Scene:
    """
    Build a table-top scene: the objects at random, non-overlapping places and headings.

    :param seed: seed of the placement; the same seed gives the same scene.
    :param kinds: object kinds, one object each (see :func:`make_object_mesh`).
    :param area: size (x, y) in metres of the region around the table centre they stand in.
    :param resolution: mesh resolution of round objects.
    :return: the scene (objects on a 1.2 x 0.8 m table whose top is the plane z = 0).
    :raises ValueError: when the objects cannot be placed without overlap in `area`.
    """
    rng = np.random.default_rng(seed)
    kinds = list(kinds)
    footprints = []
    for kind in kinds:
        vertices = np.asarray(make_object_mesh(kind, resolution=16).vertices)
        footprints.append(float(np.max(np.linalg.norm(vertices[:, :2], axis=1))) + 0.01)
    half = np.asarray(area, dtype=np.float64) / 2.0
    for _ in range(200):
        centers: list[FloatArray] = []
        for radius in footprints:
            for _ in range(100):
                candidate = rng.uniform(-half, half)
                if all(
                    np.linalg.norm(candidate - other) >= radius + other_radius
                    for other, other_radius in zip(centers, footprints, strict=False)
                ):
                    centers.append(candidate)
                    break
            else:
                break
        if len(centers) == len(kinds):
            break
    else:
        raise ValueError(f'cannot place {kinds} without overlap in a {area} m area')
    yaws = rng.uniform(-np.pi, np.pi, size=len(kinds))
    poses = [pose_matrix([x, y, 0.0], yaw) for (x, y), yaw in zip(centers, yaws, strict=True)]
    return place_objects(kinds, poses, resolution=resolution)


# Views -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class View:
    """
    One frame of :func:`scene_views`.

    :ivar index: frame number, from 0.
    :ivar points: (H, W, 3) float32 organized cloud in the camera optical frame, metres, NaN
        holes.
    :ivar labels: (H, W) int32 object labels (:data:`BACKGROUND` for table and holes).
    :ivar camera_pose: (4, 4) T_world_camera of this frame.
    """

    index: int
    points: Float32Array
    labels: IntArray
    camera_pose: FloatArray


def scene_views(
    scene: Scene,
    n_frames: int,
    *,
    distance: float = 0.8,
    elevation_deg: float = 35.0,
    azimuth_start_deg: float = -135.0,
    azimuth_end_deg: float = -45.0,
    target: ArrayLike = (0.0, 0.0, 0.05),
    width: int = DEFAULT_WIDTH,
    height: int = DEFAULT_HEIGHT,
    fx: float = DEFAULT_FOCAL,
    fy: float = DEFAULT_FOCAL,
    noise: DepthNoise | None = DEFAULT_NOISE,
    seed: int = 0,
) -> Iterator[View]:
    """
    Render a camera moving on an arc around the scene, looking at `target`, frame by frame.

    The camera stays `distance` metres from `target` at a fixed elevation (degrees above the
    table) while its azimuth (degrees, see :func:`orbit_pose`) goes from start to end in
    `n_frames` even steps. Frame i's noise uses the seed ``(seed, i)``.

    :return: an iterator of one :class:`View` per frame.
    """
    if n_frames < 1:
        raise ValueError(f'n_frames must be >= 1, got {n_frames}')
    intrinsics = camera_intrinsics(width, height, fx, fy, None, None)
    caster = DepthCamera(scene)
    azimuths = np.linspace(azimuth_start_deg, azimuth_end_deg, n_frames)
    for index, azimuth in enumerate(azimuths):
        pose = orbit_pose(target, distance, float(azimuth), elevation_deg)
        rng = np.random.default_rng([seed, index])
        points, labels = caster.render(pose, intrinsics, (width, height), noise, rng)
        yield View(index=index, points=points, labels=labels, camera_pose=pose)


def table_top_scene(seed: int, count: int, *, room: bool = True) -> Scene:
    """
    Build a table-top scene of `count` (1-5) objects of random kinds, a wall and the floor.

    The kinds are drawn (with repetition) from :data:`OBJECT_KINDS` and placed by
    :func:`make_scene` in the middle 0.7 x 0.45 m of the table; the same seed gives the same
    scene.
    """
    if not 1 <= count <= 5:
        raise ValueError(f'count must be 1 to 5, got {count}')
    rng = np.random.default_rng([seed, count])
    kinds = [str(kind) for kind in rng.choice(OBJECT_KINDS, size=count)]
    scene = make_scene(seed, kinds, area=(0.7, 0.45))
    return Scene(scene.objects, scene.table, tuple(make_room_meshes()) if room else ())


@dataclass(frozen=True)
class TableTopFrame:
    """
    One organized camera frame of a table-top scene, with its truth.

    :ivar points: (H, W, 3) float32 in the camera optical frame, metres, NaN holes.
    :ivar labels: (H, W) object labels (:data:`BACKGROUND` for table, wall, floor and holes).
    :ivar camera_pose: (4, 4) T_world_camera.
    :ivar objects: how many objects stand on the table.
    """

    points: Float32Array
    labels: IntArray
    camera_pose: FloatArray
    objects: int

    @property
    def table_plane(self) -> FloatArray:
        """Return the table top (a, b, c, d) in the camera frame, (a, b, c) the unit up."""
        rotation, translation = self.camera_pose[:3, :3], self.camera_pose[:3, 3]
        return np.append(rotation[2, :], translation[2])


def table_top_frame(
    seed: int,
    count: int,
    *,
    distance: float = 0.9,
    room: bool = True,
    noise: DepthNoise | None = DEFAULT_NOISE,
) -> TableTopFrame:
    """
    Render a raw 640 x 480 frame of :func:`table_top_scene`: table, objects, wall and floor.

    The camera looks at the table centre from `distance` metres, at an azimuth of -135 to -45
    degrees and an elevation of 30 to 60 degrees drawn from `seed` (so the wall stands behind
    the table); nothing is segmented.
    """
    scene = table_top_scene(seed, count, room=room)
    rng = np.random.default_rng([seed, count, 1])
    azimuth, elevation = rng.uniform(-135.0, -45.0), rng.uniform(30.0, 60.0)
    pose = orbit_pose((0.0, 0.0, 0.05), distance, azimuth, elevation)
    intrinsics = camera_intrinsics(
        DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_FOCAL, DEFAULT_FOCAL, None, None
    )
    points, labels = DepthCamera(scene).render(
        pose, intrinsics, (DEFAULT_WIDTH, DEFAULT_HEIGHT), noise, np.random.default_rng(seed)
    )
    return TableTopFrame(points, labels, pose, count)


def cut_table_top_frame(seed: int, count: int) -> tuple[Float32Array, IntArray, int]:
    """
    Return :func:`table_top_frame` with its image cut through one of its objects.

    The image keeps the columns on one side of the middle column of object ``seed % count``
    (the right side for odd seeds): that object stands across the new image's edge, as an
    object the camera sees only in part. Returns the finite points (N, 3), each point's object
    label (:data:`BACKGROUND` for the rest) and the cut object's label; float32, metres, in the
    camera optical frame.
    """
    frame = table_top_frame(seed, count)
    cut = seed % count
    columns = np.flatnonzero((frame.labels == cut).any(axis=0))
    middle = (int(columns.min()) + int(columns.max())) // 2
    kept = slice(middle, None) if seed % 2 else slice(None, middle)
    points, labels = frame.points[:, kept], frame.labels[:, kept]
    finite = np.all(np.isfinite(points), axis=-1)
    return points[finite], labels[finite], cut


def _object_scene(kind: str, yaw_deg: float) -> tuple[Scene, FloatArray]:
    """Place one object at the table centre; also return its bounding box centre (world, m)."""
    scene = place_objects([kind], [pose_matrix(yaw=math.radians(yaw_deg))])
    bounds = scene.objects[0].mesh.get_axis_aligned_bounding_box()
    return scene, np.asarray(bounds.get_center())


def segmented_object_cloud(
    kind: str = 'mug',
    seed: int = 0,
    *,
    distance: float = 0.6,
    azimuth_deg: float = -60.0,
    elevation_deg: float = 35.0,
    yaw_deg: float = 0.0,
    width: int = DEFAULT_WIDTH,
    height: int = DEFAULT_HEIGHT,
    noise: DepthNoise | None = DEFAULT_NOISE,
) -> Float32Array:
    """
    Return the points of one object on a table, as one depth-camera view sees them, segmented.

    The object stands at the table centre turned by `yaw_deg` about the vertical; the camera
    looks at the centre of the object's bounding box from `distance` metres at the given azimuth
    and elevation (degrees, see :func:`orbit_pose`; the defaults show a mug's handle from the
    side). Only pixels that hit the object are kept (perfect segmentation, no table points).
    The camera has the field of view of a 640 x 480, fx = fy = 525 camera; `width` and `height`
    change its resolution (the focal length scales with `width`).

    :return: (N, 3) float32 points in the camera optical frame, metres (a few thousand for
        the defaults: the mug gives about 7500).
    """
    scene, center = _object_scene(kind, yaw_deg)
    pose = orbit_pose(center, distance, azimuth_deg, elevation_deg)
    focal = DEFAULT_FOCAL * width / DEFAULT_WIDTH
    points, labels = render_depth_cloud(
        scene, pose, width=width, height=height, fx=focal, fy=focal, noise=noise, seed=seed
    )
    return points[labels == 0]


def organized_frame(
    n_points: int = 300_000,
    *,
    kind: str = 'mug',
    seed: int = 0,
    azimuth_deg: float = -60.0,
    elevation_deg: float = 35.0,
    noise: DepthNoise | None = DEFAULT_NOISE,
) -> Float32Array:
    """
    Render an organized frame in which about `n_points` pixels see one object, for benchmarks.

    The camera has the field of view of the default 640x480, fx = 525 camera and stands so that
    the object's bounding sphere fills the image height; the resolution (4:3) is then chosen so
    that the object covers about `n_points` pixels (within a few per cent). Pixels that do not
    see the object (table, background, dropped) are NaN, so the frame is the object cloud as an
    organized segmentation would deliver it.

    :return: (H, W, 3) float32 points in the camera optical frame, metres.
    """
    if n_points < 100:
        raise ValueError(f'n_points must be >= 100, got {n_points}')
    scene, center = _object_scene(kind, 0.0)
    vertices = np.asarray(scene.objects[0].mesh.vertices)
    radius = float(np.max(np.linalg.norm(vertices - center, axis=1)))
    half_fov = math.atan((DEFAULT_HEIGHT / 2.0) / DEFAULT_FOCAL)
    pose = orbit_pose(center, radius / math.sin(half_fov), azimuth_deg, elevation_deg)
    caster = DepthCamera(scene)

    def render(width: int, noise_model: DepthNoise | None) -> tuple[Float32Array, IntArray]:
        height = round(width * 3 / 4)
        focal = DEFAULT_FOCAL * width / DEFAULT_WIDTH
        intrinsics = camera_intrinsics(width, height, focal, focal, None, None)
        rng = np.random.default_rng(seed)
        return caster.render(pose, intrinsics, (width, height), noise_model, rng)

    probe_width = 320
    _, probe_labels = render(probe_width, noise)
    coverage = np.count_nonzero(probe_labels == 0) / probe_labels.size
    width = max(4, round(math.sqrt(n_points / (coverage * 0.75))))
    points, labels = render(width, noise)
    points[labels != 0] = np.nan
    return points
