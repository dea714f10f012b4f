"""
Minimum-volume oriented bounding box of a 3D point set, in compiled code (numba).

Huebner et al. (ICRA 2008), Section III-A, fit every box with the approximation of Barequet and
Har-Peled (2001): find good directions, search a small grid of directions around the best frame,
improve the best box locally, and finally grow it to enclose every point. This module follows that
scheme on the convex hull (the box of a point set is the box of its hull), with exact 2D steps:
the orientation search (:mod:`mvbb_ros.geometry.boxfit.search`) turns candidate boxes to their best
rotation about one axis (the minimum-area rectangle of the hull's silhouette, by rotating
calipers, :mod:`mvbb_ros.geometry.boxfit.rectangle`), on candidate axes from hull facets and edge
pairs (O'Rourke 1985), polishes the best by alternating such turns and (with ``grid_size`` > 0,
off by default) searches Barequet and Har-Peled's grid of directions around the result. The
best frame is then walked on the sphere of axes in small tilts, first its first axis, then its
second (:func:`mvbb_ros.geometry.boxfit.search.settle`): a minimal box whose faces are flush
with hull edges rather than a facet lies between the candidate axes, and a box stuck where no
tilt of one axis helps can shrink when another tilts; last, the thinnest axis pivots about the
hull edges flush with its faces (:func:`mvbb_ros.geometry.boxfit.search.pivot_thinnest`). The
final box is the smallest of the searched frame's box, the PCA box and the axis-aligned box,
each grown around every input point: never worse than either, and always enclosing.

What runs where, for N points whose searched hull has H vertices, F ~ 2H facets and E ~ 3H edges
(all in one compiled call, :func:`fit_kernel`; the Python wrapper only checks the input):

1. Bounding box, PCA of an evenly spread sample of at most 4096 points (its frame by
   :func:`~mvbb_ros.geometry.boxfit.frames.symmetric_eigen`), every point in the PCA frame
   centred on the bounding box and scaled to unit size: O(N), three passes.
2. Clouds of ``coreset_min`` points or more (default 65,536): Barequet and Har-Peled's grid
   coreset (:func:`mvbb_ros.geometry.boxfit.hull.column_extremes_kernel`): O(N), at most 6 x 32^2
   points kept. After the search, one pass over every point finds those sticking out of the
   frame's box (:func:`~mvbb_ros.geometry.boxfit.enclose.add_leaks`); they join the hull and the
   frame is walked again (at most :data:`~mvbb_ros.geometry.boxfit.enclose.LEAK_ROUNDS` times),
   the last pass giving the final box.
3. Quickhull (:func:`mvbb_ros.geometry.boxfit.hull.quickhull_kernel`) on all points or the coreset:
   O(N log H).
4. The orientation search on the hull (:func:`mvbb_ros.geometry.boxfit.search.search_kernel`):
   candidate ranking O(K (H + F)), then 60 to 120 axes, and at least 8 per step of the final walk,
   at O(F + E + S) each for silhouettes of S vertices.
5. Enclose every point in each candidate frame
   (:func:`~mvbb_ros.geometry.boxfit.enclose.final_box`): O(N).

Degenerate clouds never reach the hull: the extents in the PCA frame give the affine rank (an
extent below ``RANK_TOLERANCE`` of the largest is empty). One point or duplicates give a zero box,
collinear points the PCA frame, coplanar points the plane's minimum-area rectangle. Clouds
thinner than ``FLAT_SEARCH`` of their size are hulled too, but their hull's facets across the
thickness are slivers that rounding can spoil, so the plane's rectangle, its normal polished to
the thinnest direction on the 2D hulls of all points, is a candidate as well. Extents below
``enclose.ZERO_EXTENT`` of the largest are reported as exactly 0.

Compiled code: the kernels (names ending in ``_kernel``) are numba functions with ``cache=True``
and ``nogil=True`` (they release the GIL while they run, so that a node's executor thread answers
its services during a frame); the helpers they call are compiled into them and not cached on their
own (fewer cache files, a quicker warm start). Kernels take C-contiguous float64 arrays and int64
knobs; their wrappers (:func:`fit_box`, :func:`minimum_bounding_box`) check and convert the input,
so one specialisation per kernel is compiled and cached. A kernel's cache is refreshed when any
module it calls into changes (:mod:`mvbb_ros.kernel_cache`).
"""

