"""
The scene stage: the support plane under the objects, and what stands on it.

A table-top frame holds the table, what stands on it, and walls and floor around; a segmented
object holds one object. :func:`find_scene` tells them apart and reduces a scene to what stands
on its table:

1. **Plane**: a RANSAC plane fit (:mod:`mvbb_ros.pipeline.plane`: random triples of a
   fixed-seed sample of the points, each scored on that sample; the best refitted by least
   squares on its inliers until it settles), then the largest connected patch of its inliers on
   a grid in the plane (:mod:`mvbb_ros.pipeline.outline`: the table, not every point at table
   height in the room), refitted on that patch. The normal is turned towards the viewpoint (the
   sensor looks at the table's top). With ``up`` known, only planes within
   :data:`MAX_TILT_DEG` of it are tried.
2. **Outline**: the convex hull of the patch's points projected into the plane.
3. **Standing points**: more than ``support_distance`` above the plane (on the sensor's side),
   at most ``support_max_height`` above it, and at least ``support_margin`` inside the
   outline. The table, what lies below it (the floor) and what stands beside or behind it
   (walls, whose foot is the outline's edge) are dropped.
4. **Decision** (``support_plane: auto``): the plane is a support only when (a) its patch holds
   at least ``support_min_fraction`` of the points, (b) at least ``min_points`` points stand on
   it, and (c) the outline reaches at least :data:`EXTEND_M` beyond the standing points'
   footprint in at least :data:`EXTEND_DIRECTIONS_MIN` of :data:`EXTEND_DIRECTIONS` directions
   in the plane (a table reaches past its objects; a face of an object does not reach past the
   rest of the object, and a convex object has nothing on the sensor's side of its faces, so
   it fails (b)), and (d) no plane among the standing points holds :data:`WALL_SHARE` of the
   plane's own points and is :data:`WALL_WIDTH_M` wide (then the plane is a wall and the table
   stands on it), and (e) with ``up`` given, the refitted plane is within
   :data:`MAX_TILT_DEG` of it. Up to :data:`CANDIDATES` planes are tried, largest first; the
   first that passes is the support.
   Otherwise the cloud is an already segmented object and passes unchanged.

On a camera frame the pipeline (:func:`mvbb_ros.pipeline.process.process_points`) runs
:func:`find_scene` on the voxel grid of every k-th point (``process.scene_sample``, about 16k
points), then :func:`standing_mask` cuts the whole frame to what stands on the table in one
compiled pass, and only those points go through the voxel grid and the outlier removal.

``support_plane: fixed`` takes the plane ``a x + b y + c z + d = 0`` from
``support_coefficients`` ((a, b, c) pointing up, out of the table's top) and skips the fit and
the decision. The region of interest (``roi_max_distance``, metres from the viewpoint) is
applied before the filters (:func:`roi_mask`), so a room-sized cloud is cut down to the work
surface before anything costly. Pure numpy and scipy: the plane fit is cheap on a sample, and
keeps Open3D out of the node's start.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, get_args, Literal

from mvbb_ros.arrays import BoolArray, FloatArray, IndexArray, perpendicular_axes
from mvbb_ros.pipeline.outline import half_planes, inside_outline, largest_patch, outline_2d
from mvbb_ros.pipeline.plane import fit_plane, MAX_TILT_DEG, plane_through
from numba import njit, types
import numpy as np
from numpy.typing import ArrayLike, NDArray

#: What finds the support plane (the first is the library default): ``none`` (the cloud is one
#: segmented object: the paper), ``auto`` (fit it, keep it only when the cloud is a scene) or
#: ``fixed`` (``support_coefficients``).
SupportMode = Literal['none', 'auto', 'fixed']
SUPPORT_MODES: tuple[SupportMode, ...] = get_args(SupportMode)


@dataclass(frozen=True)
class SceneSettings:
    """
    The settings of the scene stage; the defaults are the paper's (no scene: one object).

    :ivar support_plane: ``none``, ``auto`` or ``fixed`` (the module doc).
    :ivar support_coefficients: (a, b, c, d) of the fixed plane ``a x + b y + c z + d = 0``,
        (a, b, c) pointing up; used with ``fixed`` only.
    :ivar support_distance: points this close to the plane (metres) are the table.
    :ivar support_max_height: what stands higher above the plane (metres) is dropped.
    :ivar support_margin: standing points lie at least this far inside the outline (metres).
    :ivar support_min_fraction: the fitted plane's patch holds at least this share of the
        points (``auto``).
    :ivar roi_max_distance: points farther than this from the viewpoint (metres) are dropped
        before anything else; 0 keeps them all.
    """

    support_plane: SupportMode = 'none'
    support_coefficients: tuple[float, ...] = ()
    support_distance: float = 0.01
    support_max_height: float = 0.5
    support_margin: float = 0.02
    support_min_fraction: float = 0.15
    roi_max_distance: float = 0.0


#: The grid of the inlier patch: this many point spacings, at least :data:`PATCH_CELL_MIN_M`.
PATCH_CELLS = 4.0
PATCH_CELL_MIN_M = 0.01
#: At most this many planes are tried as the support, largest first (each fitted to the points
#: the previous ones' patches left).
CANDIDATES = 3
#: A plane with another plane standing on it that holds this share of its own patch's points
#: and is this wide (metres, its narrower side) is a wall with the table in front of it: an
#: object's face is much smaller than its table.
WALL_SHARE = 0.1
WALL_WIDTH_M = 0.35
#: The decision's reach: the outline must pass the standing footprint by this much (metres)...
EXTEND_M = 0.05
#: ... in at least this many of these many evenly spread directions in the plane.
EXTEND_DIRECTIONS = 8
EXTEND_DIRECTIONS_MIN = 6


@dataclass(frozen=True, eq=False)
class SupportPlane:
    """
    The plane the objects stand on, in the cloud's frame.

    :ivar normal: (3,) unit normal, pointing up (to the sensor's side).
    :ivar offset: d of ``normal . x + d = 0`` (metres).
    :ivar outline: (K, 3) the table's outline in the plane, counter-clockwise seen from above
        (K = 0 when a fixed plane has no points near it).
    :ivar inliers: how many of the points the plane was fitted on lie on the table (its patch;
        for a large cloud, of the scene stage's sample: ``process.scene_sample``).
    :ivar fixed: the plane was given (``fixed``), not fitted.
    """

    normal: FloatArray
    offset: float
    outline: FloatArray
    inliers: int
    fixed: bool = False

    @property
    def coefficients(self) -> tuple[float, float, float, float]:
        """Return (a, b, c, d) of ``a x + b y + c z + d = 0``, (a, b, c) the unit normal."""
        a, b, c = (float(v) for v in self.normal)
        return a, b, c, float(self.offset)

    def heights(self, points: ArrayLike) -> FloatArray:
        """Return the signed heights of `points` (N, 3) above the plane, metres."""
        return np.asarray(points, dtype=np.float64) @ self.normal + self.offset


@dataclass(frozen=True, eq=False)
class Scene:
    """
    What the scene stage found.

    :ivar support: the support plane, or None (the cloud is one segmented object).
    :ivar kept: indices of the points that stand on the support (sorted), or None for all.
    :ivar reason: why there is no support (``auto``), else None.
    """

    support: SupportPlane | None
    kept: IndexArray | None
    reason: str | None = None


def roi_mask(
    points: FloatArray,
    viewpoint: ArrayLike,
    max_distance: float,
    bounds: ArrayLike | None = None,
) -> BoolArray | None:
    """
    Return which `points` lie within `max_distance` of `viewpoint`, None when all do.

    :param bounds: ``(2, 3)`` min and max corners of the points when known: when the box's
        farthest corner is well within reach, no point is looked at.
    """
    if max_distance <= 0.0 or len(points) == 0:
        return None
    eye = np.asarray(viewpoint, dtype=np.float64)
    if bounds is not None:
        corners = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        farthest = np.maximum(np.abs(corners[0] - eye), np.abs(corners[1] - eye))
        # A margin for the rounding of the per-point test (float32 points).
        if float(np.linalg.norm(farthest)) <= max_distance * (1.0 - 1e-6):
            return None
    inside = _within(_readonly(points), eye, float(max_distance) ** 2)
    return None if bool(inside.all()) else inside


def _readonly(points: NDArray[np.floating]) -> NDArray[np.floating]:
    """Return `points` (N, 3) as a C-contiguous read-only float32 or float64 view (no copy)."""
    array = np.asarray(points)
    if array.dtype not in (np.float32, np.float64):
        array = array.astype(np.float64)
    array = np.ascontiguousarray(array).view()
    array.flags.writeable = False  # the kernels' signatures: one for any input
    return array


@njit(
    [
        types.boolean[::1](
            types.Array(dtype, 2, 'C', readonly=True), types.float64[::1], types.float64
        )
        for dtype in (types.float32, types.float64)
    ],
    cache=True,
    nogil=True,
)
def _within(points: Any, eye: Any, squared: Any) -> Any:
    """Tell which points lie within sqrt(`squared`) of `eye` (in float64)."""
    inside = np.empty(points.shape[0], dtype=np.bool_)
    for i in range(points.shape[0]):
        dx = np.float64(points[i, 0]) - eye[0]
        dy = np.float64(points[i, 1]) - eye[1]
        dz = np.float64(points[i, 2]) - eye[2]
        inside[i] = dx * dx + dy * dy + dz * dz <= squared
    return inside


def _reach(outline: FloatArray, footprint: FloatArray) -> int:
    """Return in how many of the directions the outline passes `footprint` by EXTEND_M."""
    angles = np.arange(EXTEND_DIRECTIONS) * (2.0 * math.pi / EXTEND_DIRECTIONS)
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    beyond = (outline @ directions.T).max(axis=0) - (footprint @ directions.T).max(axis=0)
    return int(np.count_nonzero(beyond >= EXTEND_M))


def _width(flat: FloatArray) -> float:
    """Return the narrower side of the principal-axes rectangle of `flat` (N, 2)."""
    centred = flat - flat.mean(axis=0)
    axes = np.linalg.eigh(centred.T @ centred)[1]
    return float(np.min(np.ptp(centred @ axes, axis=0)))


def _frame(normal: FloatArray) -> FloatArray:
    """Return (2, 3) in-plane axes making a right-handed frame with `normal`."""
    first, second = perpendicular_axes(normal)
    return np.stack([first, second])


@dataclass(frozen=True, eq=False)
class _Candidate:
    """A plane of the cloud: its (oriented) normal and offset, and its patch's point indices."""

    normal: FloatArray
    offset: float
    patch: IndexArray


def _oriented(normal: FloatArray, offset: float, eye: FloatArray) -> tuple[FloatArray, float]:
    """Return the plane turned so that `eye` lies on its positive side."""
    return (-normal, -offset) if normal @ eye + offset < 0.0 else (normal, offset)


def _patch(
    points: FloatArray, normal: FloatArray, offset: float, distance: float, cell: float
) -> IndexArray:
    """Return the indices of the largest connected patch of the plane's inliers."""
    near = np.flatnonzero(np.abs(points @ normal + offset) <= distance)
    if len(near) < 3:
        return near
    return near[largest_patch(points[near] @ _frame(normal).T, cell)]


def _next_plane(
    points: FloatArray,
    rest: BoolArray,
    distance: float,
    up: FloatArray | None,
    eye: FloatArray,
    cell: float,
) -> _Candidate | None:
    """Return the largest plane among the `rest` of `points`, refitted on its patch."""
    indices = np.flatnonzero(rest)
    # One copy of the rest, none of all the points (the same array as a copy would be).
    whole = len(indices) == len(points) and points.flags.c_contiguous
    subset = points if whole else points[indices]
    plane = fit_plane(subset, distance, up)
    if plane is None:
        return None
    patch = indices[_patch(subset, *plane, distance, cell)]
    if len(patch) < 3:
        return None
    normal, offset = _oriented(*plane_through(points[patch]), eye)
    return _Candidate(normal, offset, patch)


def _standing(
    points: FloatArray,
    normal: FloatArray,
    offset: float,
    outline: FloatArray,
    settings: SceneSettings,
    heights: FloatArray | None = None,
) -> BoolArray:
    """
    Tell which `points` stand on the plane, inside its (2D) `outline`.

    :param heights: ``points @ normal + offset`` when already measured, else None.
    """
    if heights is None:
        heights = points @ normal + offset
    standing = (heights > settings.support_distance) & (heights <= settings.support_max_height)
    candidates = np.flatnonzero(standing)
    flat = points[candidates] @ _frame(normal).T
    standing[candidates] = inside_outline(flat, outline, settings.support_margin)
    return standing


def find_scene(
    points: FloatArray,
    settings: SceneSettings,
    *,
    viewpoint: ArrayLike = (0.0, 0.0, 0.0),
    up: ArrayLike | None = None,
    spacing: float,
    min_points: int,
) -> Scene:
    """
    Find the support plane of `points` (N, 3) float64, metres, and what stands on it.

    :param points: the filtered points.
    :param settings: the stage's settings.
    :param viewpoint: (3,) the sensor position in the points' frame.
    :param up: the up direction given by the user, or None.
    :param spacing: the point spacing (metres): the grid of the table's patch.
    :param min_points: the fewest standing points of a scene (``auto``).
    :return: the scene; without a support (``none``, or ``auto`` on a segmented object) every
        point is kept.
    """
    mode = settings.support_plane
    if mode == 'none' or len(points) < 3:
        return Scene(None, None, 'support_plane: none' if mode == 'none' else 'too few points')
    eye = np.asarray(viewpoint, dtype=np.float64)
    unit_up = None
    if up is not None:
        unit_up = np.asarray(up, dtype=np.float64)
        unit_up = unit_up / np.linalg.norm(unit_up)
    distance = settings.support_distance
    cell = max(PATCH_CELLS * spacing, PATCH_CELL_MIN_M)
    if mode == 'fixed':
        coefficients = np.asarray(settings.support_coefficients, dtype=np.float64)
        scale = float(np.linalg.norm(coefficients[:3]))
        normal, offset = coefficients[:3] / scale, float(coefficients[3]) / scale
        patch = _patch(points, normal, offset, distance, cell)
        outline = outline_2d(points[patch] @ _frame(normal).T)
        kept = np.flatnonzero(_standing(points, normal, offset, outline, settings))
        return Scene(_support(normal, offset, outline, len(patch), True), kept)
    rest = np.ones(len(points), dtype=bool)
    least = max(3, settings.support_min_fraction * len(points))
    reasons = []
    for number in range(CANDIDATES):
        if np.count_nonzero(rest) < least:
            break  # no patch of the points left can hold support_min_fraction of them
        candidate = _next_plane(points, rest, distance, unit_up, eye, cell)
        if candidate is None or len(candidate.patch) < least:
            break
        rest[candidate.patch] = False
        normal, offset = candidate.normal, candidate.offset
        if unit_up is not None and abs(normal @ unit_up) < math.cos(math.radians(MAX_TILT_DEG)):
            tilt = math.degrees(math.acos(min(1.0, abs(float(normal @ unit_up)))))
            reasons.append(f'plane {number}: tilted {tilt:.0f} deg from up_direction')
            continue
        heights = points @ normal + offset
        if min_points > 0 and not np.any(
            (heights > settings.support_distance) & (heights <= settings.support_max_height)
        ):
            # Nothing above it at all (a segmented object's face, the object behind it): no
            # outline needed to say that nothing stands on it.
            reasons.append(f'plane {number}: 0 points stand on it')
            continue
        frame = _frame(normal)
        outline = outline_2d(points[candidate.patch] @ frame.T)
        kept = np.flatnonzero(_standing(points, normal, offset, outline, settings, heights))
        if len(kept) < min_points:
            reasons.append(f'plane {number}: {len(kept)} points stand on it')
            continue
        standing = points[kept]
        reach = _reach(outline, standing @ frame.T)
        if reach < EXTEND_DIRECTIONS_MIN:
            reasons.append(
                f'plane {number}: reaches past what stands on it in {reach} of '
                f'{EXTEND_DIRECTIONS} directions'
            )
            continue
        # A table in front of a wall stands on the wall: a large plane among the standing points
        # says that this plane is the wall (none when too few points stand on it to make one).
        other = None
        if len(kept) >= WALL_SHARE * len(candidate.patch):
            whole = np.ones(len(kept), dtype=bool)
            other = _next_plane(standing, whole, distance, None, eye, cell)
        if (
            other is not None
            and len(other.patch) >= WALL_SHARE * len(candidate.patch)
            and _width(standing[other.patch] @ _frame(other.normal).T) >= WALL_WIDTH_M
        ):
            reasons.append(f'plane {number}: another large plane stands on it (a wall?)')
            continue
        return Scene(_support(normal, offset, outline, len(candidate.patch), False), kept)
    if not reasons:
        return Scene(
            None,
            None,
            'no plane holds support_min_fraction '
            f'{100 * settings.support_min_fraction:g} % of the points',
        )
    return Scene(None, None, 'no support: ' + '; '.join(reasons))


@njit(
    [
        types.boolean[::1](
            types.Array(dtype, 2, 'C', readonly=True),
            types.float64[::1],
            types.float64,
            types.float64[:, ::1],
            types.float64[:, ::1],
            types.float64[::1],
            types.float64,
            types.float64,
        )
        for dtype in (types.float32, types.float64)
    ],
    cache=True,
    nogil=True,
)
def _standing_kernel(
    points: Any,
    normal: Any,
    offset: Any,
    frame: Any,
    outward: Any,
    limits: Any,
    low: Any,
    high: Any,
) -> Any:
    """Tell which points lie in (low, high] above the plane and inside every half-plane."""
    standing = np.zeros(points.shape[0], dtype=np.bool_)
    for i in range(points.shape[0]):
        x, y, z = np.float64(points[i, 0]), np.float64(points[i, 1]), np.float64(points[i, 2])
        height = normal[0] * x + normal[1] * y + normal[2] * z + offset
        if not (low < height <= high):
            continue
        u = frame[0, 0] * x + frame[0, 1] * y + frame[0, 2] * z
        v = frame[1, 0] * x + frame[1, 1] * y + frame[1, 2] * z
        inside = True
        for k in range(outward.shape[0]):
            if outward[k, 0] * u + outward[k, 1] * v > limits[k]:
                inside = False
                break
        standing[i] = inside
    return standing


def standing_mask(
    points: NDArray[np.floating], support: SupportPlane, settings: SceneSettings
) -> BoolArray:
    """
    Tell which `points` (N, 3), float32 or float64, stand on `support` (as in :func:`find_scene`).

    More than ``support_distance`` and at most ``support_max_height`` above the plane, at least
    ``support_margin`` inside its outline (every point counts when it has no outline). One pass
    over the points, no copies: the scene stage's cut of a whole frame.
    """
    frame = np.ascontiguousarray(_frame(support.normal))
    outline = support.outline @ frame.T
    if len(outline) >= 3:
        outward, limits = half_planes(outline)
        limits = limits - settings.support_margin
    else:
        outward, limits = np.empty((0, 2)), np.empty(0)
    return _standing_kernel(
        _readonly(points),
        np.ascontiguousarray(support.normal, dtype=np.float64),
        float(support.offset),
        frame,
        np.ascontiguousarray(outward),
        np.ascontiguousarray(limits),
        float(settings.support_distance),
        float(settings.support_max_height),
    )


def _support(
    normal: FloatArray, offset: float, outline: FloatArray, inliers: int, fixed: bool
) -> SupportPlane:
    """Return the support plane with its 2D `outline` put into 3D."""
    corners = outline @ _frame(normal) - offset * normal if len(outline) else np.empty((0, 3))
    return SupportPlane(normal, offset, corners, inliers, fixed)


def warm_up() -> None:
    """Run every kernel of this module once (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5)), -1).reshape(-1, 2)
    flat = np.column_stack([grid, np.zeros(len(grid))])
    outline = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    support = SupportPlane(np.array([0.0, 0.0, 1.0]), 0.0, outline, len(flat))
    for dtype in (np.float32, np.float64):
        roi_mask(flat.astype(dtype), (0.0, 0.0, 0.0), 1.0)
        standing_mask(flat.astype(dtype) + [0.0, 0.0, 0.1], support, SceneSettings())


__all__ = [
    'find_scene',
    'fit_plane',
    'inside_outline',
    'roi_mask',
    'Scene',
    'SceneSettings',
    'SUPPORT_MODES',
    'SupportMode',
    'standing_mask',
    'SupportPlane',
]
