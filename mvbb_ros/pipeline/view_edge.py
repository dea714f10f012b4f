"""
The view's edge: which objects of a raw frame the sensor saw only in part, cut by the frame.

A camera frame ends where the image (or its valid depth) ends; an object standing across that
edge is seen in part, and its boxes and grasps stand for a piece of it. :func:`view_outline`
finds the frame's outline as the sensor sees it: every point's direction from the viewpoint,
put on the plane one unit from the viewpoint across the frame's mean direction (the gnomonic
projection: straight edges of the image stay straight), and the convex hull there.
:func:`edge_gaps` says how far inside that outline points lie, in that plane's units (radians
near the frame's centre).

An object is cut by the view (:func:`cut_by_view`) when it comes within ``view_edge_margin_deg``
of the view's outline. The scene stage keeps what stands at least ``support_margin`` inside the
table's outline, so an object cut by the view where the view also cuts the table loses that
strip and ends a little inside the view: the points of that strip next to the object count as
the object's here. The pipeline measures it on scene frames only (a support plane found, so
the frame reaches past its objects); grasps of cut objects come after those of whole objects
(``docs/grasp_rules.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

from mvbb_ros.arrays import FloatArray, perpendicular_axes
from mvbb_ros.pipeline.outline import half_planes, outline_2d
from numba import njit, types
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

#: A frame whose points lie further than this from its mean direction (degrees) is not one
#: camera's view (a spinning LiDAR's sweep): it has no outline here.
MAX_HALF_ANGLE_DEG = 75.0
#: Points nearer the viewpoint than this (metres) have no direction and are left out (some
#: depth drivers write a pixel without depth as the point (0, 0, 0)).
NEAR_M = 1e-3


@dataclass(frozen=True, eq=False)
class ViewOutline:
    """
    The convex outline of a frame as seen from its viewpoint, on the plane across its centre.

    :ivar viewpoint: (3,) the sensor position (metres).
    :ivar axes: (3, 3) rows: the two in-plane axes, then the frame's mean direction (unit).
    :ivar outward: (K, 2) the outline's outward edge normals (unit).
    :ivar limits: (K,) the outline's edges: a point ``q`` is inside when ``outward @ q <= limits``.
    """

    viewpoint: FloatArray
    axes: FloatArray
    outward: FloatArray
    limits: FloatArray


def view_outline(points: NDArray[np.floating], viewpoint: ArrayLike) -> ViewOutline | None:
    """
    Return the outline of the frame `points` (N, 3), metres, seen from `viewpoint`.

    None when the points do not make one view: fewer than 3 (of those at least :data:`NEAR_M`
    from the viewpoint), any further than :data:`MAX_HALF_ANGLE_DEG` from their mean direction,
    or all on one line of sight.
    """
    eye = np.ascontiguousarray(viewpoint, dtype=np.float64)
    array = np.ascontiguousarray(points)
    if array.dtype not in (np.float32, np.float64):
        array = array.astype(np.float64)
    if len(array) < 3:
        return None
    array = array.view()
    array.flags.writeable = False  # the kernels' signatures: one for any input
    centre = _mean_direction(array, eye, NEAR_M)
    norm = float(np.linalg.norm(centre))
    if not norm > 0.0:  # no point away from the viewpoint, or the directions cancel
        return None
    centre /= norm
    first, second = perpendicular_axes(centre)
    axes = np.stack([first, second, centre])
    flat = np.empty((len(array), 2))
    kept = _project(array, eye, axes, math.cos(math.radians(MAX_HALF_ANGLE_DEG)), NEAR_M, flat)
    if kept < 3:  # a point too far from the centre (-1), or too few
        return None
    hull = outline_2d(flat[:kept])
    if len(hull) < 3:
        return None
    return ViewOutline(eye, axes, *half_planes(hull))


_SIGNATURES = [
    types.Array(dtype, 2, 'C', readonly=True) for dtype in (types.float32, types.float64)
]


@njit
def _ray(points: Any, i: Any, eye: Any) -> Any:
    """Return point `i` of `points` less `eye` (x, y, z in float64), and its length."""
    x = np.float64(points[i, 0]) - eye[0]
    y = np.float64(points[i, 1]) - eye[1]
    z = np.float64(points[i, 2]) - eye[2]
    return x, y, z, math.sqrt(x * x + y * y + z * z)


@njit
def _local(x: Any, y: Any, z: Any, axes: Any) -> Any:
    """Return the ray (x, y, z) along ``axes[2]``, ``axes[0]`` and ``axes[1]`` (not divided)."""
    depth = axes[2, 0] * x + axes[2, 1] * y + axes[2, 2] * z
    first = axes[0, 0] * x + axes[0, 1] * y + axes[0, 2] * z
    second = axes[1, 0] * x + axes[1, 1] * y + axes[1, 2] * z
    return depth, first, second


@njit(
    [types.float64[::1](array, types.float64[::1], types.float64) for array in _SIGNATURES],
    cache=True,
    nogil=True,
)
def _mean_direction(points: Any, eye: Any, near: Any) -> Any:
    """Return the sum of the unit directions from `eye` to those `points` at least `near` away."""
    total = np.zeros(3)
    for i in range(points.shape[0]):
        x, y, z, length = _ray(points, i, eye)
        if not length >= near:
            continue
        total[0] += x / length
        total[1] += y / length
        total[2] += z / length
    return total


@njit(
    [
        types.int64(
            array,
            types.float64[::1],
            types.float64[:, ::1],
            types.float64,
            types.float64,
            types.float64[:, ::1],
        )
        for array in _SIGNATURES
    ],
    cache=True,
    nogil=True,
)
def _project(points: Any, eye: Any, axes: Any, cosine: Any, near: Any, flat: Any) -> Any:
    """
    Put the `points` at least `near` from `eye` on the plane, in order, into `flat`.

    Return how many; -1 when one lies further from ``axes[2]`` than `cosine` allows.
    """
    kept = 0
    for i in range(points.shape[0]):
        x, y, z, length = _ray(points, i, eye)
        if not length >= near:
            continue
        depth, first, second = _local(x, y, z, axes)
        if not depth > cosine * length:
            return -1
        flat[kept, 0] = first / depth
        flat[kept, 1] = second / depth
        kept += 1
    return kept


def edge_gaps(outline: ViewOutline, points: ArrayLike) -> FloatArray:
    """
    Return how far inside `outline` each of `points` (N, 3) lies, in its plane's units.

    About radians near the frame's centre (the plane is one unit from the viewpoint); negative
    outside (the outline is measured on a sample of the frame); -inf for points not in front
    of the viewpoint along the frame's mean direction.
    """
    array = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    array.flags.writeable = False
    gaps = np.empty(len(array))
    _gaps(
        array,
        outline.viewpoint,
        outline.axes,
        np.ascontiguousarray(outline.outward),
        outline.limits,
        gaps,
    )
    return gaps


@njit(
    [
        types.void(
            array,
            types.float64[::1],
            types.float64[:, ::1],
            types.float64[:, ::1],
            types.float64[::1],
            types.float64[::1],
        )
        for array in _SIGNATURES[1:]
    ],
    cache=True,
    nogil=True,
)
def _gaps(points: Any, eye: Any, axes: Any, outward: Any, limits: Any, gaps: Any) -> None:
    """Put each point's least distance inside the outline's half-planes into `gaps`."""
    for i in range(points.shape[0]):
        x, y, z, _ = _ray(points, i, eye)
        depth, first, second = _local(x, y, z, axes)
        if not depth > 0.0:
            gaps[i] = -np.inf
            continue
        u, v = first / depth, second / depth
        least = np.inf
        for k in range(limits.shape[0]):
            least = min(least, limits[k] - (outward[k, 0] * u + outward[k, 1] * v))
        gaps[i] = least


@dataclass(frozen=True)
class ViewEdge:
    """
    How far an object reaches towards the view's edge.

    :ivar gap_deg: how far inside the view's outline its nearest point lies (degrees; with the
        table's border strip next to it, :func:`cut_by_view`).
    :ivar cut: the gap is under ``view_edge_margin_deg``: the view cuts the object.
    """

    gap_deg: float
    cut: bool


def cut_by_view(
    outline: ViewOutline,
    points: ArrayLike,
    margin_deg: float,
    strip: ArrayLike | None = None,
    reach: float = 0.0,
) -> ViewEdge:
    """
    Return how far the object of `points` (N, 3) reaches towards the view's edge, and if cut.

    :param strip: (M, 3) the points the scene stage dropped along the table's outline (its
        ``support_margin`` strip, above the table), or None.
    :param reach: the strip's points within this distance (metres) of the object's belong to
        it: the object reaches as far as they do.
    """
    array = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    gap = float(edge_gaps(outline, array).min())
    band = np.empty((0, 3)) if strip is None else np.asarray(strip, dtype=np.float64)
    # Only the strip's points within the object's box grown by `reach` can touch it.
    low, high = array.min(axis=0) - reach, array.max(axis=0) + reach
    band = band.reshape(-1, 3)
    band = band[np.all((band >= low) & (band <= high), axis=1)]
    if len(band) and reach > 0.0:
        distances = cKDTree(array).query(band, distance_upper_bound=reach)[0]
        touching = band[np.isfinite(distances)]
        if len(touching):
            gap = min(gap, float(edge_gaps(outline, touching).min()))
    gap_deg = math.degrees(gap)
    return ViewEdge(gap_deg, gap_deg < margin_deg)


def warm_up() -> None:
    """Run every kernel of this module once (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 4), np.linspace(-1, 1, 4)), -1).reshape(-1, 2)
    frame = np.column_stack([grid, np.full(len(grid), 2.0)])
    for dtype in (np.float32, np.float64):
        outline = view_outline(frame.astype(dtype), (0.0, 0.0, 0.0))
    if outline is not None:
        edge_gaps(outline, frame)


__all__ = [
    'cut_by_view',
    'edge_gaps',
    'MAX_HALF_ANGLE_DEG',
    'NEAR_M',
    'view_outline',
    'ViewEdge',
    'ViewOutline',
]
