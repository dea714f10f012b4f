"""
Minimum-volume oriented bounding box of a 3D point set.

Huebner et al. (ICRA 2008), Section III-A, fit every box with the approximation of Barequet and
Har-Peled (2001): find good directions on a random sample of the points, search a small grid of
directions around the best frame, improve the best box locally, and finally grow it to enclose
every point. This module follows that scheme on the convex hull (the box of a point set is the
box of its hull) and uses exact 2D steps to make each one cheap and vectorised:

* For a fixed axis ``a``, the best rotation of the box about ``a`` is the minimum-area rectangle
  of the projection along ``a`` (:mod:`mvbb_ros.geometry.rectangle`). Its sides are flush with
  projected *silhouette* edges of the hull (:meth:`mvbb_ros.geometry.hull.Hull.silhouette`), so the
  rectangles of many axes are found at once, by batched rotating calipers on silhouette vertices
  only.
* A minimal box has a face flush with a hull facet, or adjacent faces flush with hull edges
  (O'Rourke 1985). Candidate axes are therefore the facet normals and the normals of planes
  through two hull edges; a cheap lower bound on the volume (hull width times shadow area) ranks
  them, and the best ``candidates`` facet normals and half as many edge-pair normals get their
  exact best box.
* Local improvement: the best ``starts`` boxes are turned, in turn, to their best rotation about
  one of their other axes (rotating calipers about b, then c, ...), keeping the better half of
  them each round; then Barequet and Har-Peled's grid of directions around the best frame is
  searched, and the polish resumes from any better box it finds.
* The final box encloses every input point, computed relative to the centroid.

Speed on small hulls (decomposition children, depth-frame clusters) is set by the number of numpy
calls, not by arithmetic: :func:`best_rotations_about` therefore scores every (axis, silhouette
edge) pair in a few large products on padded tables rather than in rotating calipers, whenever
the silhouettes are short (up to 64 edges; longer ones go to the calipers, whose cost grows like
S log S rather than S^2), and hulls of at most 64 facets skip the ranking step.

Cost, for N points whose hull has H vertices, F ~ 2H facets and E ~ 3H edges:

1. Check, centre, scale and rank the points (PCA): O(N).
2. Clouds of 2,048 points or more: keep the extremes of the columns of a 32 x 32 grid along each
   PCA axis (Barequet and Har-Peled's grid coreset; at most 6 144 points, usually a few thousand),
   then cull the points inside a polytope of up to 26 extreme points, when a probe says it pays
   (solid clouds; flat-sided scans keep most points): O(N).
3. Qhull on the survivors: O(N log H).
4. Rank the facet normals and the 276 edge-pair normals by the bound: O(F + 276) against 96
   binned area vectors and ``sample_size`` sampled hull vertices.
5. Best rotation about each axis tried (1.5 ``candidates`` axes, then two per frame and round of
   the polish, which halves the ``starts`` frames every round, then 13 grid directions per grid
   round: 101 to 130 axes in all on the reference clouds): O(F + E) to find the silhouette and
   O(S log S) for the calipers on its S vertices (S grows like sqrt(H) on smooth shapes).
6. Enclose every point: O(N).

The coreset makes the search approximate where Qhull's hull was exact: the box found on it is
grown to enclose every point, and on the reference clouds it lost nothing measurable (worst
1.0042 x best known, against 1.0041 on the exact hull) while the fits took a third less time.

So beyond Qhull the cost grows linearly with H (``benchmarks/mvbb.py --scaling`` measures it):
only the 24 longest edges are paired, and nothing else enumerates pairs of facets or edges,
which is what makes exact O(H^2) to O(H^3) methods take seconds on large hulls.
"""

from __future__ import annotations

import itertools
import math

from mvbb_ros.arrays import FloatArray, IndexArray
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.hull import (
    affine_rank,
    column_extremes,
    convex_hull,
    DegenerateHullError,
    Hull,
    project,
)
from mvbb_ros.geometry.rectangle import min_area_rectangle, min_area_rectangles
import numpy as np
from numpy.typing import ArrayLike

