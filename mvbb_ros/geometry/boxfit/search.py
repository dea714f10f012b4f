"""
The orientation search of the minimum-volume box fit, in compiled code (numba).

:mod:`mvbb_ros.geometry.boxfit.fit` brings a cloud to its PCA frame at unit size and hulls it
(:mod:`mvbb_ros.geometry.boxfit.hull`); this module finds the frame of the smallest box of that
hull.

* For a fixed axis ``a``, the best rotation of the box about ``a`` (a *turn*) is the
  minimum-area rectangle of the hull's silhouette along ``a``
  (:func:`mvbb_ros.geometry.boxfit.turn.rotate_about`).
* A minimal box has a face flush with a hull facet, or adjacent faces flush with hull edges
  (O'Rourke 1985). Candidate axes (:func:`candidate_axes_kernel`) are the PCA axes, the facet
  normals and the normals of planes through two of the longest hull edges or two of the
  sharpest (length times the angle the hull turns there, :func:`sharpest_edges`), ranked by a lower
  bound on the volume (the hull's width times the area of its shadow) and thinned to one per
  degree, and the pairs of the :data:`SHARPEST_PAIRED` sharpest edges whatever their bound. A
  candidate whose bound is above the ``starts``-th smallest box turned so far cannot start the
  polish and is not turned.
* Local improvement (:func:`polish`): the best ``starts`` distinct candidate boxes (axes paired
  within :data:`SAME_START`) are turned, in turn, to their
  best rotation about one of their other axes, keeping the better half every round (successive
  halving); then (``grid_size`` > 0) Barequet and Har-Peled's grid of directions around the best
  frame is searched, and the polish resumes from any better box it finds (:func:`search_kernel`).
  Last, the best frame's first axis, then its next ones (``walk_axes``), walk on the sphere in
  small tilts while the best box shrinks, and the result is polished again (:func:`walk`,
  :func:`settle`): the polish's turns and the grid's directions are 90 and 45 degrees apart, and
  a minimal box with two faces flush with hull edges lies between them. Then (``edge_pivots``)
  the box's thinnest axis is turned about the hull edges flush with its faces
  (:func:`pivot_thinnest`): a thin box flush with an edge on each of its two large faces lies on
  a ridge of the volume that no tilt of the walk follows.

Cost, for a hull of H vertices, F ~ 2H facets and E ~ 3H edges: candidate ranking O(K (H + F))
for K = min(F, :data:`SHORTLIST` x candidates) + 66 candidate axes (fewer with the binned shadow
of large hulls and the 200-vertex width sample); then about 40 candidates, two per frame and
polish round (8, 4, 2, 1 frames) and 13 per grid round, and 8 per step of the walks (more where
they move): 100 to 200 axes,
O(F + E + S) each for a silhouette of S vertices (about sqrt(H) on smooth shapes; on large hulls
about 30 % of the edges, :mod:`mvbb_ros.geometry.boxfit.turn`). The volume
bounds rule out about two fifths of the candidates and some grid directions before they are
turned (on the parts of the shared scans).
"""

from __future__ import annotations

import math

from mvbb_ros.geometry.boxfit.rectangle import sift_down, sort_xy_kernel
from mvbb_ros.geometry.boxfit.turn import cube_cell, new_work, rotate_about
import numba as nb
import numpy as np

