"""
The mirror plane of a single view: the plane about which the seen side mirrors onto the hidden.

:func:`find_mirror_plane` (Bohg et al., "Mind the Gap", ICRA 2011) tries candidate planes and
keeps the one whose mirror image contradicts the view least (a mirrored point the sensor would
have seen, in front of a seen surface or where it saw past the object), then the nearest to the
sensor. With an up direction the planes are vertical (the object stands on a support); without
one, planes turned up to 35 degrees from the viewing direction are tried.
:func:`plane_violations` counts the contradictions of many planes against the view's raster
(:mod:`mvbb_ros.geometry.views.raster`) in a numba kernel. The shape completion
(:mod:`mvbb_ros.geometry.views.completion`) mirrors the seen side about the plane found;
``docs/single_views.md`` describes the search and what it measures.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import math

from mvbb_ros.arrays import (
    BoolArray,
    column_span,
    cross,
    FloatArray,
    IndexArray,
    lexicographic_order,
    perpendicular_axes,
    read_only,
)
from mvbb_ros.common.workers import split_rows, Workers
from mvbb_ros.geometry.boxfit.rectangle import hull_2d_kernel
from mvbb_ros.geometry.views.fill import cached_perpendicular_axes
from mvbb_ros.geometry.views.raster import pixel, view_raster, ViewRaster
import numba as nb
import numpy as np

#: Points of the observed cloud whose mirror images test a candidate plane.
MIRROR_SAMPLE = 96
#: Plane positions tried per candidate normal, from the nearest observed point back to one
#: object size behind the farthest.
MIRROR_OFFSETS = 25
#: Positions tried again from the rung before the chosen one to the rung after it.
MIRROR_REFINE = 17
#: Candidate normals turn up to this far from the viewing direction (degrees), in these steps;
#: with an up direction they stay horizontal.
MIRROR_TURN_DEG = 45.0
MIRROR_CONE_DEG = 35.0
MIRROR_STEP_DEG = 9.0
#: The observed points' box axes (the object's likely symmetry directions) are taken when the
#: view refutes them at most this share of the sample more than the best fan normal.
AXIS_PRIOR = 0.1
#: ... when they turn from the viewing direction by less than acos of this (75 degrees).
AXIS_COS = 0.26
#: A mirror plane must put at least this share of the tested points behind the seen surface.
MIN_HIDDEN_SHARE = 0.2
#: Completions within this factor of the most compact one are as good; the one whose plane
#: faces the sensor most directly wins among them.
COMPACT_SLACK = 1.1


@nb.njit(
    'float64[:, :](float64[:, :], float64[:], float64[:, :], float64[:, :], float64[:], '
    'float64[:, :], float64[:], float64, boolean[:, :], float64[:, :], float64[:, :], float64, '
    'int64[:])',
    cache=True,
    nogil=True,
)
def _mirror_violations(
    sample: FloatArray,
    center: FloatArray,
    normals: FloatArray,
    offsets: FloatArray,
    viewpoint: FloatArray,
    frame: FloatArray,
    origin: FloatArray,
    cell: float,
    mask: BoolArray,
    near: FloatArray,
    oblique: FloatArray,
    tolerance: float,
    order: IndexArray,
) -> FloatArray:
    """
    Return the share of `sample` whose mirror image contradicts the view, per plane.

    An image contradicts the view when it falls outside the outline nearer than a surface the
    sensor saw too obliquely could reach (`oblique`, :func:`_oblique_ranges`), or more than
    `tolerance` in front of the nearest observed range in its cell.

    Only each normal's least value, and where it is first reached, are needed: the planes are
    tried in `order` (the likeliest first, :func:`_middle_out`) and a plane is given up (its
    share left as the count so far, above the least) as soon as it is refuted more than the best
    plane of its normal tried before it. The least values and their first positions are those
    of the full count.
    """
    rows, cols = mask.shape
    count = sample.shape[0]
    out = np.zeros((normals.shape[0], offsets.shape[1]))
    along = np.empty(count)  # each sample's height above the normal's plane through `center`
    for k in range(normals.shape[0]):
        n0, n1, n2 = normals[k, 0], normals[k, 1], normals[k, 2]
        for i in range(count):
            along[i] = (
                (sample[i, 0] - center[0]) * n0
                + (sample[i, 1] - center[1]) * n1
                + (sample[i, 2] - center[2]) * n2
            )
        least = count + 1
        for j in order:
            bad = 0
            offset = offsets[k, j]
            for i in range(count):
                if bad > least:
                    break
                height = along[i] - offset
                x = sample[i, 0] - 2.0 * height * n0 - viewpoint[0]
                y = sample[i, 1] - 2.0 * height * n1 - viewpoint[1]
                z = sample[i, 2] - 2.0 * height * n2 - viewpoint[2]
                row, col = pixel(x, y, z, frame, origin, cell)
                if row < 0 or col < 0 or row >= rows or col >= cols:
                    bad += 1
                    continue
                distance = math.sqrt(x * x + y * y + z * z)
                if not mask[row, col]:
                    if distance < oblique[row, col]:
                        bad += 1
                elif distance < near[row, col] - tolerance:
                    bad += 1
            out[k, j] = bad / count
            least = min(least, bad)
    return out


@nb.njit('Tuple((float64[:], float64[:]))(float64[:, :])', cache=True, nogil=True)
def _column_bounds(values: FloatArray) -> tuple[FloatArray, FloatArray]:
    """
    Return each column's minimum and maximum of an (N, K) array, N >= 1, in one pass.

    numpy's ``min(axis=0)`` and ``max(axis=0)`` take two passes of K values a row; the same
    values (no NaN: an extreme does not depend on the order it is taken in; only which of a
    0.0 and a -0.0 tied for one is kept might, and the plane positions add to it).
    """
    low = values[0].copy()
    high = values[0].copy()
    for i in range(1, values.shape[0]):
        for k in range(values.shape[1]):
            value = values[i, k]
            if value < low[k]:
                low[k] = value
            if value > high[k]:
                high[k] = value
    return low, high


def _middle_out(count: int) -> IndexArray:
    """Return 0 .. count - 1 from the middle outwards (the middle, one below, one above, ...)."""
    middle = (count - 1) // 2
    return np.array(sorted(range(count), key=lambda j: (abs(j - middle), j)), dtype=np.int64)


def plane_violations(
    sample: FloatArray,
    center: FloatArray,
    normals: FloatArray,
    offsets: FloatArray,
    raster: ViewRaster,
    tolerance: float,
    order: IndexArray | None = None,
    pool: Workers | None = None,
) -> FloatArray:
    """
    Return the share of `sample` whose mirror image contradicts the view, per plane (K, P).

    The planes are ``normals[k]`` (K, 3) at ``offsets[k, j]`` (K, P) from `center`; `order` is
    the order each normal's planes are tried in (default :func:`_middle_out`), which changes
    only the shares above each normal's least (:func:`_mirror_violations`). With `pool` the
    normals are split over the workers (each normal's row is its own: the same shares).
    """
    sample = np.ascontiguousarray(sample, dtype=np.float64)
    center = np.ascontiguousarray(center, dtype=np.float64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    offsets = np.ascontiguousarray(offsets, dtype=np.float64)
    tried = _middle_out(offsets.shape[1]) if order is None else np.ascontiguousarray(order)

    def rows(part: slice) -> FloatArray:
        return _mirror_violations(
            sample,
            center,
            np.ascontiguousarray(normals[part]),
            np.ascontiguousarray(offsets[part]),
            raster.viewpoint,
            raster.frame,
            raster.origin,
            raster.cell,
            raster.mask,
            raster.near,
            raster.oblique,
            tolerance,
            tried,
        )

    parts = split_rows(pool, len(normals), per_worker=1)
    if pool is None or len(parts) == 1:
        return rows(slice(0, len(normals)))
    return np.concatenate(pool.spread(rows, parts))


@dataclass(frozen=True)
class MirrorPlane:
    """
    The plane a view's far side is mirrored about.

    :ivar normal: (3,) unit normal, pointing away from the sensor.
    :ivar point: (3,) a point on the plane.
    :ivar violations: share of the tested points whose mirror image contradicts the view.
    """

    normal: FloatArray
    point: FloatArray
    violations: float

    def mirror(self, points: FloatArray) -> FloatArray:
        """Return `points` (N, 3) mirrored about the plane."""
        return _mirrored(points, self.normal, self.point)


def _horizontal(vector: FloatArray, up: FloatArray) -> FloatArray | None:
    """Return `vector` made perpendicular to `up` and unit, None when it is nearly vertical."""
    flat = vector - (vector @ up) * up
    norm = float(np.linalg.norm(flat))
    return None if norm < 0.3 else flat / norm


def _candidate_normals(
    view: FloatArray, up: FloatArray | None, axes: FloatArray
) -> tuple[FloatArray, FloatArray, int]:
    """
    Return the candidate plane normals and the preferred one.

    With `up`: horizontal normals up to :data:`MIRROR_TURN_DEG` either side of the horizontal
    viewing direction. Without: normals in a cone of :data:`MIRROR_CONE_DEG` around the viewing
    direction. Both add the `axes` (the observed points' box axes, the object's likely symmetry
    directions) turned less than ``acos(AXIS_COS)`` from the preferred normal, after the others.

    :return: the normals (K, 3), the preferred normal, and how many of the normals are the
        fan's (the rest are box axes).
    """
    rows: list[FloatArray] = []
    extra: list[FloatArray | None]
    if up is not None:
        preferred = _horizontal(view, up)
        for axis in axes:  # looking straight down: any vertical plane will do
            preferred = preferred if preferred is not None else _horizontal(axis, up)
        assert preferred is not None
        cosines, sines = _turn_angles(MIRROR_TURN_DEG, MIRROR_STEP_DEG)
        rows.append(cosines[:, None] * preferred + sines[:, None] * cross(up, preferred))
        extra = [_horizontal(axis, up) for axis in axes]
    else:
        preferred = view
        first, second = perpendicular_axes(view)
        polar_cos, polar_sin, azimuth_cos, azimuth_sin = _cone_angles(
            MIRROR_CONE_DEG, MIRROR_STEP_DEG
        )
        across = azimuth_cos[:, None] * first + azimuth_sin[:, None] * second
        rows.append(polar_cos[:, None] * view + polar_sin[:, None] * across)
        extra = list(axes)
    fan = len(rows[0])
    for axis in extra:
        if axis is not None:
            axis = axis if axis @ preferred >= 0.0 else -axis
            if axis @ preferred >= AXIS_COS:
                rows.append(axis[None, :])
    return np.concatenate(rows), preferred, fan


@functools.lru_cache(maxsize=4)
def _turn_angles(turn_deg: float, step_deg: float) -> tuple[FloatArray, FloatArray]:
    """Return the cosines and sines of the turns -turn_deg .. turn_deg, step_deg apart."""
    turn, step = math.radians(turn_deg), math.radians(step_deg)
    angles = np.arange(-turn, turn + 1e-9, step).tolist()
    return read_only([math.cos(a) for a in angles]), read_only([math.sin(a) for a in angles])


@functools.lru_cache(maxsize=4)
def _cone_angles(
    cone_deg: float, step_deg: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """
    Return the cosines and sines of the cone's polar angles and azimuths, one per normal.

    Rings every `step_deg` from the axis out to `cone_deg`, each with as many azimuths as fit
    `step_deg` apart on it. The math module's cosines, so the normals do not depend on numpy's
    vectorised trigonometry.
    """
    step = math.radians(step_deg)
    polars: list[float] = []
    azimuths: list[float] = []
    for polar in np.arange(0.0, math.radians(cone_deg) + 1e-9, step).tolist():
        ring = max(1, round(2.0 * math.pi * math.sin(polar) / step))
        turns = np.linspace(0.0, 2.0 * math.pi, ring, endpoint=False).tolist()
        polars += [polar] * ring
        azimuths += turns
    return (
        read_only([math.cos(a) for a in polars]),
        read_only([math.sin(a) for a in polars]),
        read_only([math.cos(a) for a in azimuths]),
        read_only([math.sin(a) for a in azimuths]),
    )


def find_mirror_plane(
    points: FloatArray,
    raster: ViewRaster,
    *,
    axes: FloatArray,
    up: FloatArray | None,
    spacing: float,
    pool: Workers | None = None,
) -> MirrorPlane:
    """
    Find the plane about which the observed points mirror onto the hidden side most plausibly.

    Every candidate normal (:func:`_candidate_normals`) is tried at :data:`MIRROR_OFFSETS`
    positions from the nearest observed point back to one object size behind the farthest. A
    mirrored point contradicts the view when the sensor would have seen it: outside the
    object's outline (farther than a surface too oblique for the sensor to see could reach,
    :data:`GRAZING_DEG`), or more than `spacing` in front of a seen surface. Per normal, the
    nearest position with the fewest contradictions is kept, first on a coarse ladder, then on
    a fine one around it. Over the normals, among those the view refutes least that put a fifth
    of the mirror image where the sensor could not see, the observed box's axes go first when
    the view allows them, then the most compact completion, preferring the normal nearest the
    viewing direction among those within :data:`COMPACT_SLACK` of it
    (``docs/single_views.md``). An evenly spread sample of :data:`MIRROR_SAMPLE` points (taken
    in sorted order, so the plane does not depend on the order of the points) is tested.

    :param points: (N, 3) observed points.
    :param raster: the view of those points (:func:`view_raster`).
    :param axes: (3, 3) rows: the observed points' box axes, extra candidate normals.
    :param up: unit up direction, or None when unknown.
    :param spacing: point spacing in metres (the depth tolerance of the test).
    :param pool: workers to split the candidate normals over (the same plane with any).
    :return: the plane.
    """
    # An evenly spread sample that does not depend on the order of the points.
    ordered = points[lexicographic_order(points[:, 0], points[:, 1], points[:, 2])]
    sample = np.ascontiguousarray(ordered[:: max(1, len(points) // MIRROR_SAMPLE)])
    center = points.mean(axis=0)
    view = center - raster.viewpoint
    view /= np.linalg.norm(view)
    normals, preferred, fan = _candidate_normals(view, up, np.asarray(axes, dtype=np.float64))
    nearest, farthest = _column_bounds((points - center) @ normals.T)
    size = float(np.max(column_span(points)))
    steps = np.linspace(0.0, 1.0, MIRROR_OFFSETS)
    planes = nearest[:, None] + steps[None, :] * (farthest - nearest + size)[:, None]

    def refuted(offsets: FloatArray) -> FloatArray:
        return plane_violations(sample, center, normals, offsets, raster, spacing, pool=pool)

    # Per normal: the nearest position with the fewest contradictions, found on a
    # coarse ladder of positions and then on a fine one around the chosen rung.
    coarse = refuted(planes)
    chosen = np.argmin(coarse, axis=1)
    rows = np.arange(len(normals))
    last = planes.shape[1] - 1
    low = planes[rows, np.maximum(chosen - 1, 0)]
    high = planes[rows, np.minimum(chosen + 1, last)]
    fine = low[:, None] + np.linspace(0.0, 1.0, MIRROR_REFINE)[None, :] * (high - low)[:, None]
    refined = refuted(fine)
    pick = np.argmin(refined, axis=1)
    bad = refined[rows, pick]
    offsets = fine[rows, pick]
    # Over the normals: the planes the view refutes least (within two sample points) are
    # plausible. The observed points' box axes, the object's likely symmetry directions, go
    # first when one of them is plausible; otherwise the fan's. Among those, the most compact
    # completion wins (Occam: the least unseen matter), preferring the viewing direction among
    # completions within COMPACT_SLACK of the most compact.
    # A plane that mirrors the seen side onto itself (one containing the viewing direction)
    # estimates nothing: a candidate must put some of the sample where the sensor could not see.
    heights = (sample - center) @ normals.T - offsets  # (M, K): above each chosen plane
    images = sample[:, None, :] - 2.0 * heights[:, :, None] * normals[None, :, :]
    hidden = raster.hidden(images.reshape(-1, 3), spacing).reshape(len(sample), -1)
    adds = hidden.mean(axis=0)
    useful = adds >= MIN_HIDDEN_SHARE
    best = bad[useful].min() if np.any(useful) else bad.min()
    plausible = np.flatnonzero((bad <= best + 2.0 / len(sample)) & useful)
    axes_plausible = fan + np.flatnonzero((bad[fan:] <= best + AXIS_PRIOR) & useful[fan:])
    if len(axes_plausible):
        plausible = axes_plausible
    if not len(plausible):
        plausible = np.array([int(np.argmin(bad))])
    sizes = np.array(
        [
            _completion_size(sample, normals[k], center + offsets[k] * normals[k], up, axes)
            for k in plausible
        ]
    )
    turns = np.arccos(np.clip(normals[plausible] @ preferred, -1.0, 1.0))
    compact = sizes <= COMPACT_SLACK * sizes.min()
    k = int(plausible[compact][np.argmin(turns[compact])])
    return MirrorPlane(normals[k], center + offsets[k] * normals[k], float(bad[k]))


def _mirrored(points: FloatArray, normal: FloatArray, point: FloatArray) -> FloatArray:
    """Return `points` mirrored about the plane through `point` with unit `normal`."""
    heights = (points - point) @ normal
    return points - 2.0 * heights[:, None] * normal


def _completion_size(
    sample: FloatArray,
    normal: FloatArray,
    point: FloatArray,
    up: FloatArray | None,
    axes: FloatArray,
) -> float:
    """
    Return how much of the object a mirror plane makes.

    The area of the footprint across `up` of the sample and its mirror image (a vertical mirror
    keeps heights), or, without `up`, the volume of their box along `axes`.
    """
    both = np.concatenate([sample, _mirrored(sample, normal, point)])
    if up is None:
        local = both @ np.asarray(axes).T
        return float(np.prod(column_span(local)))
    first, second = cached_perpendicular_axes(*up.tolist())
    flat = np.column_stack([both @ first, both @ second])
    return _hull_area(flat)


def _hull_area(points: FloatArray) -> float:
    """Return the area of the convex hull of 2D `points` (0 for fewer than three or a line)."""
    x = np.ascontiguousarray(points[:, 0])
    y = np.ascontiguousarray(points[:, 1])
    ring = np.empty(len(points) + 1, dtype=np.int64)
    size = hull_2d_kernel(x, y, np.arange(len(points)), len(points), ring)
    if size < 3:
        return 0.0
    xs, ys = x[ring[:size]], y[ring[:size]]
    return 0.5 * abs(float(xs @ np.roll(ys, -1) - ys @ np.roll(xs, -1)))


def warm_up() -> None:
    """Run every kernel of this module once on a tiny view (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(np.linspace(-0.05, 0.05, 6), np.linspace(0.0, 0.1, 6)), -1)
    front = np.column_stack([grid.reshape(-1, 2), np.full(36, 0.8)])
    top = front[:, [0, 2, 1]] * [1.0, 1.0, -0.5] + [0.0, 0.0, 0.8]
    points = np.concatenate([front, top])
    raster = view_raster(points, np.zeros(3), 0.02)
    up = np.array([0.0, -1.0, 0.0])
    find_mirror_plane(points, raster, axes=np.eye(3), up=up, spacing=0.02)