from __future__ import annotations

from typing import NamedTuple

from mvbb_ros.arrays import FloatArray
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.boxfit import hull as hull_module
from mvbb_ros.geometry.boxfit.enclose import add_leaks, final_box
from mvbb_ros.geometry.boxfit.frames import planar_frame, symmetric_eigen
from mvbb_ros.geometry.boxfit.search import copy_frame, polish, search_kernel
from mvbb_ros.geometry.boxfit.turn import frame_volume, new_work
import numba as nb
import numpy as np
from numpy.typing import ArrayLike

#: Relative extent (of the largest) below which a PCA direction counts as empty.
RANK_TOLERANCE = 1e-10
#: Relative PCA thickness below which the plane's rectangle is tried beside the hull search.
FLAT_SEARCH = 1e-4
#: Points of the evenly spread sample the PCA is computed on.
PCA_SAMPLE = 4096
#: Clouds of at least this many points are hulled on their grid coreset (``coreset_min``).
CORESET_MIN_POINTS = 65536
#: Facet normals ranked by the volume bound whose best box is computed (``candidates``), and
#: half as many edge-pair normals. 48 rather than 24: the bound prunes most of the extra axes
#: before they are turned, and 24 missed the best basin on 7 of 9,000 varied clouds (up to
#: 1.034 x the reference; ``CHANGELOG.md``).
CANDIDATE_AXES = 48
#: Distinct candidate boxes that start the polish (``starts``). 16 rather than 8: near-copies of
#: one basin's box no longer count twice (:data:`~mvbb_ros.geometry.boxfit.search.SAME_START`),
#: and the sixteen distinct smallest reach the basins 8 (and 12) missed on varied clouds (up to
#: 1.0215 x the reference) at no measurable cost, since the polish halves the starts every round
#: (``CHANGELOG.md``).
STARTS = 16
#: Hull edges of largest length times turning angle whose pairs are candidate axes too
#: (``sharp_edges``; :func:`~mvbb_ros.geometry.boxfit.search.sharpest_edges`), a quarter of
#: ``candidates`` of them kept: a minimal box's faces can be flush with edges shorter than the
#: longest where the hull turns sharply. Without them, 4 of 15,000 varied clouds missed the
#: best box by 1.0104-1.0148 x (``CHANGELOG.md``).
SHARP_EDGES = 18
#: First tilt of the final walk of the box's axis (radians), halved ``walk_steps`` times.
WALK_STEP = 0.04


# The whole fit ---------------------------------------------------------------------------------


