"""
Minimum-area enclosing rectangle of planar points, in compiled code.

Freeman and Shapira (1975): a minimum-area enclosing rectangle has one side collinear with an edge
of the convex hull. Rotating calipers (Toussaint 1983) visit the hull edges counter-clockwise and
move three supporting vertices (farthest along the edge, farthest from it, farthest back) forward
as the edge turns, so all edges cost O(m) for a hull of m vertices.

* :func:`hull_2d_kernel`: Andrew's monotone chain (sort by x then y, two sweeps that keep left
  turns only), after an Akl-Toussaint throw-away of the points strictly inside the octagon of the
  extremes along eight directions when there are many. Duplicates and collinear points never
  break it: they are dropped.
* :func:`calipers_kernel`: the rotating calipers on a counter-clockwise convex polygon. Areas are
  compared without square roots (the edge's squared length divides the product of the two spans).
  After the first edge the supporting vertices move by merges without branches
  (:func:`calipers_into`): the walk's branches mispredict on every new outline.

:func:`min_area_rectangle` is the typed wrapper for one planar cloud. The 3D box search
(:mod:`mvbb_ros.geometry.boxfit.search`) calls the kernels directly, on the projected silhouette of
a hull, with work arrays it reuses.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from mvbb_ros.arrays import column_max, column_min, FloatArray
import numba as nb
import numpy as np
from numpy.typing import ArrayLike

#: Points above which the octagon throw-away runs before the sort.
CULL_MIN_POINTS = 64
#: Point counts up to which an insertion sort beats the library sort.
_INSERTION_SORT_MAX = 40


class Rectangle(NamedTuple):
    """
    An oriented rectangle in the plane.

    :param center: (2,) centre.
    :param axes: (2, 2) rotation (det +1); column k is the unit direction of side k.
    :param extents: (2,) full side lengths along the two axes (>= 0).
    """

    center: FloatArray
    axes: FloatArray
    extents: FloatArray

    @property
    def area(self) -> float:
        """Area (product of the extents), in squared units of the points."""
        return float(self.extents[0] * self.extents[1])

    def corners(self) -> FloatArray:
        """Return the corner points, counter-clockwise, as a (4, 2) array."""
        signs = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        return self.center + (signs * self.extents / 2.0) @ self.axes.T


@nb.njit
def _before(x: np.ndarray, y: np.ndarray, i: int, j: int) -> bool:
    """Tell whether point i comes before point j in (x, y) order."""
    return x[i] < x[j] or (x[i] == x[j] and y[i] < y[j])


@nb.njit(cache=True, nogil=True)
def sort_xy_kernel(x: np.ndarray, y: np.ndarray, order: np.ndarray, count: int) -> None:
    """
    Sort ``order[:count]`` (indices into x, y) by x, then y.

    Insertion sort for a few points, heapsort beyond (O(n log n) whatever the input, and far
    quicker to compile than numba's own sorts).
    """
    if count <= _INSERTION_SORT_MAX:
        for i in range(1, count):
            item = order[i]
            j = i - 1
            while j >= 0 and _before(x, y, item, order[j]):
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = item
        return
    # Heapsort: build a max-heap, then move the largest to the end, count times.
    for start in range(count // 2 - 1, -1, -1):
        sift_down(x, y, order, start, count)
    for end in range(count - 1, 0, -1):
        order[0], order[end] = order[end], order[0]
        sift_down(x, y, order, 0, end)


@nb.njit
def sift_down(x: np.ndarray, y: np.ndarray, order: np.ndarray, root: int, end: int) -> None:
    """Restore the max-heap order, by (x, y), of the indices ``order[root:end]`` below `root`."""
    while True:
        child = 2 * root + 1
        if child >= end:
            return
        if child + 1 < end and _before(x, y, order[child], order[child + 1]):
            child += 1
        if not _before(x, y, order[root], order[child]):
            return
        order[root], order[child] = order[child], order[root]
        root = child


@nb.njit
def _turn(x: np.ndarray, y: np.ndarray, o: int, a: int, b: int) -> float:
    """Cross product (a - o) x (b - o): positive for a left turn o -> a -> b."""
    return (x[a] - x[o]) * (y[b] - y[o]) - (y[a] - y[o]) * (x[b] - x[o])


@nb.njit
def _octagon_cull(x: np.ndarray, y: np.ndarray, order: np.ndarray, count: int) -> int:
    """
    Drop from ``order[:count]`` the points strictly inside the octagon of eight extremes.

    :return: how many indices are left at the front of `order`.
    """
    extreme = np.zeros(8, dtype=np.int64)
    best = np.full(8, -np.inf)
    for s in range(count):
        i = order[s]
        xi = x[i]
        yi = y[i]
        # Directions counter-clockwise: (1,0), (1,1), (0,1), (-1,1), (-1,0), (-1,-1), ...
        values = (xi, xi + yi, yi, yi - xi, -xi, -xi - yi, -yi, xi - yi)
        for k in range(8):
            if values[k] > best[k]:
                best[k] = values[k]
                extreme[k] = i
    kept = 0
    for s in range(count):
        i = order[s]
        inside = True
        for k in range(8):
            a = extreme[k]
            b = extreme[(k + 1) % 8]
            if a == b:
                continue
            if _turn(x, y, a, b, i) <= 0.0:
                inside = False
                break
        if not inside:
            order[kept] = i
            kept += 1
    return kept


@nb.njit(cache=True, nogil=True)
def hull_2d_kernel(
    x: np.ndarray, y: np.ndarray, order: np.ndarray, count: int, out: np.ndarray
) -> int:
    """
    Find the convex hull of planar points, counter-clockwise, without collinear vertices.

    :param x: x coordinates.
    :param y: y coordinates.
    :param order: the indices of the points to use in ``order[:count]`` (reordered in place).
    :param count: how many.
    :param out: room for ``count + 1`` indices; receives the hull's vertex indices.
    :return: the number m of hull vertices in ``out[:m]`` (1 for coincident points, 2 for
        collinear ones).
    """
    if count > CULL_MIN_POINTS:
        count = _octagon_cull(x, y, order, count)
    sort_xy_kernel(x, y, order, count)
    size = 0
    for s in range(count):
        i = order[s]
        while size >= 2 and _turn(x, y, out[size - 2], out[size - 1], i) <= 0.0:
            size -= 1
        out[size] = i
        size += 1
    lower = size + 1
    for s in range(count - 2, -1, -1):
        i = order[s]
        while size >= lower and _turn(x, y, out[size - 2], out[size - 1], i) <= 0.0:
            size -= 1
        out[size] = i
        size += 1
    # The last point repeats the first; a single distinct point stays once.
    size = max(size - 1, 1)
    if size == 2 and x[out[0]] == x[out[1]] and y[out[0]] == y[out[1]]:
        size = 1
    return size


@nb.njit(cache=True, nogil=True)
def calipers_kernel(x: np.ndarray, y: np.ndarray, polygon: np.ndarray, size: int) -> tuple:
    """
    Find the minimum-area enclosing rectangle of a convex polygon by rotating calipers.

    :param x: x coordinates.
    :param y: y coordinates.
    :param polygon: ``polygon[:size]``: the polygon's vertex indices, counter-clockwise.
    :param size: number of vertices.
    :return: the area and the unit direction (dx, dy) of the rectangle side flush with a polygon
        edge. One vertex gives area 0 and (1, 0); two give area 0 along their segment.
    """
    rows = max(size, 1) + 1
    return calipers_into(
        x, y, polygon, size, np.empty((4, rows)), np.empty((3, rows), dtype=np.uint64)
    )


@nb.njit(inline='always')
def _walk_on(
    position: int,
    ex: float,
    ey: float,
    edge_x: np.ndarray,
    edge_y: np.ndarray,
    size: int,
    side: int,
) -> int:
    """
    Move a supporting vertex forward while its next edge points `side` of the edge (ex, ey).

    `side` 0: along the edge (the vertex farthest along it), 1: to its left (farthest from it),
    2: against it (farthest back). At most `size` steps (a polygon that is not convex).
    """
    last = size - 1
    for _ in range(size):
        if side == 0:
            onward = ex * edge_x[position] + ey * edge_y[position] > 0.0
        elif side == 1:
            onward = ex * edge_y[position] - ey * edge_x[position] > 0.0
        else:
            onward = ex * edge_x[position] + ey * edge_y[position] < 0.0
        if not onward:
            break
        position = position + 1 if position < last else 0
    return position


@nb.njit(inline='always')
def _polygon_edges(
    x: np.ndarray, y: np.ndarray, polygon: np.ndarray, size: int, scratch: np.ndarray
) -> None:
    """Copy the corners to ``scratch[0:2]``, the edges to the next corner to ``scratch[2:4]``."""
    corner_x = scratch[0]
    corner_y = scratch[1]
    edge_x = scratch[2]
    edge_y = scratch[3]
    for i in range(size):
        corner_x[i] = x[polygon[i]]
        corner_y[i] = y[polygon[i]]
    last = size - 1
    for i in range(last):
        edge_x[i] = corner_x[i + 1] - corner_x[i]
        edge_y[i] = corner_y[i + 1] - corner_y[i]
    edge_x[last] = corner_x[0] - corner_x[last]
    edge_y[last] = corner_y[0] - corner_y[last]


@nb.njit
def _short(x: np.ndarray, y: np.ndarray, polygon: np.ndarray, size: int) -> tuple:
    """Return the calipers' answer for fewer than three vertices (a point or a segment)."""
    if size < 2:
        return 0.0, 1.0, 0.0
    dx = x[polygon[1]] - x[polygon[0]]
    dy = y[polygon[1]] - y[polygon[0]]
    length = math.hypot(dx, dy)
    if not length > 0.0:
        return 0.0, 1.0, 0.0
    return 0.0, dx / length, dy / length


@nb.njit(inline='always')
def _least_rectangle(scratch: np.ndarray, size: int, places: np.ndarray, walking: bool) -> tuple:
    """
    Return the least rectangle over the edges, from their supporting vertices.

    With `walking`, the vertices are found here, edge by edge (the calipers' walk); else they
    are ``places[0:3, i]`` (farthest along edge i, from it, back).
    """
    corner_x = scratch[0]
    corner_y = scratch[1]
    edge_x = scratch[2]
    edge_y = scratch[3]
    best = np.inf
    best_x = 1.0
    best_y = 0.0
    right = 1
    top = 1
    left = 1
    for i in range(size):
        ex = edge_x[i]
        ey = edge_y[i]
        squared = ex * ex + ey * ey
        if not squared > 0.0:
            continue
        if walking:
            # Farthest along the edge, then farthest from it, then farthest back.
            right = _walk_on(right, ex, ey, edge_x, edge_y, size, 0)
            top = _walk_on(right if i == 0 else top, ex, ey, edge_x, edge_y, size, 1)
            left = _walk_on(top if i == 0 else left, ex, ey, edge_x, edge_y, size, 2)
        else:
            right = np.int64(places[0, i])
            top = np.int64(places[1, i])
            left = np.int64(places[2, i])
        along = ex * (corner_x[right] - corner_x[left]) + ey * (corner_y[right] - corner_y[left])
        across = ex * (corner_y[top] - corner_y[i]) - ey * (corner_x[top] - corner_x[i])
        area = along * across
        # Compare along * across / squared without dividing: a * squared_best < best * squared.
        if area < best * squared:
            best = area / squared
            best_x = ex
            best_y = ey
    if best == np.inf:
        return 0.0, 1.0, 0.0
    length = math.hypot(best_x, best_y)
    return max(best, 0.0), best_x / length, best_y / length


@nb.njit
def calipers_into(
    x: np.ndarray,
    y: np.ndarray,
    polygon: np.ndarray,
    size: int,
    scratch: np.ndarray,
    places: np.ndarray,
) -> tuple:
    """
    Run :func:`calipers_kernel` with a caller's work arrays (no allocation per call).

    For callers that run the calipers hundreds of times a fit. The three supporting vertices
    walk forward edge after edge; where each stops depends on the polygon, so a walk written
    with branches mispredicts at almost every edge (about half the time of a box search's
    turn on a 20-vertex outline). Here the first edge's vertices walk as usual, and for the
    other edges each vertex follows a merge without branches: at each step either the vertex
    moves on (the walk's test passes) or the edge does and the vertex's place is kept. The
    tests are the walk's, in its order, so the rectangle is the same bit for bit. The merges
    stop after ``4 * size`` steps (a convex polygon needs fewer than ``3 * size``): a polygon
    on which a vertex's test would pass all the way round is walked instead.

    :param scratch: (4, >= size + 1) floats: the corners and edges.
    :param places: (3, >= size + 1) unsigned integers: each edge's supporting vertices.
    """
    if size < 3:
        return _short(x, y, polygon, size)
    _polygon_edges(x, y, polygon, size, scratch)
    edge_x = scratch[2]
    edge_y = scratch[3]
    ex = edge_x[0]
    ey = edge_y[0]
    if not ex * ex + ey * ey > 0.0:
        return _least_rectangle(scratch, size, places, True)
    right = _walk_on(1, ex, ey, edge_x, edge_y, size, 0)
    top = _walk_on(right, ex, ey, edge_x, edge_y, size, 1)
    left = _walk_on(top, ex, ey, edge_x, edge_y, size, 2)
    # A zero edge after the last, on which no test passes: a finished merge stays on it.
    edge_x[size] = 0.0
    edge_y[size] = 0.0
    # Unsigned positions: no code for negative indices on the merges' critical path.
    end = np.uint64(size)
    zero = np.uint64(0)
    one = np.uint64(1)
    at_right = np.uint64(right)
    at_top = np.uint64(top)
    at_left = np.uint64(left)
    places[0, 0] = at_right
    places[1, 0] = at_top
    places[2, 0] = at_left
    edge_right = edge_top = edge_left = one
    for _ in range(4 * size):
        if edge_right >= end and edge_top >= end and edge_left >= end:
            break
        moves_right = (
            edge_x[edge_right] * edge_x[at_right] + edge_y[edge_right] * edge_y[at_right] > 0.0
        )
        moves_top = edge_x[edge_top] * edge_y[at_top] - edge_y[edge_top] * edge_x[at_top] > 0.0
        moves_left = (
            edge_x[edge_left] * edge_x[at_left] + edge_y[edge_left] * edge_y[at_left] < 0.0
        )
        places[0, edge_right] = at_right
        places[1, edge_top] = at_top
        places[2, edge_left] = at_left
        at_right += np.uint64(moves_right)
        at_top += np.uint64(moves_top)
        at_left += np.uint64(moves_left)
        at_right = zero if at_right == end else at_right
        at_top = zero if at_top == end else at_top
        at_left = zero if at_left == end else at_left
        edge_right = min(edge_right + np.uint64(not moves_right), end)
        edge_top = min(edge_top + np.uint64(not moves_top), end)
        edge_left = min(edge_left + np.uint64(not moves_left), end)
    else:
        return _least_rectangle(scratch, size, places, True)
    return _least_rectangle(scratch, size, places, False)


@nb.njit(cache=True, nogil=True)
def min_area_rectangle_kernel(x: np.ndarray, y: np.ndarray) -> tuple:
    """
    Return the minimum-area rectangle of planar points as (cx, cy, dx, dy, width, height).

    (dx, dy) is the unit direction of the first side, (-dy, dx) that of the second.
    """
    count = x.shape[0]
    order = np.arange(count)
    polygon = np.empty(count + 1, dtype=np.int64)
    size = hull_2d_kernel(x, y, order, count, polygon)
    _, dx, dy = calipers_kernel(x, y, polygon, size)
    low_u = np.inf
    high_u = -np.inf
    low_v = np.inf
    high_v = -np.inf
    for i in range(count):
        u = dx * x[i] + dy * y[i]
        v = dx * y[i] - dy * x[i]
        low_u = min(low_u, u)
        high_u = max(high_u, u)
        low_v = min(low_v, v)
        high_v = max(high_v, v)
    mid_u = 0.5 * (low_u + high_u)
    mid_v = 0.5 * (low_v + high_v)
    return dx * mid_u - dy * mid_v, dy * mid_u + dx * mid_v, dx, dy, high_u - low_u, high_v - low_v


def min_area_rectangle(points: ArrayLike) -> Rectangle:
    """
    Return the minimum-area rectangle enclosing planar points (exact, up to rounding).

    Coincident points give a zero-size rectangle, collinear points a zero-width one along their
    line. The rectangle encloses every point.

    :param points: (N, 2) finite points, N >= 1.
    :return: the rectangle, in the units of the points.
    :raises ValueError: on empty, non-finite or wrongly shaped input.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f'expected planar points of shape (N, 2), got shape {pts.shape}')
    if len(pts) == 0:
        raise ValueError('expected at least one planar point, got an empty array')
    if not np.isfinite(pts).all():
        raise ValueError('planar points must be finite, got NaN or inf')
    # Relative to the centre of the bounding box, scaled to unit size: far and tiny clouds keep
    # their precision and nothing underflows.
    origin = 0.5 * (column_min(pts) + column_max(pts))
    scale = float(np.max(np.abs(pts - origin)))
    scale = scale if scale > 0.0 else 1.0
    unit = (pts - origin) / scale
    x = np.ascontiguousarray(unit[:, 0])
    y = np.ascontiguousarray(unit[:, 1])
    cx, cy, dx, dy, width, height = min_area_rectangle_kernel(x, y)
    return Rectangle(
        center=origin + scale * np.array([cx, cy]),
        axes=np.array([[dx, -dy], [dy, dx]]),
        extents=scale * np.array([width, height]),
    )


def warm_up() -> None:
    """Run every kernel of this module once on tiny inputs (see :mod:`mvbb_ros.kernels`)."""
    min_area_rectangle([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [1.0, 2.0], [0.5, 1.0]])
