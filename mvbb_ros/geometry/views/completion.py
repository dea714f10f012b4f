"""
The hidden side of a single sensor view: what the sensor could not see is not empty space.

A segmented cloud from one viewpoint holds the object's near side only. Fitted as it is, boxes
hug that skin and the fit-and-split gain Theta* carves it into plates of sensor thickness,
because the object's hidden inside counts as empty space. :func:`complete_view` therefore turns
the observed points into a *solid*: the observed points, an estimate of the far side, and
samples of the space between them along the sensor's rays (space that was never seen to be
free). The decomposition then runs on the solid with the paper's gain.

Methods (``Completion``):

* ``'mirror'``: the far side is the near side mirrored about a plane (Bohg et al., "Mind the
  Gap", ICRA 2011). The plane is found by :func:`find_mirror_plane`: among candidate planes, the
  one whose mirror image contradicts the view least (a mirrored point the sensor would have
  seen, in front of a seen surface or where it saw past the object), then the nearest to the
  sensor. With an up direction the planes are vertical (the object stands on a support) and
  the solid is also filled straight down to its lowest point; without one, planes turned up to
  35 degrees from the viewing direction are tried. A view that shows one flat face (a plate:
  :data:`PLATE_RATIO`) is extruded instead: nothing in it says how deep the object is, and a
  vertical mirror would stand a leaning screen up as a tent.
* ``'extrude'``: every observed point is extended away from the viewpoint until it leaves the
  observed points' minimum box.
* ``'none'``: the observed points alone (the paper).

``docs/single_views.md`` describes the methods and what they measure on real scans and virtual
views. The hot loops (rasterising, testing mirror planes, sampling rays) are numba kernels.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import math
from typing import get_args, Literal

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
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.boxfit.fit import minimum_bounding_box
from mvbb_ros.geometry.boxfit.rectangle import hull_2d_kernel
from mvbb_ros.geometry.views.raster import (
    behind_others,
    MAX_RASTER_SIDE,
    pixel,
    view_raster,
    ViewRaster,
)
import numba as nb
import numpy as np
from numpy.typing import ArrayLike

#: How the hidden side is estimated (the ``shape_completion`` setting); see the module doc.
Completion = Literal['none', 'mirror', 'extrude']
COMPLETIONS: tuple[Completion, ...] = get_args(Completion)

#: The estimated part keeps one point per cube this many point spacings wide ...
SOLID_CELLS = 1.0
#: ... or wider, so that there are at most this many cubes along a side.
MAX_SOLID_SIDE = 96
#: Most samples of an object's estimated part (a coarser step beyond: the solid's bounds are
#: what the decomposition uses, and they do not need more).
MAX_SAMPLES = 40_000
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
#: A cloud with more than this share of its points behind another surface along their ray
#: (:func:`behind_others`), seen from the viewpoint, is not one sensor view (a model, merged
#: views, or a wrong viewpoint): its points are used as they are.
MAX_SELF_HIDDEN = 0.18
#: A jump in range of more than this many point spacings along a ray separates two surfaces.
SURFACE_GAP = 3.0
#: A view whose observed points' box is at most this thin for its middle extent shows one flat
#: face (a screen, a board, a book): it is completed by extrusion to that box, not mirrored.
#: Measured on the shared scans and views: the Kinect laptop's leaning screen 0.073, a flat mOSD
#: object 0.109, then nothing under 0.25 (``docs/single_views.md``).
PLATE_RATIO = 0.15


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
    first, second = _perpendicular_axes(*up.tolist())
    flat = np.column_stack([both @ first, both @ second])
    return _hull_area(flat)


@functools.lru_cache(maxsize=8)
def _perpendicular_axes(x: float, y: float, z: float) -> tuple[FloatArray, FloatArray]:
    """Return :func:`perpendicular_axes` of (x, y, z) (read-only; one object's up, asked often)."""
    first, second = perpendicular_axes(np.array([x, y, z]))
    return read_only(first), read_only(second)


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


@nb.njit(
    'float64[:, :](float64[:, :], float64[:, :], float64[:], float64)',
    cache=True,
    nogil=True,
)
def _segment_samples(
    starts: FloatArray, directions: FloatArray, lengths: FloatArray, step: float
) -> FloatArray:
    """Return samples every `step` along start + t direction for 0 < t <= length, per row."""
    count = 0
    for i in range(starts.shape[0]):
        if lengths[i] >= step:
            count += int(lengths[i] / step)
    out = np.empty((count, 3))
    k = 0
    for i in range(starts.shape[0]):
        if lengths[i] < step:
            continue
        for s in range(1, int(lengths[i] / step) + 1):
            for axis in range(3):
                out[k, axis] = starts[i, axis] + directions[i, axis] * (s * step)
            k += 1
    return out


def _samples(
    starts: FloatArray, directions: FloatArray, lengths: FloatArray, step: float
) -> FloatArray:
    """Sample the segments every `step`, or coarser when that would exceed :data:`MAX_SAMPLES`."""
    step = max(step, float(np.sum(lengths)) / MAX_SAMPLES)
    return _segment_samples(
        np.ascontiguousarray(starts), np.ascontiguousarray(directions), lengths, step
    )


@nb.njit('int64[:](int64[:])', cache=True, nogil=True)
def _ascending(best: IndexArray) -> IndexArray:
    """Return the non-negative entries of `best` (distinct point indices) in ascending order."""
    largest = -1
    for index in best:
        if index >= 0:
            largest = max(largest, index)
    chosen = np.zeros(largest + 1, dtype=np.bool_)
    for index in best:
        if index >= 0:
            chosen[index] = True
    kept = np.empty(chosen.sum(), dtype=np.int64)
    count = 0
    for index in range(largest + 1):
        if chosen[index]:
            kept[count] = index
            count += 1
    return kept


@nb.njit('int64[:](float64[:, :], boolean[:], float64)', cache=True, nogil=True)
def _one_per_cell(points: FloatArray, keep: BoolArray, cell: float) -> IndexArray:
    """
    Return the indices of one point per occupied cubic cell `cell` wide (sorted).

    The estimated part of a solid is sampled densely along rays that run side by side; one point
    per cell keeps its shape (the decomposition only needs its bounds and a fair count) at a
    fraction of the points. The point kept is the cell's lowest in x, then y, then z, so the
    choice does not depend on the order of the points. The cells are coarser when that would
    make more than :data:`MAX_SOLID_SIDE` cells along a side. Only the points with `keep` set
    take part (the cells are those of the kept points alone); the indices are into `points`.
    """
    count = 0
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    for i in range(points.shape[0]):
        if keep[i]:
            count += 1
            for axis in range(3):
                low[axis] = min(low[axis], points[i, axis])
                high[axis] = max(high[axis], points[i, axis])
    if count == 0:
        return np.zeros(0, dtype=np.int64)
    widest = 0.0
    for axis in range(3):
        widest = max(widest, high[axis] - low[axis])
    cell = max(cell, widest / MAX_SOLID_SIDE)
    span = np.empty(3, dtype=np.int64)
    for axis in range(3):
        span[axis] = int((high[axis] - low[axis]) / cell) + 1
    best = np.full(span[0] * span[1] * span[2], -1, dtype=np.int64)
    for i in range(points.shape[0]):
        if not keep[i]:
            continue
        key = 0
        for axis in range(3):
            key = key * span[axis] + int((points[i, axis] - low[axis]) / cell)
        other = best[key]
        if other < 0:
            best[key] = i
            continue
        for axis in range(3):
            if points[i, axis] != points[other, axis]:
                if points[i, axis] < points[other, axis]:
                    best[key] = i
                break
    return _ascending(best)


def _rays(points: FloatArray, viewpoint: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return the unit directions from `viewpoint` to `points` and their ranges."""
    directions = points - viewpoint
    ranges = np.linalg.norm(directions, axis=1)
    return directions / np.maximum(ranges, 1e-300)[:, None], ranges


def fill_to_far_side(
    points: FloatArray, far: FloatArray, raster: ViewRaster, step: float
) -> FloatArray:
    """
    Sample the space between each observed point and the far side behind it, every `step`.

    A ray's far side is the farthest `far` point in its raster cell; cells without one take the
    farthest in the 3 x 3 cells around them (the far side's own samples are a spacing apart).

    :return: (M, 3) samples, none at the observed points themselves.
    """
    cells, ranges = raster.locate(points)
    far_cells, far_ranges = raster.locate(far)
    rows, cols = raster.mask.shape
    lengths = _far_side_lengths(cells, ranges, far_cells, far_ranges, rows, cols)
    directions, _ = _rays(points, raster.viewpoint)
    return _samples(points, directions, lengths, step)


@nb.njit(
    'float64[:](int64[:, :], float64[:], int64[:, :], float64[:], int64, int64)',
    cache=True,
    nogil=True,
)
def _far_side_lengths(
    cells: IndexArray,
    ranges: FloatArray,
    far_cells: IndexArray,
    far_ranges: FloatArray,
    rows: int,
    cols: int,
) -> FloatArray:
    """
    Return how far each ray runs past its point to the far side (0 outside the raster).

    The deepest far-side range per raster cell, in cells without one the deepest of the 3 x 3
    cells around (-inf when none: no length), less the point's range, at least 0. Maxima only:
    the values of the numpy steps this replaced (``np.maximum.at``, a 3 x 3 maximum filter,
    whose reflected border adds no other value).
    """
    deepest = np.full((rows, cols), -np.inf)
    for i in range(far_cells.shape[0]):
        row = far_cells[i, 0]
        if row >= 0:
            col = far_cells[i, 1]
            deepest[row, col] = max(deepest[row, col], far_ranges[i])
    lengths = np.empty(cells.shape[0])
    for i in range(cells.shape[0]):
        row, col = cells[i, 0], cells[i, 1]
        far_end = 0.0
        if row >= 0:
            far_end = deepest[row, col]
            if far_end == -np.inf:
                for a in range(max(row - 1, 0), min(row + 2, rows)):
                    for b in range(max(col - 1, 0), min(col + 2, cols)):
                        far_end = max(far_end, deepest[a, b])
        length = far_end - ranges[i]
        lengths[i] = length if length > 0.0 else 0.0
    return lengths


def fill_to_box(points: FloatArray, viewpoint: FloatArray, box: Box, step: float) -> FloatArray:
    """Sample each point's ray away from `viewpoint`, every `step`, until it leaves `box`."""
    directions, _ = _rays(points, viewpoint)
    local = box.to_local(points)
    along = directions @ box.rotation
    half = box.half_extents
    with np.errstate(divide='ignore', invalid='ignore'):
        exits = np.where(
            along > 0.0,
            (half - local) / along,
            np.where(along < 0.0, (-half - local) / along, np.inf),
        )
    lengths = np.clip(exits.min(axis=1), 0.0, None)
    return _samples(points, directions, lengths, step)


@nb.njit('int64[:](float64[:], float64[:], float64[:], float64)', cache=True, nogil=True)
def _column_tops(
    across: FloatArray, along: FloatArray, height: FloatArray, step: float
) -> IndexArray:
    """Return the index of the highest point of every occupied `step`-wide column (sorted)."""
    count = across.shape[0]
    low_a, low_b = across.min(), along.min()
    width = int((across.max() - low_a) / step) + 1
    depth = int((along.max() - low_b) / step) + 1
    best = np.full(width * depth, -1, dtype=np.int64)
    for i in range(count):
        cell = int((across[i] - low_a) / step) * depth + int((along[i] - low_b) / step)
        if best[cell] < 0 or height[i] > height[best[cell]]:
            best[cell] = i
    return _ascending(best)


def fill_down(points: FloatArray, up: FloatArray, lowest: float, step: float) -> FloatArray:
    """
    Sample straight down from the top of every footprint column to the height `lowest`.

    The footprint is cut into `step`-wide columns across `up` (coarser when that would make
    more than :data:`MAX_RASTER_SIDE` columns along a side); each column's highest point is the
    top of a column of samples every `step` (the object stands on something below it).
    """
    first, second = _perpendicular_axes(*up.tolist())
    across, along, height = points @ first, points @ second, points @ up
    widest = max(float(np.ptp(across)), float(np.ptp(along)))
    tops = _column_tops(across, along, height, max(step, widest / MAX_RASTER_SIDE))
    down = np.repeat(-up[None, :], len(tops), axis=0)
    return _samples(points[tops], down, height[tops] - lowest, step)


@dataclass(frozen=True, eq=False)
class CompletedView:
    """
    One object's observed points and the estimate of what the sensor could not see.

    :ivar points: (M, 3) the solid: the observed points first, then the estimated ones.
    :ivar observed: how many of :attr:`points` the sensor saw.
    :ivar method: the completion asked for.
    :ivar plane: the mirror plane (``'mirror'``, unless the view was a plate), else None.
    :ivar skipped: why nothing was estimated although a completion was asked for, else None.
    """

    points: FloatArray
    observed: int
    method: Completion
    plane: MirrorPlane | None = None
    skipped: str | None = None

    @property
    def estimated(self) -> FloatArray:
        """Return the estimated points (the solid without the observed ones)."""
        start = self.observed
        return self.points[start:]


def complete_view(
    points: ArrayLike,
    *,
    method: Completion = 'none',
    viewpoint: ArrayLike = (0.0, 0.0, 0.0),
    up: ArrayLike | None = None,
    spacing: float,
    floor: float | None = None,
    pool: Workers | None = None,
) -> CompletedView:
    """
    Return one object's observed points with an estimate of what the sensor could not see.

    :param points: (N, 3) observed points of one object, metres, N >= 1.
    :param method: ``'none'``, ``'mirror'`` or ``'extrude'`` (see the module doc).
    :param viewpoint: (3,) sensor position in the points' frame (the frame's origin for camera
        and laser frames).
    :param up: up direction in the points' frame (need not be unit), or None when unknown.
    :param spacing: point spacing (the voxel size), metres: the step of the samples.
    :param floor: with `up`, the height along unit `up` of the support the object rests on
        (metres), or None: the hidden side is filled down to it, not only to the lowest
        observed point, and no estimate goes below it (the table ends the object).
    :param pool: workers: the observed points' box is fitted while the view is rastered (the
        same solid with any), or None.
    :return: the solid, observed points first.
    :raises ValueError: for an unknown method or a non-positive spacing.
    """
    if method not in COMPLETIONS:
        raise ValueError(f'completion must be one of {COMPLETIONS}, got {method!r}')
    if not spacing > 0.0:
        raise ValueError(f'spacing must be > 0, got {spacing!r}')
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    eye = np.asarray(viewpoint, dtype=np.float64)
    if method == 'none' or len(pts) < 4:
        return CompletedView(pts, len(pts), method)
    fitted = None if pool is None else pool.submit(lambda: minimum_bounding_box(pts))
    raster = view_raster(pts, eye, spacing)
    self_hidden = float(np.mean(behind_others(pts, raster, SURFACE_GAP * spacing)))
    if self_hidden > MAX_SELF_HIDDEN:
        reason = (
            f'not one view from {eye.tolist()}: {100 * self_hidden:.0f} % of the points lie '
            'behind others (is viewpoint the sensor position in the cloud frame?)'
        )
        if fitted is not None:
            fitted.cancel()
        return CompletedView(pts, len(pts), method, skipped=reason)
    # The observed points' minimum box: the extrusion stops at its far faces, and its axes are
    # the object's likely symmetry directions.
    box = minimum_bounding_box(pts) if fitted is None else fitted.result()
    thin, middle = np.sort(box.extents)[:2]
    if method == 'extrude' or thin <= PLATE_RATIO * middle:
        # One flat face seen gives no depth behind it, and a mirror about a vertical plane
        # would stand a leaning plate up as a tent: a plate keeps its own box.
        estimated = fill_to_box(pts, eye, box, spacing)
        every = np.ones(len(estimated), dtype=np.bool_)
        estimated = estimated[_one_per_cell(estimated, every, SOLID_CELLS * spacing)]
        return CompletedView(np.concatenate([pts, estimated]), len(pts), method)
    unit_up = None
    if up is not None:
        unit_up = np.asarray(up, dtype=np.float64)
        unit_up = unit_up / np.linalg.norm(unit_up)
    plane = find_mirror_plane(
        pts, raster, axes=box.rotation.T, up=unit_up, spacing=spacing, pool=pool
    )
    # Keep the mirror images that add something: hidden behind the seen surface. The others
    # either repeat a seen surface or contradict the view.
    far = plane.mirror(pts)
    far = far[raster.hidden(far, spacing)]
    # The space between the seen surface and its mirror image, within the box of the two: rays
    # at the outline must not carry the far side's range past the object's sides.
    both = np.concatenate([pts, far])
    bounds = Box.enclosing(both, box.rotation)
    fill = fill_to_far_side(pts, far, raster, spacing)
    fill = fill[bounds.contains(fill, tol=spacing)]
    if unit_up is not None:
        # Nor past the seen width across the (vertical) mirror plane: a mirror keeps that
        # width, but the rays diverge from the viewpoint, so the samples behind the edge of the
        # seen surface run wider than it, into the box's slack (a 3 cm plate seen end-on from
        # 0.5 m came out 1 cm thicker, 1.7 times its volume). The slack stays along the normal
        # and up, where the far side and the bottom are estimates that tend to fall short.
        side = cross(unit_up, plane.normal)
        across = fill @ side
        width = both @ side
        fill = fill[(across >= width.min()) & (across <= width.max())]
    parts = [both, fill]
    if unit_up is not None:
        lowest = float(np.min(both @ unit_up)) if floor is None else floor
        parts.append(fill_down(np.concatenate(parts), unit_up, lowest, spacing))
    estimated = np.concatenate(parts[1:])
    if unit_up is not None and floor is not None:
        keep = estimated @ unit_up >= floor
    else:
        keep = np.ones(len(estimated), dtype=np.bool_)
    # The cells of the kept points only, their indices into `estimated`: one copy, not two.
    estimated = estimated[_one_per_cell(estimated, keep, SOLID_CELLS * spacing)]
    return CompletedView(np.concatenate([pts, estimated]), len(pts), method, plane)


def warm_up() -> None:
    """Run every kernel of this module once on a tiny view (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(np.linspace(-0.05, 0.05, 6), np.linspace(0.0, 0.1, 6)), -1)
    front = np.column_stack([grid.reshape(-1, 2), np.full(36, 0.8)])
    top = front[:, [0, 2, 1]] * [1.0, 1.0, -0.5] + [0.0, 0.0, 0.8]
    complete_view(np.concatenate([front, top]), method='mirror', up=(0, -1, 0), spacing=0.02)