@nb.njit(cache=True, nogil=True)
def fit_kernel(
    points: np.ndarray,
    seed: int,
    sample_size: int,
    grid_size: int,
    candidates: int,
    starts: int,
    max_rounds: int,
    exhaustive: int,
    pair_edges: int,
    sharp_edges: int,
    coreset_cells: int,
    coreset_min: int,
    hull_tolerance: float,
    walk_steps: int,
    walk_step: float,
    walk_axes: int,
    distinct_starts: int,
    edge_pivots: int,
) -> tuple:
    """
    Fit the minimum-volume oriented box of finite points (see the module notes).

    :param points: (N, 3) C-contiguous finite points, N >= 1.
    :return: centre (3,), rotation (3, 3) whose columns are the box axes (right-handed) and full
        extents (3,), in the units and frame of the points.
    """
    count = points.shape[0]
    # Bounds in scalars (registers): the passes over every point are a third of a part fit.
    low0 = high0 = points[0, 0]
    low1 = high1 = points[0, 1]
    low2 = high2 = points[0, 2]
    for i in range(1, count):
        low0 = min(low0, points[i, 0])
        high0 = max(high0, points[i, 0])
        low1 = min(low1, points[i, 1])
        high1 = max(high1, points[i, 1])
        low2 = min(low2, points[i, 2])
        high2 = max(high2, points[i, 2])
    low = np.array([low0, low1, low2])
    high = np.array([high0, high1, high2])
    origin = np.empty(3)
    for k in range(3):
        origin[k] = 0.5 * (low[k] + high[k])
    scale = 0.5 * max(high[0] - low[0], high[1] - low[1], high[2] - low[2])
    if not scale > 0.0:
        return origin, np.eye(3), np.zeros(3)
    # PCA of an evenly spread sample, relative to the bounding box centre, at unit scale
    # (the reciprocal of a subnormal scale overflows: such clouds are first scaled up by a power
    # of two, which is exact).
    pre = 2.0**600 if scale < 1e-290 else 1.0
    inverse = 1.0 / (scale * pre)
    step = max(1, count // PCA_SAMPLE)
    o0, o1, o2 = origin[0], origin[1], origin[2]
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    taken = 0
    for i in range(0, count, step):
        m0 += (points[i, 0] - o0) * pre * inverse
        m1 += (points[i, 1] - o1) * pre * inverse
        m2 += (points[i, 2] - o2) * pre * inverse
        taken += 1
    m0 /= taken
    m1 /= taken
    m2 /= taken
    # The sums in scalars (registers), in the same order as an array's would be.
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0
    for i in range(0, count, step):
        d0 = (points[i, 0] - o0) * pre * inverse - m0
        d1 = (points[i, 1] - o1) * pre * inverse - m1
        d2 = (points[i, 2] - o2) * pre * inverse - m2
        c00 += d0 * d0
        c01 += d0 * d1
        c02 += d0 * d2
        c11 += d1 * d1
        c12 += d1 * d2
        c22 += d2 * d2
    covariance = np.empty((3, 3))
    covariance[0, 0] = c00
    covariance[0, 1] = covariance[1, 0] = c01
    covariance[0, 2] = covariance[2, 0] = c02
    covariance[1, 1] = c11
    covariance[1, 2] = covariance[2, 1] = c12
    covariance[2, 2] = c22
    pca = symmetric_eigen(covariance)
    # Every point in the PCA frame, and its box there.
    local = np.empty((count, 3))
    p00, p01, p02 = pca[0, 0], pca[0, 1], pca[0, 2]
    p10, p11, p12 = pca[1, 0], pca[1, 1], pca[1, 2]
    p20, p21, p22 = pca[2, 0], pca[2, 1], pca[2, 2]
    l0 = l1 = l2 = np.inf
    h0 = h1 = h2 = -np.inf
    for i in range(count):
        d0 = (points[i, 0] - o0) * pre * inverse
        d1 = (points[i, 1] - o1) * pre * inverse
        d2 = (points[i, 2] - o2) * pre * inverse
        v0 = d0 * p00 + d1 * p10 + d2 * p20
        v1 = d0 * p01 + d1 * p11 + d2 * p21
        v2 = d0 * p02 + d1 * p12 + d2 * p22
        local[i, 0] = v0
        local[i, 1] = v1
        local[i, 2] = v2
        l0, h0 = min(l0, v0), max(h0, v0)
        l1, h1 = min(l1, v1), max(h1, v1)
        l2, h2 = min(l2, v2), max(h2, v2)
    local_low = np.array([l0, l1, l2])
    local_high = np.array([h0, h1, h2])
    spans = np.empty(3)
    for k in range(3):
        spans[k] = local_high[k] - local_low[k]
    largest = max(spans[0], spans[1], spans[2])
    rank = 0
    widest = 0
    narrowest = 0
    for k in range(3):
        if spans[k] > RANK_TOLERANCE * largest:
            rank += 1
        if spans[k] > spans[widest]:
            widest = k
        if spans[k] < spans[narrowest]:
            narrowest = k
    # The two widest PCA axes, for the planar frame.
    middle_axis = 3 - widest - narrowest if widest != narrowest else (widest + 1) % 3
    frames = np.zeros((2, 3, 3))
    # The box of every point in a frame, where a leak check already measured it.
    known = np.zeros(2, dtype=np.bool_)
    known_bounds = np.zeros((2, 2, 3))
    used = 0
    if rank == 2:
        copy_frame(planar_frame(local, widest, middle_axis), frames[used])
        used += 1
    elif rank == 3 and spans[narrowest] < FLAT_SEARCH * largest:
        # So thin that the hull's facets across the thickness are slivers: the plane's minimum
        # rectangle too, its normal tilted to the thinnest direction by the polish on the 2D
        # hulls of every point (the PCA normal of a noisy slab is off by about thickness /
        # sqrt(N)); the smaller box of this and the hull search wins.
        planar = np.empty((1, 3, 3))
        copy_frame(planar_frame(local, widest, middle_axis), planar[0])
        volume = np.array([frame_volume(local, planar[0])])
        # No hull: no edges, so every rotation is the 2D hull of every point's projection.
        no_edges = np.zeros((0, 2), dtype=np.int64)
        work = new_work(local, np.zeros((0, 3)), no_edges, no_edges)
        _, frame = polish(local, work, planar, volume, max(max_rounds, 3))
        copy_frame(frame, frames[used])
        used += 1
    if rank == 3:
        if coreset_cells > 0 and count >= coreset_min:
            kept = hull_module.column_extremes_kernel(local, local_low, local_high, coreset_cells)
            searched = np.empty((kept.shape[0], 3))
            for i in range(kept.shape[0]):
                for k in range(3):
                    searched[i, k] = local[kept[i], k]
        else:
            searched = local
        status, hull_ids, _, normals, areas, edges, edge_facets = hull_module.quickhull_kernel(
            searched, hull_tolerance
        )
        if status == hull_module.BROKEN:
            # No hull: search every point with the PCA axes, the polish and the grid only.
            _, frame = search_kernel(
                searched,
                np.zeros((0, 3)),
                np.zeros(0),
                np.zeros((0, 2), dtype=np.int64),
                np.zeros((0, 2), dtype=np.int64),
                seed,
                candidates,
                pair_edges,
                sharp_edges,
                sample_size,
                exhaustive,
                starts,
                max_rounds,
                grid_size,
                walk_steps,
                walk_step,
                walk_axes,
                distinct_starts,
                edge_pivots,
            )
            copy_frame(frame, frames[used])
            used += 1
        elif status < 3:
            if used == 0:
                copy_frame(planar_frame(local, widest, middle_axis), frames[used])
                used += 1
        else:
            vertices = np.empty((hull_ids.shape[0], 3))
            for i in range(hull_ids.shape[0]):
                for k in range(3):
                    vertices[i, k] = searched[hull_ids[i], k]
            volume, frame = search_kernel(
                vertices,
                normals,
                areas,
                edges,
                edge_facets,
                seed,
                candidates,
                pair_edges,
                sharp_edges,
                sample_size,
                exhaustive,
                starts,
                max_rounds,
                grid_size,
                walk_steps,
                walk_step,
                walk_axes,
                distinct_starts,
                edge_pivots,
            )
            if searched.shape[0] < count:
                frame, bounds, exact = add_leaks(
                    local,
                    vertices,
                    frame,
                    volume,
                    hull_tolerance,
                    max_rounds,
                    walk_steps,
                    walk_step,
                    edge_pivots,
                )
                if exact:
                    known[used] = True
                    for k in range(3):
                        known_bounds[used, 0, k] = bounds[0, k]
                        known_bounds[used, 1, k] = bounds[1, k]
            copy_frame(frame, frames[used])
            used += 1
    return final_box(
        local,
        origin,
        scale,
        pca,
        frames[:used],
        known,
        known_bounds,
        low,
        high,
        local_low,
        local_high,
    )


# Python API ------------------------------------------------------------------------------------


def _as_points(points: ArrayLike) -> FloatArray:
    """Return `points` as a C-contiguous float (N, 3) array, or raise ValueError saying why."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.shape == (3,):
        pts = pts.reshape(1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f'minimum_bounding_box needs points of shape (N, 3), got {pts.shape}')
    if len(pts) == 0:
        raise ValueError('minimum_bounding_box needs at least one point, got an empty array')
    if not np.isfinite(pts).all():
        bad = np.count_nonzero(~np.isfinite(pts).all(axis=1))
        raise ValueError(
            f'minimum_bounding_box got {bad} of {len(pts)} points with non-finite coordinates '
            '(NaN or inf); drop them first'
        )
    return np.ascontiguousarray(pts)


def _check_knob(name: str, value: object, low: int) -> int:
    """Return `value` as an int; raise ValueError unless it is an integer (not a bool) >= `low`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f'{name} must be an integer >= {low}, got {value!r}')
    return int(value)


