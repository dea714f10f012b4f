"""
Face-approach grasp hypotheses on the boxes of a decomposition (plain numpy/scipy, no ROS).

Huebner et al. (ICRA 2008), Sections IV-B and V: every face of every leaf box gives four
hypotheses (approach along the negative face normal from ``standoff`` off the face centre, the
fingers closing along one face edge or the other, in both senses); faces covered by or touching
another box, faces wider than the gripper and approaches from below the support are removed;
the rest are ranked by a task strategy (largest, smallest, outermost or nearest box first).
:func:`grasp_hypotheses` returns them, :func:`grasp_filter_counts` counts what each filter
removes. The exact rules (pose convention, occlusion tolerance, support tests, tie-breaking) are
in ``docs/grasp_rules.md``. Units are those of the boxes (metres for sensor data).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, get_args, Literal

from mvbb_ros.arrays import BoolArray, cross, FloatArray, IndexArray, read_only
from mvbb_ros.geometry import box as box_geometry
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition.result import Decomposition
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

#: Face order (+a, -a, +b, -b, +c, -c) of :attr:`Grasp.face`, from :mod:`mvbb_ros.geometry.box`.
FACE_NAMES: tuple[str, ...] = box_geometry.FACE_NAMES

#: Ranking strategies (:func:`grasp_hypotheses`); the first is the default.
Strategy = Literal['largest', 'smallest', 'outermost', 'nearest']
STRATEGIES: tuple[Strategy, ...] = get_args(Strategy)
#: Gripper frame axis that points along the approach direction; the first is the default.
ApproachAxis = Literal['z', 'x']
APPROACH_AXES: tuple[ApproachAxis, ...] = get_args(ApproachAxis)
#: Gripper rolls about the approach direction, in degrees, in hypothesis order.
ROLLS_DEG: tuple[int, ...] = (0, 90, 180, 270)
#: Hypotheses per box: six faces, four rolls.
HYPOTHESES_PER_BOX = len(FACE_NAMES) * len(ROLLS_DEG)

#: Defaults (metres): Franka Hand maximum opening; pre-grasp distance; finger clearance.
DEFAULT_GRIPPER_MAX_WIDTH = 0.08
DEFAULT_STANDOFF = 0.05
DEFAULT_SUPPORT_CLEARANCE = 0.01
#: Default relative contact tolerance, of the smaller :func:`box_sizes` of the two boxes.
DEFAULT_CONTACT_FRACTION = 0.1
#: Default limit on upward approaches, degrees above the horizontal.
DEFAULT_MAX_APPROACH_ELEVATION_DEG = 45.0
#: Without far-side grasps, an approach must turn at least this far (degrees) from
#: perpendicular to the viewing direction, away from the sensor: the object's centre is
#: estimated from what the sensor saw, which lies towards the sensor.
FAR_SIDE_MARGIN_DEG = 3.0


@dataclass(frozen=True, eq=False)
class Grasp:
    """
    One grasp hypothesis: a pre-grasp gripper pose in the boxes' frame.

    :ivar position: (3,) gripper frame origin, ``standoff`` off the face centre along its normal.
    :ivar quaternion: (4,) unit orientation (x, y, z, w), w >= 0, of the gripper frame (which
        gripper axis approaches and which closes: ``docs/grasp_rules.md``).
    :ivar approach: (3,) unit direction the gripper moves in, the negative outward face normal.
    :ivar closing: (3,) unit direction the fingers close along, a face edge direction.
    :ivar width: opening the gripper needs, the box extent along ``closing`` (boxes' units).
    :ivar box_index: index of the box in the input sequence (or ``Decomposition.leaves``).
    :ivar face: face index into :data:`mvbb_ros.geometry.box.FACE_NAMES` (+a, -a, +b, -b, +c, -c).
    :ivar roll_deg: roll of the closing direction about ``approach``: 0, 90, 180 or 270.
    :ivar score: strategy score in [0, 1] of the box (higher is better; list order is the rank).
    :ivar object_index: which object of the cloud the grasp is on (0 when the cloud is one
        object; the pipeline numbers the objects it separates).
    :ivar depth: how far the gripper moves along ``approach`` from ``position`` before it
        closes: ``position + depth * approach`` is where the fingertips stop (the paper's
        hypotheses: ``standoff``, the face centre; refined grasps: past the first contact,
        ``docs/grasp_rules.md``).
    """

    position: FloatArray
    quaternion: FloatArray
    approach: FloatArray
    closing: FloatArray
    width: float
    box_index: int
    face: int
    roll_deg: int
    score: float
    object_index: int = 0
    depth: float = DEFAULT_STANDOFF

    @property
    def face_name(self) -> str:
        """Name of the face, from :data:`mvbb_ros.geometry.box.FACE_NAMES` (e.g. ``'-z'``)."""
        return FACE_NAMES[self.face]

    @property
    def rotation(self) -> FloatArray:
        """(3, 3) rotation matrix of :attr:`quaternion`; its columns are the gripper axes."""
        return Rotation.from_quat(self.quaternion).as_matrix()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of every field (arrays as lists) plus ``face_name``."""
        return {
            'position': [float(v) for v in self.position],
            'quaternion': [float(v) for v in self.quaternion],
            'approach': [float(v) for v in self.approach],
            'closing': [float(v) for v in self.closing],
            'width': self.width,
            'box_index': self.box_index,
            'face': self.face,
            'face_name': self.face_name,
            'roll_deg': self.roll_deg,
            'score': self.score,
            'object_index': self.object_index,
            'depth': self.depth,
        }

    def __repr__(self) -> str:
        position = np.array2string(self.position, precision=4)
        return (
            f'Grasp(box={self.box_index}, face={self.face_name}, roll={self.roll_deg}, '
            f'position={position}, width={self.width:.4g}, score={self.score:.3g})'
        )


@dataclass(frozen=True)
class GraspStats:
    """
    How many hypotheses (and faces) survive each filter, in the order they are applied.

    :ivar boxes: number of leaf boxes.
    :ivar faces: faces before any filter (6 per box).
    :ivar faces_unoccluded: faces left after the occlusion filter.
    :ivar faces_graspable: faces with at least one hypothesis left after every filter.
    :ivar hypotheses: hypotheses before any filter (24 per box).
    :ivar after_occlusion: hypotheses left after removing occluded faces.
    :ivar after_width: ... and also those wider than ``gripper_max_width``.
    :ivar after_support: ... and also those from below, too close to the support or (with
        ``far_side`` off) from the far side of their object (the final count, ``len(grasps)``).
    """

    boxes: int
    faces: int
    faces_unoccluded: int
    faces_graspable: int
    hypotheses: int
    after_occlusion: int
    after_width: int
    after_support: int

    def as_dict(self) -> dict[str, int]:
        """Return the counts as a plain dict, for reports."""
        return asdict(self)


def _floats(values: ArrayLike) -> tuple[float, ...]:
    """Return array-like numbers as a flat tuple of floats (settings are hashable values)."""
    return tuple(float(v) for v in np.asarray(values, dtype=np.float64).reshape(-1))


@dataclass(frozen=True)
class GraspSettings:
    """
    The settings of the grasp stage: the keyword arguments of :func:`grasp_hypotheses`.

    The defaults are the library's (the Franka Hand's opening, a 5 cm standoff, no support
    filter); :func:`grasp_hypotheses` documents each field. Arrays are kept as tuples of floats.
    What the grasps know of the view (the up direction, the sensor position, each box's object)
    are arguments of their own: the pipeline takes them from its view stage.

    :raises ValueError: when a setting is out of range, with the setting's name and value.
    """

    gripper_max_width: float = DEFAULT_GRIPPER_MAX_WIDTH
    standoff: float = DEFAULT_STANDOFF
    approach_axis: ApproachAxis = 'z'
    strategy: Strategy = 'largest'
    support_plane: tuple[float, ...] | None = None
    support_clearance: float = DEFAULT_SUPPORT_CLEARANCE
    max_approach_elevation_deg: float = DEFAULT_MAX_APPROACH_ELEVATION_DEG
    contact_tolerance: float | None = None
    contact_fraction: float = DEFAULT_CONTACT_FRACTION
    max_grasps: int = 0
    far_side: bool = True

    def __post_init__(self) -> None:
        if self.strategy not in STRATEGIES:
            raise ValueError(f'strategy must be one of {STRATEGIES}, got {self.strategy!r}')
        if self.approach_axis not in APPROACH_AXES:
            raise ValueError(f"approach_axis must be 'x' or 'z', got {self.approach_axis!r}")
        if not self.gripper_max_width > 0.0:
            raise ValueError(f'gripper_max_width must be > 0, got {self.gripper_max_width}')
        if not self.standoff >= 0.0:
            raise ValueError(f'standoff must be >= 0, got {self.standoff}')
        if not 0.0 <= self.max_approach_elevation_deg <= 90.0:
            raise ValueError(
                'max_approach_elevation_deg must be in [0, 90], '
                f'got {self.max_approach_elevation_deg}'
            )
        if self.contact_tolerance is not None and not self.contact_tolerance >= 0.0:
            raise ValueError(
                f'contact_tolerance must be >= 0 or None, got {self.contact_tolerance}'
            )
        if not self.contact_fraction >= 0.0:
            raise ValueError(f'contact_fraction must be >= 0, got {self.contact_fraction}')
        if isinstance(self.max_grasps, bool) or not isinstance(self.max_grasps, (int, np.integer)):
            raise ValueError(f'max_grasps must be an integer >= 0, got {self.max_grasps!r}')
        if self.max_grasps < 0:
            raise ValueError(f'max_grasps must be an integer >= 0, got {self.max_grasps!r}')
        if self.support_plane is not None:
            _unit(self.support_plane, 'support_plane', size=4)  # finite, 4 numbers, not zero
            object.__setattr__(self, 'support_plane', _floats(self.support_plane))
        object.__setattr__(self, 'max_grasps', int(self.max_grasps))


# Geometry helpers -------------------------------------------------------------------------------


def box_sizes(extents: ArrayLike) -> FloatArray:
    """
    Return the size of each box used to scale the contact tolerance: its middle extent.

    The middle of the three extents, or the largest when the middle one is zero (a segment). A
    flat box (one zero extent, as fitted to a planar patch or a ring of mesh vertices) keeps the
    size of its face.

    :param extents: (..., 3) box extents.
    :return: (...,) sizes, in the extents' units.
    """
    ordered = np.sort(np.asarray(extents, dtype=np.float64), axis=-1)
    return np.where(ordered[..., 1] > 0.0, ordered[..., 1], ordered[..., 2])


def boxes_intersect(
    center_a: ArrayLike,
    rotation_a: ArrayLike,
    half_extents_a: ArrayLike,
    center_b: ArrayLike,
    rotation_b: ArrayLike,
    half_extents_b: ArrayLike,
) -> BoolArray:
    """
    Return whether two closed oriented boxes intersect, by the exact separating-axis test.

    The arguments broadcast over leading dimensions: centres (..., 3), rotations (..., 3, 3)
    whose columns are the box axes, half extents (..., 3) (>= 0, zero allowed). Candidate axes
    are the 3 + 3 box axes and their 9 cross products; a cross product of (nearly) parallel axes,
    norm below 1e-9, cannot separate and is skipped. Boxes that merely touch intersect.

    :return: boolean array of the broadcast leading shape.
    """
    axes_a = np.swapaxes(np.asarray(rotation_a, dtype=np.float64), -1, -2)  # rows = axes
    axes_b = np.swapaxes(np.asarray(rotation_b, dtype=np.float64), -1, -2)
    half_a = np.asarray(half_extents_a, dtype=np.float64)
    half_b = np.asarray(half_extents_b, dtype=np.float64)
    offset = np.asarray(center_b, dtype=np.float64) - np.asarray(center_a, dtype=np.float64)
    axes_a, axes_b = np.broadcast_arrays(axes_a, axes_b)
    edges = cross(axes_a[..., :, None, :], axes_b[..., None, :, :])  # edge-edge axes
    edges = edges.reshape(*edges.shape[:-3], 9, 3)
    norms = np.linalg.norm(edges, axis=-1, keepdims=True)
    usable = norms[..., 0] > 1e-9
    edges = edges / np.where(usable[..., None], norms, 1.0)
    candidates = np.concatenate([axes_a, axes_b, edges], axis=-2)  # (..., 15, 3)
    valid = np.concatenate([np.ones(usable.shape[:-1] + (6,), dtype=bool), usable], axis=-1)
    reach_a = np.einsum(
        '...lk,...k->...l', np.abs(candidates @ np.swapaxes(axes_a, -1, -2)), half_a
    )
    reach_b = np.einsum(
        '...lk,...k->...l', np.abs(candidates @ np.swapaxes(axes_b, -1, -2)), half_b
    )
    distance = np.abs(np.einsum('...ld,...d->...l', candidates, offset))
    separated = valid & (distance > reach_a + reach_b)
    return ~np.any(separated, axis=-1)


#: Box pairs tested for occlusion in one vectorised call: bounds the work arrays
#: (6 faces x pairs x 15 axes x 3) to a few megabytes whatever the number of boxes.
OCCLUSION_CHUNK = 2048


def _near_pairs(
    centers: FloatArray, radius: FloatArray, reach: float
) -> tuple[IndexArray, IndexArray]:
    """Return the ordered pairs (owner, other) of boxes whose spheres come within `reach`."""
    near = cKDTree(centers).query_ball_point(centers, radius + radius.max() + reach)
    counts = np.array([len(row) for row in near], dtype=np.intp)
    owner = np.repeat(np.arange(len(centers), dtype=np.intp), counts)
    other = np.concatenate([np.asarray(row, dtype=np.intp) for row in near])
    distinct = owner != other
    return owner[distinct], other[distinct]


def _occluded_faces(
    centers: FloatArray,
    rotations: FloatArray,
    extents: FloatArray,
    contact_tolerance: float | None,
    contact_fraction: float,
) -> BoolArray:
    """
    Return (B, 6) whether each face is occluded by another box (``docs/grasp_rules.md``).

    Only pairs of boxes close enough to touch are tested, in chunks of
    :data:`OCCLUSION_CHUNK`, so memory grows with the touching pairs, not with B x B.
    """
    count = len(centers)
    occluded = np.zeros((count, len(FACE_NAMES)), dtype=bool)
    if count < 2:
        return occluded
    scale = float(np.max(extents)) if extents.size else 0.0
    floor = 1e-9 * scale + 8.0 * np.finfo(float).eps * float(np.max(np.abs(centers)))
    sizes = box_sizes(extents)

    def pair_tolerance(owner: IndexArray, other: IndexArray) -> FloatArray:
        if contact_tolerance is None:
            tolerance = contact_fraction * np.minimum(sizes[owner], sizes[other])
        else:
            tolerance = np.full(len(owner), float(contact_tolerance))
        return tolerance + floor

    # Only pairs whose bounding spheres, the owner's grown by the slab's reach, meet can touch.
    radius = 0.5 * np.linalg.norm(extents, axis=1)
    largest = contact_fraction * float(sizes.max()) if contact_tolerance is None else 0.0
    owner_index, other_index = _near_pairs(
        centers, radius, max(largest, float(contact_tolerance or 0.0)) + 3.0 * floor
    )
    reach = pair_tolerance(owner_index, other_index) + 2.0 * floor
    distance = np.linalg.norm(centers[other_index] - centers[owner_index], axis=1)
    close = distance <= (radius[owner_index] + radius[other_index] + reach) * (1.0 + 1e-9)
    owner_index, other_index = owner_index[close], other_index[close]

    half = extents / 2.0
    faces = len(FACE_NAMES)
    axis_of = np.arange(faces) // 2
    signs = np.where(np.arange(faces) % 2 == 1, -1.0, 1.0)
    normals = signs[:, None, None] * np.moveaxis(rotations[:, :, axis_of], -1, 0)  # (6, B, 3)
    face_centers = centers[None, :, :] + normals * half[:, axis_of].T[:, :, None]
    for start in range(0, len(owner_index), OCCLUSION_CHUNK):
        chunk = slice(start, start + OCCLUSION_CHUNK)
        owner, other = owner_index[chunk], other_index[chunk]
        tolerance = pair_tolerance(owner, other)  # (P,)
        depth = tolerance + floor  # the slab reaches `floor` behind the face plane
        # Slab per (face, pair): inset by tol in-plane, from the face plane to tol outside.
        slab_half = np.broadcast_to(
            np.maximum(half[owner] - tolerance[:, None], 0.0), (faces, len(owner), 3)
        ).copy()
        slab_half[np.arange(faces), :, axis_of] = depth / 2.0
        offsets = (tolerance - depth / 2.0)[None, :, None]
        slab_centers = face_centers[:, owner, :] + normals[:, owner, :] * offsets
        hits = boxes_intersect(
            slab_centers,
            rotations[owner][None],
            slab_half,
            centers[other][None],
            rotations[other][None],
            half[other][None],
        )  # (6, P)
        for face in range(faces):
            occluded[owner[hits[face]], face] = True
    return occluded


def _unit(vector: ArrayLike, name: str, size: int = 3) -> FloatArray:
    out = np.asarray(vector, dtype=np.float64).reshape(-1)
    if out.shape != (size,) or not np.all(np.isfinite(out)):
        raise ValueError(f'{name} must be {size} finite numbers, got {vector!r}')
    norm = float(np.linalg.norm(out[:3]))
    if norm == 0.0:
        raise ValueError(f'{name} must have a non-zero direction, got {vector!r}')
    return out / norm


def _leaf_boxes(source: Decomposition | Sequence[Box]) -> tuple[list[Box], FloatArray | None]:
    """Return the leaf boxes and, for a decomposition, its kept points (else None)."""
    if isinstance(source, Decomposition):
        cloud = np.asarray(source.points, dtype=np.float64)[source.kept_point_indices]
        return list(source.leaves), cloud
    if isinstance(source, Box) or not isinstance(source, Sequence):
        raise TypeError(
            'grasp_hypotheses expects a Decomposition or a sequence of Box, '
            f'got {type(source).__name__}'
        )
    boxes = list(source)
    for box in boxes:
        if not isinstance(box, Box):
            raise TypeError(
                f'leaf boxes must be mvbb_ros.geometry.box.Box, got {type(box).__name__}'
            )
    return boxes, None


def _object_centroid(boxes: Sequence[Box], points: FloatArray | None) -> FloatArray:
    if points is not None and len(points):
        return points.mean(axis=0)
    centers = np.array([box.center for box in boxes])
    volumes = np.array([box.volume for box in boxes])
    if volumes.sum() > 0.0:
        return (centers * volumes[:, None]).sum(axis=0) / volumes.sum()
    return centers.mean(axis=0)


def _object_centres(boxes: Sequence[Box], points: FloatArray | None, view: _View) -> FloatArray:
    """Return per box the centre of its object (its points' mean, else its boxes' centroid)."""
    objects = np.array([view.object_index(i) for i in range(len(boxes))])
    centres = np.empty((len(boxes), 3))
    for number in np.unique(objects):
        mine = np.flatnonzero(objects == number)
        own = points if len(np.unique(objects)) == 1 else None
        centres[mine] = _object_centroid([boxes[int(i)] for i in mine], own)
    return centres


def _strategy_keys(
    strategy: str, boxes: Sequence[Box], points: FloatArray | None, sensor_origin: ArrayLike
) -> FloatArray:
    """Return per box a ranking key where larger is better."""
    volumes = np.array([box.volume for box in boxes])
    centers = np.array([box.center for box in boxes])
    if strategy == 'largest':
        return volumes
    if strategy == 'smallest':
        return -volumes
    if strategy == 'outermost':
        return np.linalg.norm(centers - _object_centroid(boxes, points), axis=1)
    origin = np.asarray(sensor_origin, dtype=np.float64).reshape(3)
    return -np.linalg.norm(centers - origin, axis=1)


def strategy_scores(
    strategy: Strategy,
    boxes: Sequence[Box],
    sensor_origin: ArrayLike = (0.0, 0.0, 0.0),
    points: FloatArray | None = None,
) -> FloatArray:
    """
    Return each box's strategy score in [0, 1] (1: the strategy's best box; the rules above).

    :param strategy: ``'largest'``, ``'smallest'``, ``'outermost'`` or ``'nearest'``.
    :param boxes: the leaf boxes, at least one.
    :param sensor_origin: the sensor position for ``'nearest'``.
    :param points: the object's points for the centroid of ``'outermost'`` (None: the boxes').
    :return: (B,) scores, min-max normalised over the boxes (all 1 when they tie).
    """
    return _normalised(_tie_rounded(_strategy_keys(strategy, boxes, points, sensor_origin)))


def gripper_quaternions(
    approaches: ArrayLike, closings: ArrayLike, approach_axis: ApproachAxis = 'z'
) -> FloatArray:
    """
    Return the gripper orientations (x, y, z, w; w >= 0) of approach and closing directions.

    :param approaches: (G, 3) unit approach directions.
    :param closings: (G, 3) unit closing directions, perpendicular to the approaches.
    :param approach_axis: the pose convention (``docs/grasp_rules.md``).
    :return: (G, 4) quaternions.
    """
    approach = np.asarray(approaches, dtype=np.float64).reshape(-1, 3)
    closing = np.asarray(closings, dtype=np.float64).reshape(-1, 3)
    if approach_axis == 'z':
        columns = (cross(closing, approach), closing, approach)
    else:
        columns = (approach, closing, cross(approach, closing))
    if not len(approach):
        return np.zeros((0, 4))
    return box_geometry.rotation_quaternions(np.stack(columns, axis=-1))


def _tie_rounded(keys: FloatArray) -> FloatArray:
    """Return `keys` rounded to 1e-9 of their largest magnitude, so rounding makes no order."""
    step = 1e-9 * float(np.max(np.abs(keys)))
    if step == 0.0 or not np.isfinite(step):
        return keys.copy()
    return np.round(keys / step) * step


def _normalised(keys: FloatArray) -> FloatArray:
    low, high = float(keys.min()), float(keys.max())
    if high - low <= 0.0:
        return np.ones_like(keys)
    return np.clip((keys - low) / (high - low), 0.0, 1.0)


# Public API -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _View:
    """What the grasps need to know of the sensor view: up, the sensor, the boxes' objects."""

    up: FloatArray | None
    sensor_origin: FloatArray
    object_indices: tuple[int, ...] | None

    @classmethod
    def of(
        cls, up: ArrayLike | None, sensor_origin: ArrayLike, object_indices: Sequence[int] | None
    ) -> _View:
        """Check and convert the view arguments of :func:`grasp_hypotheses`."""
        origin = np.asarray(sensor_origin, dtype=np.float64).reshape(-1)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise ValueError(f'sensor_origin must be 3 finite numbers, got {sensor_origin!r}')
        indices = None if object_indices is None else tuple(int(i) for i in object_indices)
        return cls(None if up is None else _unit(up, 'up'), origin, indices)

    def object_index(self, box: int) -> int:
        """Return the object of box `box` (0 when no objects were given)."""
        return 0 if self.object_indices is None else self.object_indices[box]


def _hypotheses(
    source: Decomposition | Sequence[Box],
    settings: GraspSettings,
    view: _View,
) -> tuple[list[Grasp], GraspStats]:
    """Return the ranked hypotheses (all of them, before ``max_grasps``) and the filter counts."""
    plane = (
        None
        if settings.support_plane is None
        else _unit(settings.support_plane, 'support_plane', size=4)
    )
    up_direction = view.up
    if up_direction is None and plane is not None:
        up_direction = plane[:3]

    boxes, points = _leaf_boxes(source)
    if not boxes:
        return [], GraspStats(0, 0, 0, 0, 0, 0, 0, 0)
    if view.object_indices is not None and len(view.object_indices) != len(boxes):
        raise ValueError(
            f'object_indices has {len(view.object_indices)} entries for {len(boxes)} boxes'
        )

    centers = np.array([box.center for box in boxes])
    rotations = np.array([box.rotation for box in boxes])
    extents = np.array([box.extents for box in boxes])
    count = len(boxes)
    n_faces, n_rolls = len(FACE_NAMES), len(ROLLS_DEG)

    # Hypotheses, shape (B, 6, 4, ...), face-major then roll.
    face_index = np.arange(n_faces)
    face_axis = face_index // 2
    face_sign = np.where(face_index % 2 == 0, 1.0, -1.0)
    normals = face_sign[None, :, None] * np.swapaxes(rotations, 1, 2)[:, face_axis, :]
    face_centers = centers[:, None, :] + normals * (extents[:, face_axis] / 2.0)[:, :, None]
    approach = -normals
    edge_axis = (face_axis + 1) % 3
    edge = np.swapaxes(rotations, 1, 2)[:, edge_axis, :]  # roll 0 closing, (B, 6, 3)
    turned = cross(approach, edge)  # edge turned by +90 degrees about approach
    roll_rad = np.deg2rad(np.array(ROLLS_DEG, dtype=np.float64))
    cos_roll = np.rint(np.cos(roll_rad))  # exactly 1, 0, -1, 0
    sin_roll = np.rint(np.sin(roll_rad))
    closing = (
        cos_roll[None, None, :, None] * edge[:, :, None, :]
        + sin_roll[None, None, :, None] * turned[:, :, None, :]
        + 0.0  # no negative zeros
    )
    other_axis = (face_axis + 2) % 3
    edge_widths = np.stack([extents[:, edge_axis], extents[:, other_axis]], axis=-1)  # (B, 6, 2)
    widths = edge_widths[:, :, np.array([0, 1, 0, 1])]  # (B, 6, 4)
    approach_per_roll = np.broadcast_to(approach[:, :, None, :], closing.shape)
    positions = np.broadcast_to(
        (face_centers + settings.standoff * normals)[:, :, None, :], closing.shape
    ).copy()

    # Filters.
    shape = (count, n_faces, n_rolls)
    occluded = _occluded_faces(
        centers, rotations, extents, settings.contact_tolerance, settings.contact_fraction
    )
    keep_occlusion = np.broadcast_to(~occluded[:, :, None], shape)
    keep_width = keep_occlusion & (widths <= settings.gripper_max_width)
    keep = keep_width.copy()
    if up_direction is not None:
        limit = np.sin(np.deg2rad(settings.max_approach_elevation_deg))
        keep &= approach_per_roll @ up_direction <= limit
    if plane is not None:
        half_span = (widths / 2.0)[..., None] * closing
        fingers_at_face = face_centers[:, :, None, :]
        heights = (
            np.stack(
                [
                    positions @ plane[:3],
                    (fingers_at_face + half_span) @ plane[:3],
                    (fingers_at_face - half_span) @ plane[:3],
                ]
            )
            + plane[3]
        )
        keep &= np.all(heights >= settings.support_clearance, axis=0)
    if not settings.far_side:
        centres = _object_centres(boxes, points, view)
        sight = centres - view.sensor_origin
        sight /= np.maximum(np.linalg.norm(sight, axis=1, keepdims=True), 1e-300)
        margin = np.sin(np.deg2rad(FAR_SIDE_MARGIN_DEG))
        keep &= np.einsum('bfrk,bk->bfr', approach_per_roll, sight) >= margin

    # Poses.
    if settings.approach_axis == 'z':
        columns = (cross(closing, approach_per_roll), closing, approach_per_roll)
    else:
        columns = (approach_per_roll, closing, cross(approach_per_roll, closing))
    gripper_rotations = np.stack(columns, axis=-1)  # (B, 6, 4, 3, 3)
    selected = np.argwhere(keep)  # lexicographic: box, face, roll
    quaternions = np.empty((len(selected), 4))
    if len(selected):
        quaternions = box_geometry.rotation_quaternions(gripper_rotations[keep])

    keys = _tie_rounded(_strategy_keys(settings.strategy, boxes, points, view.sensor_origin))
    scores = _normalised(keys)
    # Stable sort on the box key keeps (box, face, roll) order among ties.
    order = np.argsort(-keys[selected[:, 0]], kind='stable') if len(selected) else selected[:, 0]

    grasps = []
    for row in order:
        box_i, face_i, roll_i = (int(v) for v in selected[row])
        grasps.append(
            Grasp(
                position=read_only(positions[box_i, face_i, roll_i]),
                quaternion=read_only(quaternions[row]),
                approach=read_only(approach[box_i, face_i]),
                closing=read_only(closing[box_i, face_i, roll_i]),
                width=float(widths[box_i, face_i, roll_i]),
                box_index=box_i,
                face=face_i,
                roll_deg=ROLLS_DEG[roll_i],
                score=float(scores[box_i]),
                object_index=view.object_index(box_i),
                depth=settings.standoff,
            )
        )
    stats = GraspStats(
        boxes=count,
        faces=count * n_faces,
        faces_unoccluded=int(np.count_nonzero(~occluded)),
        faces_graspable=int(np.count_nonzero(keep.any(axis=2))),
        hypotheses=count * HYPOTHESES_PER_BOX,
        after_occlusion=int(np.count_nonzero(keep_occlusion)),
        after_width=int(np.count_nonzero(keep_width)),
        after_support=len(grasps),
    )
    return grasps, stats


def grasp_hypotheses(
    source: Decomposition | Sequence[Box],
    *,
    gripper_max_width: float = DEFAULT_GRIPPER_MAX_WIDTH,
    standoff: float = DEFAULT_STANDOFF,
    approach_axis: ApproachAxis = 'z',
    strategy: Strategy = 'largest',
    up: ArrayLike | None = None,
    support_plane: ArrayLike | None = None,
    support_clearance: float = DEFAULT_SUPPORT_CLEARANCE,
    max_approach_elevation_deg: float = DEFAULT_MAX_APPROACH_ELEVATION_DEG,
    contact_tolerance: float | None = None,
    contact_fraction: float = DEFAULT_CONTACT_FRACTION,
    sensor_origin: ArrayLike = (0.0, 0.0, 0.0),
    max_grasps: int = 0,
    object_indices: Sequence[int] | None = None,
    far_side: bool = True,
) -> list[Grasp]:
    """
    Return face-approach grasp hypotheses on leaf boxes, filtered and ranked (best first).

    ``docs/grasp_rules.md`` defines the hypotheses, the pose convention, occlusion, the support
    filter and the strategies precisely. All lengths are in the boxes' units (metres for
    sensor data; scale them for the millimetre GraspIt! models). The keyword arguments are the
    fields of :class:`GraspSettings`; :func:`grasp_filter_counts` takes the same and counts what
    each filter removes.

    :param source: a :class:`~mvbb_ros.geometry.decomposition.result.Decomposition` (its leaves,
        and its kept points for the object centroid of ``'outermost'``) or a sequence of
        :class:`~mvbb_ros.geometry.box.Box`.
    :param gripper_max_width: maximum opening of the gripper; wider hypotheses are removed
        (default 0.08 m, the Franka Hand).
    :param standoff: distance of the pre-grasp position from the face centre along the outward
        normal (>= 0, default 0.05 m).
    :param approach_axis: gripper axis that points along ``approach``, ``'z'`` (default) or
        ``'x'``; the fingers close along the gripper y axis.
    :param strategy: ``'largest'`` (default), ``'smallest'``, ``'outermost'`` or ``'nearest'``.
    :param up: up direction (3,) in the boxes' frame (any length); enables the direction test.
    :param support_plane: (a, b, c, d), plane ``a x + b y + c z + d = 0`` with (a, b, c) up;
        enables the direction test (with its normal as ``up`` unless ``up`` is given) and the
        clearance test.
    :param support_clearance: minimum height above the support plane of the pre-grasp position
        and of both fingers at the face (default 0.01 m).
    :param max_approach_elevation_deg: approaches pointing upwards by more than this many
        degrees above the horizontal are removed (default 45, in [0, 90]).
    :param contact_tolerance: absolute occlusion tolerance; None (default) uses
        ``contact_fraction``.
    :param contact_fraction: relative occlusion tolerance used when ``contact_tolerance`` is None
        (default 0.1, of the smaller middle extent of the two boxes).
    :param sensor_origin: sensor position (3,) for ``'nearest'`` (default the frame origin).
    :param max_grasps: return at most this many, best first (default 0: all).
    :param object_indices: the object each box belongs to (one per box), copied to
        :attr:`Grasp.object_index`; None: all 0.
    :param far_side: keep approaches from the far side of their object as seen from
        ``sensor_origin`` (default True, the paper); False removes those whose approach points
        back towards the sensor (``docs/grasp_rules.md``).
    :return: the surviving hypotheses sorted best first.
    :raises ValueError: on an unknown strategy or approach axis, or an invalid parameter.
    :raises TypeError: when the input is neither a decomposition nor a sequence of boxes.
    """
    settings = GraspSettings(
        gripper_max_width=gripper_max_width,
        standoff=standoff,
        approach_axis=approach_axis,
        strategy=strategy,
        support_plane=None if support_plane is None else _floats(support_plane),
        support_clearance=support_clearance,
        max_approach_elevation_deg=max_approach_elevation_deg,
        contact_tolerance=contact_tolerance,
        contact_fraction=contact_fraction,
        max_grasps=max_grasps,
        far_side=far_side,
    )
    grasps, _ = _hypotheses(source, settings, _View.of(up, sensor_origin, object_indices))
    return grasps[: settings.max_grasps] if settings.max_grasps > 0 else grasps


def grasp_filter_counts(
    source: Decomposition | Sequence[Box],
    *,
    up: ArrayLike | None = None,
    sensor_origin: ArrayLike = (0.0, 0.0, 0.0),
    object_indices: Sequence[int] | None = None,
    **options: Any,
) -> GraspStats:
    """
    Return how many hypotheses of :func:`grasp_hypotheses` survive each filter, in order.

    :param source: as for :func:`grasp_hypotheses`.
    :param up: as for :func:`grasp_hypotheses`.
    :param sensor_origin: as for :func:`grasp_hypotheses`.
    :param object_indices: as for :func:`grasp_hypotheses`.
    :param options: the fields of :class:`GraspSettings`; ``max_grasps`` is no filter and does
        not change the counts.
    :return: the counts: faces and hypotheses before any filter, after occlusion, after the
        width filter and after the support filter.
    :raises ValueError: for an invalid option.
    :raises TypeError: when the input is neither a decomposition nor a sequence of boxes.
    """
    view = _View.of(up, sensor_origin, object_indices)
    return _hypotheses(source, GraspSettings(**options), view)[1]