#: Relative volume gain below which polishing stops (far below the 1 % quality target).
POLISH_TOLERANCE = 1e-5
#: Cube-map cells per face side for binning facet area vectors in the shadow-area bound.
SHADOW_CELLS = 4
#: Facet counts up to which the shadow area is summed over the facets themselves.
EXACT_SHADOW_FACETS = 96
#: Relative slack of the volume bounds when they rule out a candidate axis: far above their
#: rounding (and the hull tolerance's effect on the shadow area, about 1e-11), far below a gain.
BOUND_SLACK = 1e-6
#: Two turned boxes whose axes pair up within this angle (radians) are one start of the polish:
#: the starts are the smallest *distinct* boxes, so that near-copies of one basin's box do not
#: crowd out another basin.
SAME_START = math.radians(3.0)
#: Facets ranked by their volume bound, per candidate axis: the largest by area.
SHORTLIST = 8
#: Tilt directions of :func:`walk` around the axis.
WALK_DIRECTIONS = 8
#: Halvings fewer in the walks of a box's later axes (:func:`settle`): they look for another
#: basin, the first axis's walk converges finely. 2 rather than 3: a later axis's finer tilt
#: still found the basin of a 343-point part that the shorter walk left at 1.0159 x the
#: exhaustive reference, for 1.6 % of a default fit's time (1 cost 4.8 %; ``CHANGELOG.md``).
LATER_WALK_SHORTER = 2
#: The tilt directions of :func:`walk` (cosine and sine of multiples of 45 degrees).
_WALK_COS = np.cos(np.arange(WALK_DIRECTIONS) * (2.0 * np.pi / WALK_DIRECTIONS))
_WALK_SIN = np.sin(np.arange(WALK_DIRECTIONS) * (2.0 * np.pi / WALK_DIRECTIONS))
#: Candidate axes within about 1 degree (1 - |cos|) of one already taken are skipped.
_PARALLEL = 1.5e-4
#: The pivots of :func:`pivot_thinnest` tilt the box's thinnest axis by at most this (radians).
#: On 600 varied clouds (``benchmarks/boxfit_quality.py``'s seed 42) every pivot that shrank a
#: box tilted it by 3.4 degrees or less; the limit leaves about a third of the pivots to turn.
PIVOT_TILT = math.radians(5.0)
#: The pairs of this many of the sharpest edges are candidate axes whatever their volume bound:
#: the bound (width times shadow area) ranked the pair of a minimal box's two sharpest flush
#: edges 103rd of 153 on a 1,227-point cut of a Kinect scan, whose search then ended 1.049 x
#: the reference.
SHARPEST_PAIRED = 4
#: Hull vertices within this share of the box's largest extent of a face touch it.
_TOUCHING = 1e-9


# Small helpers ------------------------------------------------------------------------------


@nb.njit
def _ranking(values: np.ndarray, count: int) -> np.ndarray:
    """Return the order of ``values[:count]``, smallest first, ties by index (stable)."""
    order = np.arange(count)
    # Sorting (value, index) pairs, so that ties keep their index order.
    ties = np.arange(count).astype(np.float64)
    sort_xy_kernel(values, ties, order, count)
    return order


@nb.njit
def _same_frame(first: np.ndarray, second: np.ndarray, cos_limit: float) -> bool:
    """Tell whether every axis of `first` is within the angle of some axis of `second`."""
    for i in range(3):
        best = 0.0
        for j in range(3):
            dot = abs(
                first[0, i] * second[0, j]
                + first[1, i] * second[1, j]
                + first[2, i] * second[2, j]
            )
            best = max(best, dot)
        if best < cos_limit:
            return False
    return True


@nb.njit
def copy_frame(source: np.ndarray, target: np.ndarray) -> None:
    """Copy a 3x3 array (an explicit loop: slice assignment compiles slowly in numba)."""
    for i in range(3):
        for j in range(3):
            target[i, j] = source[i, j]


@nb.njit
def _cross_into(
    out: np.ndarray, row: int, ax: float, ay: float, az: float, bx: float, by: float, bz: float
) -> None:
    out[row, 0] = ay * bz - az * by
    out[row, 1] = az * bx - ax * bz
    out[row, 2] = ax * by - ay * bx


# Candidate axes -------------------------------------------------------------------------------