def fit_box(
    points: ArrayLike,
    *,
    seed: int = 0,
    sample_size: int = 200,
    grid_size: int = 0,
    candidates: int = CANDIDATE_AXES,
    starts: int = STARTS,
    max_rounds: int = 3,
    exhaustive: int = 32,
    pair_edges: int = 12,
    sharp_edges: int = SHARP_EDGES,
    coreset_cells: int = 32,
    coreset_min: int = CORESET_MIN_POINTS,
    walk_steps: int = 6,
    walk_axes: int = 3,
    distinct_starts: int = 1,
    edge_pivots: int = 1,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """
    Return the minimum-volume oriented box enclosing `points` as plain arrays.

    The box always encloses every point (to 1e-9 of its size) and has a right-handed rotation;
    the result is deterministic for a given seed. Degenerate clouds give zero extents where the
    data has none (see the module notes). The knobs' defaults were chosen on the shared reference
    clouds (volume within 1 % of the best known) and on children-like clouds (cost).

    :param points: (N, 3) points (a single (3,) point is accepted), N >= 1, finite.
    :param seed: seed of the random sample of hull vertices used to rank candidate axes.
    :param sample_size: hull vertices sampled to measure widths in the ranking bound (the paper
        samples 200 points); the rotations and the polish always use the whole hull.
    :param grid_size: half-width of Barequet and Har-Peled's grid of directions searched around
        the best polished frame (13 directions for 1, 49 for 2; 0 turns the grid off; the paper
        uses 3).
    :param candidates: facet normals (ranked by the volume bound), and half as many edge-pair
        normals, whose best box is computed.
    :param starts: best distinct candidate boxes polished by alternating rotating calipers,
        halved every round.
    :param max_rounds: most polishing rounds, and most grid searches.
    :param exhaustive: hulls with at most this many facets try every distinct facet normal
        without ranking.
    :param pair_edges: longest hull edges whose pairs give candidate axes.
    :param sharp_edges: hull edges of largest length times turning angle whose pairs give
        candidate axes too (a quarter of `candidates` of them kept; 0 turns them off).
    :param coreset_cells: columns per side of the grid coreset for large clouds (0: never).
    :param coreset_min: clouds of at least this many points are hulled on their grid coreset;
        smaller ones on all points. A coreset's frame is re-checked against every point: points
        sticking out of its box by more than
        :data:`~mvbb_ros.geometry.boxfit.enclose.LEAK_TOLERANCE` join the hull and the frame is
        walked again.
    :param walk_steps: halvings of the final walk of the box's axis on the sphere (first tilt
        :data:`WALK_STEP` radians, eight directions; 0 turns it off): it finds the minimal boxes
        flush with two hull edges that lie between the candidate axes and the grid's.
    :param walk_axes: the box's axes walked in turn (1 to 3; more escape more local minima
        where no tilt of the first axis helps, at the cost of another, shorter walk each).
    :param distinct_starts: 1: the polish starts from the smallest boxes whose axes do not pair
        up within :data:`~mvbb_ros.geometry.boxfit.search.SAME_START`; 0: from the smallest boxes,
        near-copies included.
    :param edge_pivots: 1: after the walks, turn the box about the axes that keep a hull edge
        flush with a face of its thinnest extent
        (:func:`~mvbb_ros.geometry.boxfit.search.pivot_thinnest`): the ridge of thin boxes that
        no tilt of the walk follows; 0: off.
    :return: centre (3,), rotation (3, 3) with the box axes as columns, full extents (3,), in
        the units and frame of the points.
    :raises ValueError: on an empty array, a wrong shape, non-finite coordinates or bad knobs.
    """
    knobs = _knobs(
        seed=seed,
        sample_size=sample_size,
        grid_size=grid_size,
        candidates=candidates,
        starts=starts,
        max_rounds=max_rounds,
        exhaustive=exhaustive,
        pair_edges=pair_edges,
        sharp_edges=sharp_edges,
        coreset_cells=coreset_cells,
        coreset_min=coreset_min,
        walk_steps=walk_steps,
        walk_axes=walk_axes,
        distinct_starts=distinct_starts,
        edge_pivots=edge_pivots,
    )
    return _run(_as_points(points), knobs)


class _Knobs(NamedTuple):
    """The knobs of :func:`fit_box`, checked, in the kernel's order."""

    seed: int
    sample_size: int
    grid_size: int
    candidates: int
    starts: int
    max_rounds: int
    exhaustive: int
    pair_edges: int
    sharp_edges: int
    coreset_cells: int
    coreset_min: int
    walk_steps: int
    walk_axes: int
    distinct_starts: int
    edge_pivots: int


def _knobs(
    *,
    seed: int,
    sample_size: int,
    grid_size: int,
    candidates: int,
    starts: int,
    max_rounds: int,
    exhaustive: int,
    pair_edges: int,
    sharp_edges: int,
    coreset_cells: int,
    coreset_min: int,
    walk_steps: int,
    walk_axes: int,
    distinct_starts: int,
    edge_pivots: int,
) -> _Knobs:
    """Check the knobs of :func:`fit_box` (ValueError naming a bad one); return them."""
    return _Knobs(
        _check_knob('seed', seed, 0) & (2**63 - 1),
        _check_knob('sample_size', sample_size, 1),
        _check_knob('grid_size', grid_size, 0),
        _check_knob('candidates', candidates, 1),
        _check_knob('starts', starts, 1),
        _check_knob('max_rounds', max_rounds, 0),
        _check_knob('exhaustive', exhaustive, 0),
        _check_knob('pair_edges', pair_edges, 0),
        _check_knob('sharp_edges', sharp_edges, 0),
        _check_knob('coreset_cells', coreset_cells, 0),
        _check_knob('coreset_min', coreset_min, 0),
        _check_knob('walk_steps', walk_steps, 0),
        _check_knob('walk_axes', walk_axes, 1),
        _check_flag('distinct_starts', distinct_starts),
        _check_flag('edge_pivots', edge_pivots),
    )


def _check_flag(name: str, value: int) -> int:
    if _check_knob(name, value, 0) > 1:
        raise ValueError(f'{name} must be 0 or 1, got {value!r}')
    return int(value)


def _run(points: FloatArray, knobs: _Knobs) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Run :func:`fit_kernel` on checked points and knobs."""
    return fit_kernel(
        points,
        knobs.seed,
        knobs.sample_size,
        knobs.grid_size,
        knobs.candidates,
        knobs.starts,
        knobs.max_rounds,
        knobs.exhaustive,
        knobs.pair_edges,
        knobs.sharp_edges,
        knobs.coreset_cells,
        knobs.coreset_min,
        hull_module.HULL_TOLERANCE,
        knobs.walk_steps,
        WALK_STEP,
        knobs.walk_axes,
        knobs.distinct_starts,
        knobs.edge_pivots,
    )


#: The default knobs (from :func:`fit_box`'s signature).
_DEFAULT_KNOBS = _knobs(**(fit_box.__kwdefaults__ or {}))
#: The knobs of a decomposition's light part fits (``part_search: light``): 6 starts, copies of
#: one basin's box included, fewer candidate axes and edge pairs (no sharp ones), a short walk
#: of the first axis only, and parts of 1,000 points or more hulled on a 12 x 12 grid coreset
#: (re-checked against every point, :func:`add_leaks`). Lighter than the default search: a
#: decomposition fits tens of parts a cloud. Smaller parts search as :data:`SMALL_PART_SEARCH`.
#: It misses the best basin on about one part in 200 (up to 1.07 x an exhaustive reference;
#: ``docs/performance.md``).
PART_SEARCH: dict[str, int] = {
    'candidates': 16,
    'starts': 6,
    'grid_size': 0,
    'pair_edges': 6,
    'sharp_edges': 0,
    'coreset_cells': 12,
    'coreset_min': 1000,
    'walk_steps': 2,
    'walk_axes': 1,
    'distinct_starts': 0,
    'edge_pivots': 0,
}
_PART_KNOBS = _DEFAULT_KNOBS._replace(**PART_SEARCH)
#: The knobs of light part fits of fewer than ``PART_SEARCH['coreset_min']`` points, hulled on
#: every point: their hulls are small, so their search is cheap and can afford 8 starts and a
#: longer walk of every axis (the light search's misses were mostly such parts).
SMALL_PART_SEARCH: dict[str, int] = {**PART_SEARCH, 'starts': 8, 'walk_steps': 4, 'walk_axes': 3}
_SMALL_PART_KNOBS = _DEFAULT_KNOBS._replace(**SMALL_PART_SEARCH)
#: The knobs of a decomposition's full part fits (``part_search: full``, the node's): the
#: default search, parts of 1,000 points or more hulled on its 32 x 32 grid coreset. Within
#: 1.01 x an exhaustive reference on 30,000 varied clouds, at about twice a light fit's time.
FULL_PART_SEARCH: dict[str, int] = {'coreset_min': 1000}
_FULL_PART_KNOBS = _DEFAULT_KNOBS._replace(**FULL_PART_SEARCH)
#: The knobs of a decomposition's root fit: the default search, hulled on the grid coreset from
#: 16,384 points on (instead of 65,536): dense curved clouds have thousands of hull vertices.
#: Within 1.01 x an exhaustive reference on 30,000 varied clouds, as the default fit
#: (``docs/performance.md``, the box fit's quality on varied clouds).
ROOT_SEARCH: dict[str, int] = {'coreset_min': 16384}


def fit_part(points: FloatArray, *, seed: int = 0, full: bool = False) -> Box:
    """
    Return the minimum-volume box of a decomposition's part, without checks.

    :func:`minimum_bounding_box` with the knobs of :data:`PART_SEARCH` (:data:`SMALL_PART_SEARCH`
    below its ``coreset_min`` points), or of :data:`FULL_PART_SEARCH` when `full`, and without
    its checks and conversions, for points known to be valid (the parts the decomposition cuts).

    :param points: (N, 3) C-contiguous float64 array of finite points, N >= 1 (not checked).
    :param seed: an integer >= 0 (not checked).
    :param full: the default search instead of the light one.
    :return: the box.
    """
    if full:
        knobs = _FULL_PART_KNOBS
    elif points.shape[0] < _PART_KNOBS.coreset_min:
        knobs = _SMALL_PART_KNOBS
    else:
        knobs = _PART_KNOBS
    return Box.trusted(*_run(points, knobs._replace(seed=seed & (2**63 - 1))))


def minimum_bounding_box(
    points: ArrayLike,
    *,
    seed: int = 0,
    sample_size: int = 200,
    grid_size: int = 0,
    candidates: int = CANDIDATE_AXES,
    starts: int = STARTS,
    max_rounds: int = 3,
    exhaustive: int = 32,
    pair_edges: int = 12,
    sharp_edges: int = SHARP_EDGES,
    coreset_cells: int = 32,
    coreset_min: int = CORESET_MIN_POINTS,
    walk_steps: int = 6,
    walk_axes: int = 3,
    distinct_starts: int = 1,
    edge_pivots: int = 1,
) -> Box:
    """
    Return the minimum-volume oriented box enclosing `points` (Barequet-Har-Peled style).

    :func:`fit_box` as a :class:`~mvbb_ros.geometry.box.Box` (same knobs). The box always
    encloses every point (to 1e-9 of its size) and has a right-handed rotation; the result is
    deterministic for a given seed. Degenerate clouds never fail: one point or duplicates give a
    zero-size box, collinear points a box with extents (length, 0, 0), coplanar points the
    plane's minimum-area rectangle with zero thickness. Coordinates are centred and scaled
    internally, so clouds far from the origin, huge or tiny keep their precision. On the shared
    reference clouds the volume is within 0.4 % of the best known (``benchmarks/mvbb.py``).

    :param points: (N, 3) points (a single (3,) point is accepted), N >= 1, finite.
    :param seed: seed of the random sample of hull vertices used to rank candidate axes.
    :param sample_size: see :func:`fit_box`.
    :param grid_size: see :func:`fit_box`.
    :param candidates: see :func:`fit_box`.
    :param starts: see :func:`fit_box`.
    :param max_rounds: see :func:`fit_box`.
    :param exhaustive: see :func:`fit_box`.
    :param pair_edges: see :func:`fit_box`.
    :param sharp_edges: see :func:`fit_box`.
    :param coreset_cells: see :func:`fit_box`.
    :param coreset_min: see :func:`fit_box`.
    :param walk_steps: see :func:`fit_box`.
    :param walk_axes: see :func:`fit_box`.
    :param distinct_starts: see :func:`fit_box`.
    :param edge_pivots: see :func:`fit_box`.
    :return: the box, in the units and frame of the points.
    :raises ValueError: on an empty array, a wrong shape, non-finite coordinates or bad knobs.
    """
    center, rotation, extents = fit_box(
        points,
        seed=seed,
        sample_size=sample_size,
        grid_size=grid_size,
        candidates=candidates,
        starts=starts,
        max_rounds=max_rounds,
        exhaustive=exhaustive,
        pair_edges=pair_edges,
        sharp_edges=sharp_edges,
        coreset_cells=coreset_cells,
        coreset_min=coreset_min,
        walk_steps=walk_steps,
        walk_axes=walk_axes,
        distinct_starts=distinct_starts,
        edge_pivots=edge_pivots,
    )
    # The kernel's arrays are fresh and meet the box's invariants: no checks, no copies.
    return Box.trusted(center, rotation, extents)


def warm_up() -> None:
    """Run every kernel of this module once on tiny clouds (see :mod:`mvbb_ros.kernels`)."""
    rng = np.random.default_rng(0)
    for points in (rng.normal(size=(30, 3)), rng.normal(size=(2, 3)), np.zeros((1, 3))):
        fit_box(points)
    fit_box(rng.normal(size=(200, 3)), coreset_min=100)
    # The decomposition passes read-only points (numba compiles those apart): warm them too.
    frozen = rng.normal(size=(30, 3))
    frozen.flags.writeable = False
    fit_box(frozen)