#: Relative volume gain below which polishing stops (far below the 1 % quality target).
_POLISH_TOLERANCE = 1e-5
#: Cube-map cells per face side for binning facet normals in the shadow-area bound.
_SHADOW_CELLS = 4
#: Longest hull edges whose pairs give candidate axes (all edges of hulls with fewer).
_PAIR_EDGES = 24
#: In-plane length (of unit-scaled hull edges) below which an edge gives no rectangle direction.
_EDGE_TOLERANCE = 1e-12
#: Entries per block of the batched rectangle products, to keep temporaries in cache.
_BLOCK_SIZE = 1 << 15
#: Longest silhouette (in edges) handled by the batched products; longer ones use calipers.
_BRUTE_WIDTH = 64
#: Longest edges paired for candidate axes when every facet normal is tried.
_SMALL_PAIR_EDGES = 24
#: Clouds with at least this many points are searched on their grid coreset (``coreset_cells``).
CORESET_MIN_POINTS = 2048


def _as_points(points: ArrayLike) -> FloatArray:
    """Return `points` as a float (N, 3) array, or raise ValueError saying what is wrong."""
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
    return pts


def _cross(first: FloatArray, second: FloatArray) -> FloatArray:
    """Return the cross products of (..., 3) arrays (numpy.cross has a large fixed cost)."""
    x1, y1, z1 = first[..., 0], first[..., 1], first[..., 2]
    x2, y2, z2 = second[..., 0], second[..., 1], second[..., 2]
    return np.stack([y1 * z2 - z1 * y2, z1 * x2 - x1 * z2, x1 * y2 - y1 * x2], axis=-1)


def _frame_volumes(hull: Hull, frames: FloatArray) -> FloatArray:
    """Return the volumes (K,) of the boxes of the hull with the frames' axes (K, 3, 3)."""
    heights = project(frames.transpose(0, 2, 1).reshape(-1, 3), hull.vertex_rows)
    extents = (heights.max(axis=1) - heights.min(axis=1)).reshape(-1, 3)
    return np.prod(extents, axis=1)


def _frames_about(axes: FloatArray, sides: FloatArray) -> FloatArray:
    """Return right-handed frames (K, 3, 3) with columns axis, side, axis x side."""
    return np.stack([axes, sides, _cross(axes, sides)], axis=2)