@nb.njit
def _binned_area_vectors(normals: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """
    Sum the facet area vectors over a cube-map binning of their normals.

    Half the sum of |A . n| over the bins is a lower bound of the shadow area along n (triangle
    inequality), and a cheap one: at most 6 x 4 x 4 bins whatever the hull's size. Only the
    bins that hold area are returned (a third to a half of them on the parts of the shared
    scans); an empty bin's term is +0.0, so the sums are the same bit for bit.
    """
    cells = SHADOW_CELLS
    binned = np.zeros((6 * cells * cells, 3))
    for f in range(normals.shape[0]):
        row = cube_cell(normals[f, 0], normals[f, 1], normals[f, 2], cells)
        for k in range(3):
            binned[row, k] += areas[f] * normals[f, k]
    size = 0
    for row in range(binned.shape[0]):
        if binned[row, 0] != 0.0 or binned[row, 1] != 0.0 or binned[row, 2] != 0.0:
            for k in range(3):
                binned[size, k] = binned[row, k]
            size += 1
    return binned[:size]


@nb.njit
def _volume_bounds(
    axes: np.ndarray, vertices: np.ndarray, sample: np.ndarray, shadow: np.ndarray
) -> np.ndarray:
    """
    Return a lower bound on the volume of any box with each axis.

    The box's extent along the axis is at least the hull's width (measured on a sample of the
    vertices: lower still), and its face across the axis covers the hull's shadow, whose area is
    half the sum of |A_f . n| over the facet area vectors A_f (binned or not).
    """
    count = axes.shape[0]
    bounds = np.empty(count)
    for j in range(count):
        ax = axes[j, 0]
        ay = axes[j, 1]
        az = axes[j, 2]
        area = 0.0
        for f in range(shadow.shape[0]):
            area += abs(ax * shadow[f, 0] + ay * shadow[f, 1] + az * shadow[f, 2])
        low = np.inf
        high = -np.inf
        for s in range(sample.shape[0]):
            i = sample[s]
            h = ax * vertices[i, 0] + ay * vertices[i, 1] + az * vertices[i, 2]
            low = min(low, h)
            high = max(high, h)
        bounds[j] = 0.5 * area * (high - low)
    return bounds


@nb.njit
def _shadow_vectors(normals: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Return the facet area vectors of the shadow bound (binned for large hulls)."""
    if normals.shape[0] > EXACT_SHADOW_FACETS:
        return _binned_area_vectors(normals, areas)
    shadow = np.empty((normals.shape[0], 3))
    for f in range(normals.shape[0]):
        for k in range(3):
            shadow[f, k] = areas[f] * normals[f, k]
    return shadow


@nb.njit
def _take_distinct(
    axes: np.ndarray,
    values: np.ndarray,
    bounds: np.ndarray,
    count: int,
    out: np.ndarray,
    out_bounds: np.ndarray,
    size: int,
) -> int:
    """
    Append to ``out[size:]`` up to `count` axes by increasing value (ties by index), no repeats.

    Each taken axis's volume bound (from `bounds`) goes to the same row of `out_bounds`.

    A direction and its opposite are one axis; repeats of any axis already in ``out`` are
    skipped. The axes come off a heap one at a time: usually a sixth of them are looked at, and
    a full sort cost more than the rest of the ranking. :return: the new size of `out`.
    """
    # The 2D sort's max-heap on (-value, -index): its top is the smallest value, ties by index
    # (negation is exact, so the order is the sort's).
    remaining = values.shape[0]
    keys = -values
    ties = -np.arange(remaining).astype(np.float64)
    heap = np.arange(remaining)
    for root in range(remaining // 2 - 1, -1, -1):
        sift_down(keys, ties, heap, root, remaining)
    start = size
    while remaining > 0 and size - start < count and size < out.shape[0]:
        j = heap[0]
        remaining -= 1
        heap[0] = heap[remaining]
        sift_down(keys, ties, heap, 0, remaining)
        repeated = False
        for i in range(size):
            dot = axes[j, 0] * out[i, 0] + axes[j, 1] * out[i, 1] + axes[j, 2] * out[i, 2]
            if abs(dot) > 1.0 - _PARALLEL:
                repeated = True
                break
        if not repeated:
            for k in range(3):
                out[size, k] = axes[j, k]
            out_bounds[size] = bounds[j]
            size += 1
    return size


@nb.njit
def _keep_largest(values: np.ndarray, ids: np.ndarray, value: float, item: int) -> None:
    """Insert `item` into the largest-first `values` and `ids`, after its equals; drop the last."""
    i = values.shape[0] - 1
    while i > 0 and values[i - 1] < value:
        values[i] = values[i - 1]
        ids[i] = ids[i - 1]
        i -= 1
    values[i] = value
    ids[i] = item


@nb.njit
def longest_edges(vertices: np.ndarray, edges: np.ndarray, count: int) -> np.ndarray:
    """Return the ids of the `count` longest hull edges, longest first (ties in edge order)."""
    count = min(count, edges.shape[0])
    longest = np.full(count, -1, dtype=np.int64)
    lengths = np.full(count, -1.0)
    for e in range(edges.shape[0]):
        length = 0.0
        for k in range(3):
            length += (vertices[edges[e, 1], k] - vertices[edges[e, 0], k]) ** 2
        if count > 0 and length > lengths[count - 1]:
            _keep_largest(lengths, longest, length, e)
    return longest


@nb.njit
def sharpest_edges(
    vertices: np.ndarray,
    edges: np.ndarray,
    edge_facets: np.ndarray,
    normals: np.ndarray,
    count: int,
) -> np.ndarray:
    """
    Return the ids of the `count` hull edges of largest length times turning angle, largest first.

    A face flush with an edge but with neither of its facets has its normal between the two
    facets' normals, on an arc as long as the angle the hull turns at the edge: a long edge
    between nearly coplanar facets offers almost no such faces (the facets' normals are candidate
    axes already), a sharp one offers many. Ties keep the edges' order.
    """
    count = min(count, edges.shape[0])
    sharpest = np.full(count, -1, dtype=np.int64)
    scores = np.full(count, -1.0)
    for e in range(edges.shape[0] if count > 0 else 0):
        length = 0.0
        for k in range(3):
            length += (vertices[edges[e, 1], k] - vertices[edges[e, 0], k]) ** 2
        length = math.sqrt(length)
        f = edge_facets[e, 0]
        g = edge_facets[e, 1]
        cosine = normals[f, 0] * normals[g, 0] + normals[f, 1] * normals[g, 1]
        cosine += normals[f, 2] * normals[g, 2]
        cosine = min(1.0, max(-1.0, cosine))
        # The turn is at most pi sqrt((1 - cos) / 2) (as sin x >= 2 x / pi on [0, pi / 2]):
        # an edge that cannot beat the last one kept needs no arc cosine.
        if length * math.pi * math.sqrt(0.5 * (1.0 - cosine)) <= scores[count - 1]:
            continue
        score = length * math.acos(cosine)
        if score > scores[count - 1]:
            _keep_largest(scores, sharpest, score, e)
    return sharpest


@nb.njit
def edge_pair_axes(vertices: np.ndarray, edges: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """
    Return the unit normals of the planes spanned by two of the `chosen` hull edges (their ids).

    A face can be flush with two hull edges without lying on a facet (for a tetrahedron, with two
    opposite edges); such faces' normals are candidate axes too.
    """
    count = chosen.shape[0]
    if count < 2:
        return np.zeros((0, 3))
    directions = np.empty((count, 3))
    for i in range(count):
        e = chosen[i]
        length = 0.0
        for k in range(3):
            length += (vertices[edges[e, 1], k] - vertices[edges[e, 0], k]) ** 2
        norm = math.sqrt(length)
        for k in range(3):
            directions[i, k] = (vertices[edges[e, 1], k] - vertices[edges[e, 0], k]) / norm
    out = np.empty((count * (count - 1) // 2, 3))
    size = 0
    for i in range(count):
        for j in range(i + 1, count):
            _cross_into(
                out,
                size,
                directions[i, 0],
                directions[i, 1],
                directions[i, 2],
                directions[j, 0],
                directions[j, 1],
                directions[j, 2],
            )
            norm = math.sqrt(out[size, 0] ** 2 + out[size, 1] ** 2 + out[size, 2] ** 2)
            if norm > 1e-9:
                for k in range(3):
                    out[size, k] /= norm
                size += 1
    return out[:size]


@nb.njit
def _sample(count: int, size: int, seed: int) -> np.ndarray:
    """Return `size` distinct indices below `count` (all when fewer), drawn from `seed`."""
    indices = np.arange(count)
    if count <= size:
        return indices
    state = np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(0x2545F4914F6CDD1D)
    for i in range(size):
        # xorshift64*
        state ^= state >> np.uint64(12)
        state ^= state << np.uint64(25)
        state ^= state >> np.uint64(27)
        draw = (state * np.uint64(0x2545F4914F6CDD1D)) >> np.uint64(11)
        j = i + int(draw % np.uint64(count - i))
        indices[i], indices[j] = indices[j], indices[i]
    return indices[:size].copy()


@nb.njit(cache=True, nogil=True)
def candidate_axes_kernel(
    vertices: np.ndarray,
    normals: np.ndarray,
    areas: np.ndarray,
    edges: np.ndarray,
    edge_facets: np.ndarray,
    seed: int,
    candidates: int,
    pair_edges: int,
    sharp_edges: int,
    sample_size: int,
    exhaustive: int,
) -> tuple:
    """
    Return the axes whose best box is computed (PCA axes, facet normals, edge-pair normals).

    The coordinates are those of the PCA frame, so its axes are the coordinate axes. Hulls with
    at most `exhaustive` facets give every distinct facet normal; larger ones the `candidates`
    of least volume bound (:func:`_volume_bounds`). Edge-pair normals of the `pair_edges`
    longest edges are ranked the same way, and half as many kept; then those of the
    `sharp_edges` sharpest edges (:func:`sharpest_edges`), a quarter as many, and last the pairs
    of the :data:`SHARPEST_PAIRED` sharpest, unranked.

    :return: the axes (K, 3) and their volume bounds (K,).
    """
    sample = _sample(vertices.shape[0], sample_size, seed)
    shadow = _shadow_vectors(normals, areas)
    facet_count = normals.shape[0] if normals.shape[0] <= exhaustive else candidates
    pairs = edge_pair_axes(vertices, edges, longest_edges(vertices, edges, pair_edges))
    sharpest = sharpest_edges(vertices, edges, edge_facets, normals, sharp_edges)
    sharp_pairs = edge_pair_axes(vertices, edges, sharpest)
    paired = edge_pair_axes(vertices, edges, sharpest[:SHARPEST_PAIRED])
    out = np.empty((3 + facet_count + candidates // 2 + candidates // 4 + paired.shape[0], 3))
    out_bounds = np.empty(out.shape[0])
    size = 0
    for k in range(3):
        for j in range(3):
            out[size, j] = 1.0 if j == k else 0.0
        size += 1
    pca_bounds = _volume_bounds(out[:3], vertices, sample, shadow)
    for k in range(3):
        out_bounds[k] = pca_bounds[k]
    if normals.shape[0] <= exhaustive:
        bounds = _volume_bounds(normals, vertices, sample, shadow)
        order = np.arange(normals.shape[0]).astype(np.float64)  # every normal, in order
        size = _take_distinct(normals, order, bounds, facet_count, out, out_bounds, size)
    else:
        # Only the largest facets are ranked: a box's face lies on a large facet far more often
        # than on a sliver, and the bounds are most of the ranking's cost.
        shortlist = normals
        listed = SHORTLIST * candidates
        if normals.shape[0] > listed:
            largest = np.argsort(-areas, kind='mergesort')[:listed]
            largest.sort()  # hull order again: ties in the ranking as without the shortlist
            shortlist = np.empty((listed, 3))
            for i in range(listed):
                for k in range(3):
                    shortlist[i, k] = normals[largest[i], k]
        bounds = _volume_bounds(shortlist, vertices, sample, shadow)
        size = _take_distinct(shortlist, bounds, bounds, facet_count, out, out_bounds, size)
    if pairs.shape[0] > 0 and candidates // 2 > 0:
        bounds = _volume_bounds(pairs, vertices, sample, shadow)
        size = _take_distinct(pairs, bounds, bounds, candidates // 2, out, out_bounds, size)
    if sharp_pairs.shape[0] > 0 and candidates // 4 > 0:
        bounds = _volume_bounds(sharp_pairs, vertices, sample, shadow)
        size = _take_distinct(sharp_pairs, bounds, bounds, candidates // 4, out, out_bounds, size)
    if paired.shape[0] > 0:
        # The pairs of the very sharpest edges whatever their bounds (in pair order).
        bounds = _volume_bounds(paired, vertices, sample, shadow)
        order = np.arange(paired.shape[0]).astype(np.float64)
        size = _take_distinct(paired, order, bounds, paired.shape[0], out, out_bounds, size)
    return out[:size].copy(), out_bounds[:size].copy()


# The search ------------------------------------------------------------------------------------


@nb.njit
def grid_axes(frame: np.ndarray, grid_size: int) -> np.ndarray:
    """
    Return Barequet and Har-Peled's grid of directions around a frame.

    The unit directions ``i a + j b + k c`` for integers ``|i|, |j|, |k| <= grid_size`` with no
    common divisor (a, b, c the frame's columns), one per line through the origin.
    """
    side = 2 * grid_size + 1
    out = np.empty((side * side * side, 3))
    size = 0
    for i in range(-grid_size, grid_size + 1):
        for j in range(-grid_size, grid_size + 1):
            for k in range(-grid_size, grid_size + 1):
                # One of each opposite pair: the first non-zero coefficient is positive.
                if not (i > 0 or (i == 0 and (j > 0 or (j == 0 and k > 0)))):
                    continue
                a = abs(i)
                b = abs(j)
                while b:
                    a, b = b, a % b
                b = abs(k)
                while b:
                    a, b = b, a % b
                if a != 1:
                    continue
                x = i * frame[0, 0] + j * frame[0, 1] + k * frame[0, 2]
                y = i * frame[1, 0] + j * frame[1, 1] + k * frame[1, 2]
                z = i * frame[2, 0] + j * frame[2, 1] + k * frame[2, 2]
                norm = math.sqrt(x * x + y * y + z * z)
                out[size, 0] = x / norm
                out[size, 1] = y / norm
                out[size, 2] = z / norm
                size += 1
    return out[:size].copy()


@nb.njit
def polish(
    vertices: np.ndarray,
    work: tuple,
    frames: np.ndarray,
    volumes: np.ndarray,
    max_rounds: int,
) -> tuple:
    """
    Improve boxes by turning each, in turn, to its best rotation about one of its other axes.

    Each frame is best about its first axis. Every round tries the other two axes of every
    frame still improving and keeps the better turn when it gains more than
    :data:`POLISH_TOLERANCE`; that axis then comes first. After each round the worse half of
    the frames is dropped (successive halving), so only the best start is followed to the end.

    :return: the best volume and frame (3, 3).
    """
    count = frames.shape[0]
    improving = np.ones(count, dtype=np.bool_)
    trial = np.empty((3, 3))
    best_trial = np.empty((3, 3))
    for _ in range(max_rounds):
        moved = False
        for s in range(count):
            if not improving[s]:
                continue
            best = np.inf
            for column in (1, 2):
                volume = rotate_about(
                    vertices,
                    work,
                    frames[s, 0, column],
                    frames[s, 1, column],
                    frames[s, 2, column],
                    trial,
                )
                if volume < best:
                    best = volume
                    copy_frame(trial, best_trial)
            if best < volumes[s] * (1.0 - POLISH_TOLERANCE):
                volumes[s] = best
                copy_frame(best_trial, frames[s])
                moved = True
            else:
                improving[s] = False
        if not moved:
            break
        # Keep the better half, best first (an insertion sort: a handful of frames).
        order = _ranking(volumes, count)
        kept = (count + 1) // 2
        new_frames = np.empty((kept, 3, 3))
        new_volumes = np.empty(kept)
        new_improving = np.empty(kept, dtype=np.bool_)
        for i in range(kept):
            copy_frame(frames[order[i]], new_frames[i])
            new_volumes[i] = volumes[order[i]]
            new_improving[i] = improving[order[i]]
        frames = new_frames
        volumes = new_volumes
        improving = new_improving
        count = kept
    best = 0
    for s in range(1, count):
        if volumes[s] < volumes[best]:
            best = s
    frame = np.empty((3, 3))
    copy_frame(frames[best], frame)
    return volumes[best], frame


@nb.njit
def walk(
    vertices: np.ndarray,
    work: tuple,
    frame: np.ndarray,
    volume: float,
    first_step: float,
    steps: int,
) -> tuple:
    """
    Tilt a box's first axis in small steps while its best rotation about the axis shrinks.

    A pattern search on the sphere of axes: the axis is tilted by `first_step` radians towards
    each of eight directions across it (its box's other axes and their diagonals), moving to the
    first tilt whose best box is smaller; with none, the step is halved, `steps` times in all.
    The polish's turns are 90 degree jumps and the grid's 13 directions 45 degrees apart: a
    minimal box with two faces flush with hull edges (not a facet) lies between them.

    :return: the volume and frame (3, 3) found.
    """
    trial = np.empty((3, 3))
    best_frame = frame.copy()
    step = first_step
    halvings = 0
    last = 0  # the direction of the last move, tried first (a walk tends to keep its heading)
    while halvings < steps:
        moved = False
        ax, ay, az = best_frame[0, 0], best_frame[1, 0], best_frame[2, 0]
        for turn in range(WALK_DIRECTIONS):
            d = (last + turn) % WALK_DIRECTIONS
            c = _WALK_COS[d] * step
            s = _WALK_SIN[d] * step
            x = ax + c * best_frame[0, 1] + s * best_frame[0, 2]
            y = ay + c * best_frame[1, 1] + s * best_frame[1, 2]
            z = az + c * best_frame[2, 1] + s * best_frame[2, 2]
            norm = math.sqrt(x * x + y * y + z * z)
            found = rotate_about(vertices, work, x / norm, y / norm, z / norm, trial)
            if found < volume * (1.0 - POLISH_TOLERANCE):
                volume = found
                copy_frame(trial, best_frame)
                moved = True
                last = d
                break
        if not moved:
            step *= 0.5
            halvings += 1
    return volume, best_frame


@nb.njit(cache=True, nogil=True)
def search_kernel(
    vertices: np.ndarray,
    normals: np.ndarray,
    areas: np.ndarray,
    edges: np.ndarray,
    edge_facets: np.ndarray,
    seed: int,
    candidates: int,
    pair_edges: int,
    sharp_edges: int,
    sample_size: int,
    exhaustive: int,
    starts: int,
    max_rounds: int,
    grid_size: int,
    walk_steps: int,
    walk_step: float,
    walk_axes: int,
    distinct: int,
    edge_pivots: int,
) -> tuple:
    """
    Search the frame of the minimum-volume box of a full-dimensional hull.

    :return: the volume (of the hull vertices) and the frame (3, 3), columns the box axes.
    """
    work = new_work(vertices, normals, edges, edge_facets)
    axes, bounds = candidate_axes_kernel(
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
    )
    count = axes.shape[0]
    kept = max(1, min(starts, count))
    # The starts of the polish: the `kept` smallest boxes (with `distinct`, distinct ones), kept
    # in a list as the axes are turned in order. With `distinct`, a box the same as one listed
    # (axes paired within SAME_START) replaces the larger ones it repeats, or is dropped when
    # one listed is no larger. An axis whose volume bound is above the last of a full list
    # cannot change it, and is not turned (the slack covers the bound's rounding; the starts
    # are the same as with every axis turned).
    same = math.cos(SAME_START)
    listed = np.empty(kept, dtype=np.int64)
    listed_volumes = np.full(kept, np.inf)
    filled = 0
    frames = np.empty((count, 3, 3))
    for j in range(count):
        if filled == kept and bounds[j] * (1.0 - BOUND_SLACK) > listed_volumes[kept - 1]:
            continue
        volume = rotate_about(
            vertices,
            work,
            axes[j, 0],
            axes[j, 1],
            axes[j, 2],
            frames[j],
        )
        if filled == kept and not volume < listed_volumes[kept - 1]:
            continue
        repeated = False
        for s in range(filled if distinct else 0):
            if listed_volumes[s] <= volume and _same_frame(frames[j], frames[listed[s]], same):
                repeated = True
                break
        if repeated:
            continue
        left = 0
        for s in range(filled):
            if not distinct or not _same_frame(frames[j], frames[listed[s]], same):
                listed[left] = listed[s]
                listed_volumes[left] = listed_volumes[s]
                left += 1
        filled = left
        # Insert after the listed ones no larger (ties keep the axes' order).
        i = min(filled, kept - 1)
        while i > 0 and listed_volumes[i - 1] > volume:
            listed[i] = listed[i - 1]
            listed_volumes[i] = listed_volumes[i - 1]
            i -= 1
        listed[i] = j
        listed_volumes[i] = volume
        filled = min(filled + 1, kept)
    start_frames = np.empty((filled, 3, 3))
    start_volumes = np.empty(filled)
    for i in range(filled):
        copy_frame(frames[listed[i]], start_frames[i])
        start_volumes[i] = listed_volumes[i]
    volume, frame = polish(vertices, work, start_frames, start_volumes, max_rounds)
    # Barequet and Har-Peled's grid of directions around the best frame: when the best box about
    # one of them is smaller, polish it and look again (the alternating rotations alone can stop
    # where no single-axis turn helps but a turn about a diagonal does).
    # A direction whose bound is above the best box cannot give a smaller one: not turned.
    trial = np.empty((1, 3, 3))
    for _ in range(max_rounds if grid_size > 0 else 0):
        grid = grid_axes(frame, grid_size)
        sample = _sample(vertices.shape[0], sample_size, seed)
        bounds = _volume_bounds(grid, vertices, sample, _shadow_vectors(normals, areas))
        best = volume
        for j in range(grid.shape[0]):
            if bounds[j] * (1.0 - BOUND_SLACK) > best:
                continue
            found = rotate_about(
                vertices,
                work,
                grid[j, 0],
                grid[j, 1],
                grid[j, 2],
                frames[0],
            )
            if found < best:
                best = found
                copy_frame(frames[0], trial[0])
        if not best < volume * (1.0 - POLISH_TOLERANCE):
            break
        found_volume = np.array([best])
        volume, frame = polish(vertices, work, trial.copy(), found_volume, max_rounds)
    return settle(
        vertices,
        work,
        frame,
        volume,
        max_rounds,
        walk_steps,
        walk_step,
        walk_axes,
        edge_pivots,
    )


@nb.njit
def pivot_thinnest(vertices: np.ndarray, work: tuple, frame: np.ndarray, volume: float) -> tuple:
    """
    Turn a box about the axes that keep an edge flush with a face of its thinnest extent.

    Where a hull edge lies in one face across the box's thinnest axis and the opposite face
    touches a vertex, the box can shrink by tilting that axis about the flush edge until an
    edge at the vertex is flush too: a ridge of the volume (a minimal box flush with two hull
    edges, O'Rourke 1985) that no tilt of :func:`walk` follows, since every tilt off the edge
    lifts one of its ends. The candidate axes are the normals of the planes through a flush
    edge and an edge leaving a touching vertex of the opposite face, within :data:`PIVOT_TILT`.

    :param work: the hull's edges and reusable arrays
        (:func:`~mvbb_ros.geometry.boxfit.turn.new_work`).
    :return: the volume and frame (3, 3) of the smallest box found (the input when none is
        smaller by :data:`POLISH_TOLERANCE`).
    """
    edges = work[10]  # new_work's layout: the hull's (E, 2) edges
    count = vertices.shape[0]
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    for i in range(count):
        for k in range(3):
            h = vertices[i, 0] * frame[0, k] + vertices[i, 1] * frame[1, k]
            h += vertices[i, 2] * frame[2, k]
            low[k] = min(low[k], h)
            high[k] = max(high[k], h)
    thin = 0
    for k in range(1, 3):
        if high[k] - low[k] < high[thin] - low[thin]:
            thin = k
    nx, ny, nz = frame[0, thin], frame[1, thin], frame[2, thin]
    tolerance = _TOUCHING * max(high[0] - low[0], high[1] - low[1], high[2] - low[2])
    at_low = np.empty(count, dtype=np.bool_)
    at_high = np.empty(count, dtype=np.bool_)
    for i in range(count):
        h = nx * vertices[i, 0] + ny * vertices[i, 1] + nz * vertices[i, 2]
        at_low[i] = h - low[thin] <= tolerance
        at_high[i] = high[thin] - h <= tolerance
    limit = math.cos(PIVOT_TILT)
    best_frame = frame.copy()
    best = volume
    trial = np.empty((3, 3))
    axis = np.empty((1, 3))
    for side in range(2):
        flush = at_low if side == 0 else at_high
        opposite = at_high if side == 0 else at_low
        for e in range(edges.shape[0]):
            a, b = edges[e, 0], edges[e, 1]
            if not (flush[a] and flush[b]):
                continue
            dx = vertices[b, 0] - vertices[a, 0]
            dy = vertices[b, 1] - vertices[a, 1]
            dz = vertices[b, 2] - vertices[a, 2]
            for f in range(edges.shape[0]):
                c, d = edges[f, 0], edges[f, 1]
                if opposite[c] == opposite[d]:  # an edge leaving a touching vertex
                    continue
                _cross_into(
                    axis,
                    0,
                    dx,
                    dy,
                    dz,
                    vertices[d, 0] - vertices[c, 0],
                    vertices[d, 1] - vertices[c, 1],
                    vertices[d, 2] - vertices[c, 2],
                )
                x, y, z = axis[0, 0], axis[0, 1], axis[0, 2]
                norm = math.sqrt(x * x + y * y + z * z)
                if not abs(x * nx + y * ny + z * nz) >= limit * norm or norm == 0.0:
                    continue
                found = rotate_about(vertices, work, x / norm, y / norm, z / norm, trial)
                if found < best * (1.0 - POLISH_TOLERANCE):
                    best = found
                    copy_frame(trial, best_frame)
    return best, best_frame


@nb.njit
def settle(
    vertices: np.ndarray,
    work: tuple,
    frame: np.ndarray,
    volume: float,
    max_rounds: int,
    walk_steps: int,
    walk_step: float,
    walk_axes: int,
    edge_pivots: int,
) -> tuple:
    """
    Walk each of a frame's first `walk_axes` axes in turn (:func:`walk`), then polish the result.

    A box stuck where no tilt of its first axis helps can still shrink when another of its axes
    tilts (the best rotation about that axis is found exactly, the others follow); each walk
    starts from the frame the previous one found, the later ones :data:`LATER_WALK_SHORTER`
    halvings shorter. With `edge_pivots`, the polished box is then turned about the pivots of
    its thinnest axis (:func:`pivot_thinnest`). :return: volume and frame.
    """
    if walk_steps <= 0:
        return volume, frame
    for pivot in range(walk_axes):
        if pivot > 0:
            # The next axis first (a cyclic turn of the columns keeps the frame right-handed).
            rolled = np.empty((3, 3))
            for i in range(3):
                for k in range(3):
                    rolled[i, k] = frame[i, (k + 1) % 3]
            frame = rolled
        steps = walk_steps if pivot == 0 else max(1, walk_steps - LATER_WALK_SHORTER)
        volume, frame = walk(vertices, work, frame, volume, walk_step, steps)
    frames = np.empty((1, 3, 3))
    copy_frame(frame, frames[0])
    volume, frame = polish(vertices, work, frames, np.array([volume]), max_rounds)
    if edge_pivots:
        return pivot_thinnest(vertices, work, frame, volume)
    return volume, frame


def warm_up() -> None:
    """Run every kernel of this module once on a tiny hull (see :mod:`mvbb_ros.kernels`)."""
    from mvbb_ros.geometry.boxfit.hull import convex_hull

    points = np.array(np.meshgrid(*[[-1.0, 1.0]] * 3)).reshape(3, -1).T * [0.9, 0.6, 0.3]
    found = convex_hull(points)
    vertices = np.ascontiguousarray(points[found.vertices])
    search_kernel(
        vertices,
        found.normals,
        found.areas,
        found.edges,
        found.edge_facets,
        0,
        8,
        4,
        6,
        200,
        32,
        4,
        3,
        1,
        4,
        0.02,
        3,
        1,
        1,
    )