def _plane_bases(axes: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return two unit vectors (K, 3) each, spanning the planes perpendicular to unit `axes`."""
    helper = np.zeros_like(axes)
    helper[np.arange(len(axes)), np.argmin(np.abs(axes), axis=1)] = 1.0
    first = _cross(axes, helper)
    first /= np.linalg.norm(first, axis=1)[:, None]
    return first, _cross(axes, first)


def _padded(rows: IndexArray, values: IndexArray, count: int) -> tuple[IndexArray, IndexArray]:
    """
    Lay out `values` grouped by `rows` (sorted) as a (count, width) table, one row per group.

    Short rows repeat their group's first value (repeats change no maximum or minimum).

    :param rows: (M,) sorted group of each value, in ``range(count)``.
    :param values: (M,) values.
    :param count: number of groups.
    :return: the table, and the group sizes (count,); an empty group's row holds value 0.
    """
    sizes = np.bincount(rows, minlength=count)
    starts = np.cumsum(sizes) - sizes
    first = values[np.minimum(starts, len(values) - 1)] if len(values) else np.zeros(count, int)
    table = np.repeat(np.where(sizes > 0, first, 0)[:, None], max(int(sizes.max()), 1), axis=1)
    table[rows, np.arange(len(rows)) - starts[rows]] = values
    return table, sizes


def best_rotations_about(hull: Hull, axes: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """
    For each axis, find the minimum-volume box of the hull that has that axis.

    The rotation about the axis is the minimum-area rectangle of the hull's projection along it,
    which has a side along a projected edge of that projection's 2D hull (Freeman and Shapira
    1975): the projected *silhouette* of the hull (:meth:`mvbb_ros.geometry.hull.Hull.silhouette`).
    So, for every axis ``a`` and every silhouette edge, the edge's direction ``d`` in the plane
    across ``a`` and ``u = a x d`` give a rectangle spanned by the silhouette vertices' extents
    along ``d`` and ``u``; the least is exact (up to rounding). All axes are done at once, on
    tables padded to the longest silhouette: one (K, S, 3) by (K, 3, 2S) product per block of
    axes, O(K S^2) for silhouettes of S edges, but a fixed, small number of numpy calls.

    :param hull: convex hull of the points.
    :param axes: (K, 3) unit axes.
    :return: volumes (K,) and right-handed frames (K, 3, 3) whose first column is the axis.
    """
    axes = np.ascontiguousarray(np.asarray(axes, dtype=np.float64).reshape(-1, 3))
    count = len(axes)
    axis_ids, edge_ids = np.nonzero(hull.silhouette(axes))
    edges, edge_sizes = _padded(axis_ids, edge_ids, count)
    if edges.shape[1] > _BRUTE_WIDTH:
        return _caliper_rotations_about(hull, axes)
    # Both ends of every silhouette edge: each silhouette vertex comes twice, which costs less
    # than finding each once.
    vertices = hull.edges[edges].reshape(count, -1)
    # Silhouette edge directions in the plane across each axis, and the directions across them.
    along = hull.edge_vectors[edges]
    along -= np.einsum('kse,ke->ks', along, axes)[:, :, None] * axes[:, None, :]
    lengths = np.sqrt(np.einsum('kse,kse->ks', along, along))
    usable = lengths > _EDGE_TOLERANCE
    along /= np.where(usable, lengths, 1.0)[:, :, None]
    directions = np.concatenate([along, _cross(axes[:, None, :], along)], axis=1)
    width = edges.shape[1]
    areas = np.empty((count, width))
    step = max(1, _BLOCK_SIZE // (2 * width * vertices.shape[1]))
    for begin in range(0, count, step):
        block = slice(begin, begin + step)
        # Heights (S, k, 2S) with the silhouette vertex first: reducing over the first axis
        # runs on long contiguous rows (over the last, numpy's reductions crawl).
        # Heights (S, k, 2S) with the silhouette vertex first: reducing over the first axis
        # runs on long contiguous rows (over the last, numpy's reductions crawl).
        heights = hull.vertices[vertices[block]] @ directions[block].transpose(0, 2, 1)
        heights = np.ascontiguousarray(heights.transpose(1, 0, 2))
        spans = heights.max(axis=0) - heights.min(axis=0)
        areas[block] = spans[:, :width] * spans[:, width:]
    areas[~usable] = np.inf
    best = np.argmin(areas, axis=1)
    rows = np.arange(count)
    heights = project(axes, hull.vertex_rows)
    volumes = areas[rows, best] * (heights.max(axis=1) - heights.min(axis=1))
    volumes[edge_sizes == 0] = np.inf
    # Rounding leaves the chosen side a little off the plane across a short edge: square it up.
    sides = along[rows, best]
    sides -= np.einsum('kd,kd->k', sides, axes)[:, None] * axes
    sides /= np.maximum(np.linalg.norm(sides, axis=1), 1e-300)[:, None]
    return volumes, _frames_about(axes, sides)


def _caliper_rotations_about(hull: Hull, axes: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """
    For each axis, find the minimum-volume box of the hull that has that axis.

    The rotation about the axis is the minimum-area rectangle of the hull's projection along it
    (exact up to rounding). The 2D hull of that projection is the projected silhouette, so only
    silhouette vertices are projected, and all axes go through one batched rotating-calipers call
    (:func:`mvbb_ros.geometry.rectangle.min_area_rectangles`): O(K E) to find the silhouettes, then
    O(S log S) for their S vertices in all.

    :param hull: convex hull of the points.
    :param axes: (K, 3) unit axes.
    :return: volumes (K,) and right-handed frames (K, 3, 3) whose first column is the axis.
    """
    axes = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    count = len(axes)
    axis_ids, edge_ids = np.nonzero(hull.silhouette(axes))
    # Both ends of every silhouette edge, axis by axis: each silhouette vertex comes twice,
    # and the calipers drop repeats.
    axis_ids = np.repeat(axis_ids, 2)
    vertex_ids = hull.edges[edge_ids].ravel()
    first, second = _plane_bases(axes)
    # Plane coordinates as complex numbers x + iy (what the batched calipers take).
    basis = first + 1j * second
    planar = np.einsum('md,md->m', hull.vertices[vertex_ids], basis[axis_ids])
    _, directions = min_area_rectangles(planar, axis_ids, count)
    sides = directions[:, :1] * first + directions[:, 1:] * second
    frames = _frames_about(axes, sides)
    return _frame_volumes(hull, frames), frames


def _unique_axes(directions: FloatArray) -> FloatArray:
    """Drop later repeats from unit `directions` (K, 3), a direction and its opposite being one."""
    parallel = np.abs(directions @ directions.T) > 1.0 - 1e-12
    repeated = np.triu(parallel, 1).any(axis=0)
    return directions[~repeated]


def _binned_area_vectors(hull: Hull, cells: int = _SHADOW_CELLS) -> FloatArray:
    """
    Sum the facet area vectors (area times unit normal) over a cube-map binning of the normals.

    :return: (6 cells^2, 3) summed area vectors (empty bins are zero).
    """
    normals = hull.normals
    dominant = np.argmax(np.abs(normals), axis=1)
    rows = np.arange(len(normals))
    major = normals[rows, dominant]
    cube_face = 2 * dominant + (major < 0.0)
    # The other two coordinates, divided by the dominant one, lie in [-1, 1] on that cube face.
    others = np.stack([normals[rows, (dominant + 1) % 3], normals[rows, (dominant + 2) % 3]], 1)
    cell = np.clip(
        ((others / np.abs(major)[:, None] + 1.0) * (cells / 2.0)).astype(int), 0, cells - 1
    )
    bins = (cube_face * cells + cell[:, 0]) * cells + cell[:, 1]
    area_vectors = normals * hull.areas[:, None]
    return np.stack(
        [np.bincount(bins, weights=area_vectors[:, i], minlength=6 * cells**2) for i in range(3)],
        axis=1,
    )


def _edge_pair_axes(hull: Hull, count: int) -> FloatArray:
    """
    Return the unit normals of the planes spanned by two hull edges, for the longest edges.

    A face can be flush with two hull edges without lying on a facet (for a tetrahedron, with
    two opposite edges); such faces' normals are candidate axes too.

    :param hull: the hull.
    :param count: how many of the longest edges to pair (all pairs among them).
    :return: (P, 3) unit axes (pairs of parallel edges give none).
    """
    lengths = np.linalg.norm(hull.edge_vectors, axis=1)
    longest = np.argsort(-lengths, kind='stable')[:count]
    directions = hull.edge_vectors[longest] / lengths[longest, None]
    first, second = np.triu_indices(len(longest), 1)
    normals = _cross(directions[first], directions[second])
    norms = np.linalg.norm(normals, axis=1)
    keep = norms > 1e-9
    return normals[keep] / norms[keep, None]


def _ranked(
    hull: Hull, axes: FloatArray, count: int, sample: IndexArray, binned: FloatArray
) -> FloatArray:
    """Return the `count` distinct `axes` of least volume bound (see :func:`candidate_axes`)."""
    if not len(axes):
        return axes
    shadow = 0.5 * np.abs(project(axes, binned)).sum(axis=1)
    heights = project(axes, np.ascontiguousarray(hull.vertex_rows[:, sample]))
    bound = shadow * (heights.max(axis=1) - heights.min(axis=1))
    # Coplanar facets repeat a normal; look a little deeper than `count` for distinct ones.
    order = np.argsort(bound, kind='stable')[: 4 * count]
    return _unique_axes(axes[order])[:count]


def candidate_axes(
    hull: Hull, count: int, sample: IndexArray, pair_edges: int = _PAIR_EDGES
) -> FloatArray:
    """
    Return the most promising box axes: `count` facet normals and `count` / 2 edge-pair normals.

    A minimal box has a face flush with a hull facet, or faces flush with hull edges (O'Rourke
    1985). Candidates are the facet normals, and the normals of planes spanned by two of the
    `pair_edges` longest edges (all edges of small hulls; a tetrahedron's box, for one, can have
    faces flush with two opposite edges). Each kind is ranked on its own by a lower bound on the
    volume of a box with axis ``n``: the hull's width along ``n`` times the area of its shadow
    along ``n`` (the projected hull lies inside the box's rectangle), made cheaper and lower
    still by summing the facet area vectors ``A_f`` over bins of similar normals before taking
    half the sum of ``|A_f . n|`` (the shadow area), and by measuring the width on a sample of
    the hull vertices.

    :param hull: convex hull of the points.
    :param count: how many facet normals to return, at most (and half as many pair normals).
    :param sample: indices of the hull vertices used for widths.
    :param pair_edges: longest edges whose pairs give candidate axes.
    :return: (at most 1.5 count, 3) unit axes.
    """
    binned = np.ascontiguousarray(_binned_area_vectors(hull).T)
    return np.concatenate(
        [
            _ranked(hull, hull.normals, count, sample, binned),
            _ranked(hull, _edge_pair_axes(hull, pair_edges), count // 2, sample, binned),
        ]
    )


def grid_axes(frame: ArrayLike, grid_size: int) -> FloatArray:
    """
    Return Barequet and Har-Peled's grid of directions around a frame.

    The directions ``i a + j b + k c`` for integers ``|i|, |j|, |k| <= grid_size`` (a, b, c the
    frame's columns), one per line through the origin.

    :param frame: (3, 3) rotation, columns are the axes.
    :param grid_size: grid half-width (0 gives no direction).
    :return: (K, 3) unit directions.
    """
    steps = range(-grid_size, grid_size + 1)
    triples = [
        t
        for t in itertools.product(steps, repeat=3)
        if t > (0, 0, 0) and math.gcd(math.gcd(abs(t[0]), abs(t[1])), abs(t[2])) == 1
    ]
    if not triples:
        return np.zeros((0, 3))
    directions = np.array(triples, dtype=np.float64) @ np.asarray(frame, dtype=np.float64).T
    return directions / np.linalg.norm(directions, axis=1)[:, None]


def polish(hull: Hull, frames: ArrayLike, max_rounds: int) -> tuple[FloatArray, FloatArray]:
    """
    Improve boxes by turning each, in turn, to its best rotation about one of its axes.

    The frames come from :func:`best_rotations_about`, so each is already best about its first
    axis. Every round scores the best rotation about the other two axes of every frame still
    improving (one batched call) and keeps the better when it is smaller; the axis just turned
    about then comes first. Each step is exact (rotating calipers), so a volume never increases;
    a frame stops when its gain falls below a relative 1e-5. After each round the worse half of
    the frames is dropped (successive halving): every start gets a first step, only the best is
    followed to the end.

    :param hull: convex hull of the points.
    :param frames: (K, 3, 3) starting frames (columns are axes).
    :param max_rounds: most rounds.
    :return: volumes and frames (at most K, 3, 3) after polishing, smallest volume first.
    """
    frames = np.array(frames, dtype=np.float64).reshape(-1, 3, 3)
    volumes = _frame_volumes(hull, frames)
    improving = np.ones(len(frames), dtype=bool)
    for _ in range(max_rounds):
        active = np.flatnonzero(improving)
        if not len(active):
            break
        axes = frames[active][:, :, 1:].transpose(0, 2, 1).reshape(-1, 3)
        new_volumes, new_frames = best_rotations_about(hull, axes)
        new_volumes = new_volumes.reshape(-1, 2)
        pick = np.argmin(new_volumes, axis=1)
        rows = np.arange(len(active))
        best = new_volumes[rows, pick]
        better = best < volumes[active] * (1.0 - _POLISH_TOLERANCE)
        chosen = new_frames.reshape(-1, 2, 3, 3)[rows, pick]
        frames[active[better]] = chosen[better]
        volumes[active[better]] = best[better]
        improving[active[~better]] = False
        order = np.argsort(volumes, kind='stable')[: (len(frames) + 1) // 2]
        frames, volumes, improving = frames[order], volumes[order], improving[order]
    order = np.argsort(volumes, kind='stable')
    return volumes[order], frames[order]


def _best_frame(
    hull: Hull,
    pca: FloatArray,
    *,
    rng: np.random.Generator,
    sample_size: int,
    grid_size: int,
    candidates: int,
    starts: int,
    max_rounds: int,
    exhaustive: int,
) -> FloatArray:
    """Return the frame (3, 3) of the best box found for a full-dimensional hull."""
    size = len(hull.vertices)
    sample = np.arange(size) if size <= sample_size else rng.choice(size, sample_size, False)
    if len(hull.normals) <= exhaustive:
        # Small hulls: every distinct facet normal, the PCA axes and the edge-pair normals of
        # the longest edges, all in one batched call (cheaper than ranking them).
        axes = np.concatenate(
            [_unique_axes(hull.normals), pca.T, _edge_pair_axes(hull, _SMALL_PAIR_EDGES)]
        )
    else:
        axes = candidate_axes(hull, candidates, sample)
    volumes, frames = best_rotations_about(hull, axes)
    order = np.argsort(volumes, kind='stable')[:starts]
    volumes, frames = polish(hull, frames[order], max_rounds)
    volume, frame = volumes[0], frames[0]
    # Barequet and Har-Peled's grid of directions around the best frame: when the best box
    # about one of them is smaller, polish it and look again (the alternating rotations alone
    # can stop where no single-axis turn helps but a turn about a diagonal does).
    for _ in range(max_rounds if grid_size > 0 else 0):
        grid_volumes, grid_frames = best_rotations_about(hull, grid_axes(frame, grid_size))
        best = int(np.argmin(grid_volumes))
        if not grid_volumes[best] < volume * (1.0 - _POLISH_TOLERANCE):
            break
        volumes, frames = polish(hull, grid_frames[[best]], max_rounds)
        volume, frame = volumes[0], frames[0]
    # The PCA and axis-aligned boxes are always candidates, so the result is never worse.
    fallback = np.stack([pca, np.eye(3)])
    every = np.concatenate([frame[None], fallback])
    every_volumes = np.concatenate([[volume], _frame_volumes(hull, fallback)])
    return every[int(np.argmin(every_volumes))]


def _planar_frame(unit: FloatArray, pca: FloatArray) -> FloatArray:
    """Return the frame (3, 3) of coplanar points: the plane's minimum-area rectangle."""
    plane = pca[:, :2]
    rectangle = min_area_rectangle(unit @ plane)
    first = plane @ rectangle.axes[:, 0]
    second = plane @ rectangle.axes[:, 1]
    return np.column_stack([first, second, np.cross(first, second)])


def _search_points(unit: FloatArray, pca: FloatArray, coreset_cells: int) -> FloatArray:
    """Return the points whose hull the search runs on: a grid coreset of large clouds."""
    if coreset_cells == 0 or len(unit) < CORESET_MIN_POINTS:
        return unit
    # The PCA frame's coordinates as (3, N) rows, the layout column_extremes works on.
    return unit[column_extremes((pca.T @ unit.T).T, coreset_cells)]


def _enclosing(origin: FloatArray, centered_rows: FloatArray, frame: FloatArray) -> Box:
    """Return the smallest box with the frame's axes around points given relative to `origin`."""
    local = project(frame.T, centered_rows)
    low = local.min(axis=1)
    high = local.max(axis=1)
    return Box(center=origin + frame @ ((low + high) / 2.0), rotation=frame, extents=high - low)


def _check_knob(name: str, value: object, low: int) -> None:
    """Raise ValueError unless `value` is an integer (not a bool) >= `low`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f'{name} must be an integer >= {low}, got {value!r}')


def _normalized(
    points: ArrayLike,
) -> tuple[FloatArray, FloatArray, FloatArray | None, int, FloatArray]:
    """
    Check `points` and bring them to the coordinates the search works in.

    :return: the centroid (3,); the points relative to it as (3, N) rows; the same scaled to unit
        size as (N, 3), or None when all points coincide; the affine rank and the PCA frame.
    """
    pts = _as_points(points)
    # Everything runs on coordinates relative to the centroid (and scaled to unit size for
    # Qhull), which keeps far-away and tiny clouds precise.
    rows = np.ascontiguousarray(pts.T)
    origin = rows.mean(axis=1)
    centered = rows - origin[:, None]
    scale = float(np.max(np.abs(centered)))
    if scale == 0.0:
        return origin, centered, None, 0, np.eye(3)
    unit = (centered / scale).T
    rank, pca = affine_rank(unit)
    return origin, centered, unit, rank, pca


def search_hull(points: ArrayLike, *, coreset_cells: int = 32) -> Hull:
    """
    Return the convex hull that :func:`minimum_bounding_box` searches for `points`.

    Everything a fit does before its search (checks, centring, PCA, the grid coreset, the cull
    and Qhull), in the centred unit-size coordinates the search uses: the cost floor of a fit,
    which ``benchmarks/mvbb.py`` times beside the whole fit.

    :param points: (N, 3) finite points spanning three dimensions.
    :param coreset_cells: as for :func:`minimum_bounding_box`.
    :return: the hull.
    :raises DegenerateHullError: when the points span fewer than three dimensions.
    """
    _check_knob('coreset_cells', coreset_cells, 0)
    _, _, unit, rank, pca = _normalized(points)
    if unit is None or rank < 3:
        raise DegenerateHullError(f'the points span {rank} dimensions, a hull needs 3')
    return convex_hull(_search_points(unit, pca, coreset_cells))


def minimum_bounding_box(
    points: ArrayLike,
    *,
    seed: int = 0,
    sample_size: int = 200,
    grid_size: int = 1,
    candidates: int = 48,
    starts: int = 8,
    max_rounds: int = 3,
    exhaustive: int = 64,
    coreset_cells: int = 32,
) -> Box:
    """
    Return the minimum-volume oriented box enclosing `points` (Barequet-Har-Peled style).

    The box always encloses every point (to 1e-9 of its size) and has a right-handed rotation;
    the result is deterministic for a given seed. Degenerate clouds never reach Qhull: one point
    or duplicates give a zero-size box, collinear points a box with extents (length, 0, 0),
    coplanar points the plane's minimum-area rectangle with zero thickness. Coordinates are
    centred and scaled internally, so clouds far from the origin or tiny keep their precision.
    On the shared reference clouds the volume is within 0.5 % of the best known (see
    ``benchmarks/mvbb.py``); the knobs' defaults were chosen there, by measurement.

    :param points: (N, 3) points (a single (3,) point is accepted), N >= 1, finite.
    :param seed: seed of the random sample of hull vertices.
    :param sample_size: hull vertices sampled to rank the facet normals (the paper samples 200
        points); the rotations and the polish always use the full hull.
    :param grid_size: half-width of Barequet and Har-Peled's grid of directions searched around
        the best polished frame (the paper uses 3; 0 turns the grid off).
    :param candidates: facet normals, and half as many edge-pair normals, (ranked by a volume
        lower bound) whose best box is computed.
    :param starts: best boxes polished by alternating rotating calipers, halved every round.
    :param max_rounds: most polishing rounds, and most grid searches (more than 3 changed no
        box on the reference clouds, their decomposition children or small random clouds).
    :param exhaustive: hulls with at most this many facets try every distinct facet normal (and
        the PCA axes and the edge-pair normals) in one batched call instead of ranking them.
    :param coreset_cells: clouds of 2,048 points or more are searched on the column extremes of
        a ``coreset_cells``-square grid in their PCA frame (Barequet and Har-Peled's grid
        coreset, :func:`mvbb_ros.geometry.hull.column_extremes`) instead of all their points; the
        box is still grown to enclose every point. 0 searches the exact hull of all points.
    :return: the box, in the units and frame of the points.
    :raises ValueError: on an empty array, a wrong shape, non-finite coordinates or bad knobs.
    """
    for name, value, low in (
        ('sample_size', sample_size, 1),
        ('grid_size', grid_size, 0),
        ('candidates', candidates, 1),
        ('starts', starts, 1),
        ('max_rounds', max_rounds, 0),
        ('exhaustive', exhaustive, 0),
        ('coreset_cells', coreset_cells, 0),
    ):
        _check_knob(name, value, low)
    origin, centered, unit, rank, pca = _normalized(points)
    if unit is None:
        return _enclosing(origin, centered, np.eye(3))
    if rank == 0:
        frame = np.eye(3)
    elif rank == 1:
        frame = pca
    elif rank == 2:
        frame = _planar_frame(unit, pca)
    else:
        try:
            hull = convex_hull(_search_points(unit, pca, int(coreset_cells)))
        except DegenerateHullError:
            frame = _planar_frame(unit, pca)
        else:
            frame = _best_frame(
                hull,
                pca,
                rng=np.random.default_rng(seed),
                sample_size=int(sample_size),
                grid_size=int(grid_size),
                candidates=int(candidates),
                starts=int(starts),
                max_rounds=int(max_rounds),
                exhaustive=int(exhaustive),
            )
    return _enclosing(origin, centered, frame)
