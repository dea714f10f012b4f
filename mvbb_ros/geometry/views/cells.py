"""
Cubic cells for neighbour searches in compiled kernels: bin points, then find a cell's points.

(And :func:`search_tree`, the k-d tree that numpy-level code queries for near points.)

A kernel that needs "the points near this one" bins the cloud once with :func:`cell_grid`
(cells one `width` wide, keyed by one integer per cell, keys sorted) and looks up any cell's
points with :func:`cell_start`: a binary search in the sorted keys, then a walk while the key
stays the same. O(N log N) to build, O(log N) per cell; no dictionary in compiled code. Cells
next to each other along z have consecutive keys (:func:`column_keys`), so the points of a
column of cells follow each other in the sorted order: one search finds them all.

:func:`cell_start` is our own binary search rather than ``np.searchsorted``: numba 0.68 loaded a
cached kernel that called ``np.searchsorted`` beside another of our compiled helpers with wrong
answers (the object clustering found 2,792 clusters in one L-shaped cloud; freshly compiled, 1).
:func:`key_order` is our own merge sort rather than ``np.argsort`` for the same reason: numba
builds its sorts from generated functions whose symbol names can repeat between a cached library
and one compiled later in another process, and a kernel loaded beside the other can then run the
wrong one (wrong grasp normals after ``surface.py`` alone was recompiled). No kernel of ours calls
numba's generated sort or search functions. ``test/test_kernel_cache.py`` runs the kernels
compiled and then cached and compares.
"""

from __future__ import annotations

from mvbb_ros.arrays import FloatArray, IndexArray
import numba as nb
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree


@nb.njit(cache=True, nogil=True)
def cell_grid(
    points: FloatArray, width: float, pad: int
) -> tuple[IndexArray, IndexArray, IndexArray, IndexArray]:
    """
    Bin `points` in cubic cells `width` wide, with `pad` empty cells around the cloud.

    :return: ``(cells, span, order, sorted_keys)``: each point's (N, 3) integer cell, the grid's
        (3,) size in cells, the points' order by cell key and the keys in that order. A cell's key
        is :func:`cell_key`; offsets up to `pad` cells from any point's cell stay inside the grid.
    """
    count = points.shape[0]
    low = np.zeros(3)
    span = np.ones(3, dtype=np.int64)
    for axis in range(3):
        if count > 0:
            low[axis] = points[:, axis].min()
            span[axis] = int((points[:, axis].max() - low[axis]) / width) + 2 * pad + 1
    cells = np.empty((count, 3), dtype=np.int64)
    keys = np.empty(count, dtype=np.int64)
    for i in range(count):
        for axis in range(3):
            cells[i, axis] = int((points[i, axis] - low[axis]) / width) + pad
        keys[i] = cell_key(cells[i, 0], cells[i, 1], cells[i, 2], span)
    order = key_order(keys)
    return cells, span, order, keys[order]


@nb.njit(cache=True, nogil=True)
def key_order(keys: IndexArray) -> IndexArray:
    """Return the stable order that sorts integer `keys` (a bottom-up merge sort, O(N log N))."""
    count = keys.shape[0]
    order = np.arange(count)
    buffer = np.empty(count, dtype=np.int64)
    run = 1
    while run < count:
        for start in range(0, count, 2 * run):
            middle = min(start + run, count)
            end = min(start + 2 * run, count)
            left, right, out = start, middle, start
            while left < middle and right < end:
                if keys[order[right]] < keys[order[left]]:
                    buffer[out] = order[right]
                    right += 1
                else:
                    buffer[out] = order[left]
                    left += 1
                out += 1
            while left < middle:
                buffer[out] = order[left]
                left += 1
                out += 1
            while right < end:
                buffer[out] = order[right]
                right += 1
                out += 1
        order, buffer = buffer, order
        run *= 2
    return order


@nb.njit(cache=True, nogil=True, inline='always')
def cell_key(x: int, y: int, z: int, span: IndexArray) -> int:
    """Return the key of cell (x, y, z) in a grid of `span` cells."""
    return (x * span[1] + y) * span[2] + z


@nb.njit(cache=True, nogil=True, inline='always')
def column_keys(x: int, y: int, z: int, reach: int, span: IndexArray) -> tuple[int, int]:
    """
    Return the first and last key of cells (x, y, z - reach) .. (x, y, z + reach).

    They are consecutive, so their points are the sorted run from :func:`cell_start` of the
    first key while the key is at most the last.
    """
    first = cell_key(x, y, z - reach, span)
    return first, first + 2 * reach


@nb.njit(cache=True, nogil=True)
def cell_start(sorted_keys: IndexArray, key: int) -> int:
    """Return the first position in `sorted_keys` whose key is not below `key`."""
    low, high = 0, sorted_keys.shape[0]
    while low < high:
        middle = (low + high) // 2
        if sorted_keys[middle] < key:
            low = middle + 1
        else:
            high = middle
    return low


@nb.njit(
    [
        nb.float64[::1](
            nb.types.Array(nb.float64, 2, 'C', readonly=readonly),
            nb.int64[::1],
            nb.int64,
            nb.int64[::1],
        )
        for readonly in (False, True)
    ],
    cache=True,
    nogil=True,
)
def neighbour_distances(
    points: FloatArray, order: IndexArray, axis: int, queries: IndexArray
) -> FloatArray:
    """
    Return the distance from each of the points `queries` to its nearest other point.

    Exact, and the same floats as scipy's k-d tree (``query(points[queries], k=2)[0][:, 1]``:
    the squared differences added x, y, z, then the root); no tree: the points are sorted along
    one `axis` (`order`; the widest one keeps few points close along it), and each query walks
    out both ways from its place in that order until the distance along the axis alone is no
    shorter than the nearest found. Infinity when there is no other point.

    :param points: (N, 3) the points.
    :param order: the order that sorts the points' `axis` coordinates.
    :param axis: 0, 1 or 2.
    :param queries: indices of the points whose neighbours are wanted.
    """
    count = points.shape[0]
    place = np.empty(count, dtype=np.int64)
    for k in range(count):
        place[order[k]] = k
    distances = np.empty(queries.shape[0])
    for q in range(queries.shape[0]):
        i = queries[q]
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        key = points[i, axis]
        best = np.inf  # squared
        # Along the axis the gaps only grow (rounding is monotonic), and a point's squared
        # distance is at least its squared gap: the first gap as long as the best ends a walk.
        for k in range(place[i] + 1, count):
            j = order[k]
            gap = points[j, axis] - key
            if gap * gap >= best:
                break
            dx, dy, dz = points[j, 0] - x, points[j, 1] - y, points[j, 2] - z
            best = min(best, dx * dx + dy * dy + dz * dz)
        for k in range(place[i] - 1, -1, -1):
            j = order[k]
            gap = points[j, axis] - key
            if gap * gap >= best:
                break
            dx, dy, dz = points[j, 0] - x, points[j, 1] - y, points[j, 2] - z
            best = min(best, dx * dx + dy * dy + dz * dz)
        distances[q] = np.sqrt(best)
    return distances


def search_tree(points: ArrayLike) -> cKDTree:
    """
    Return scipy's k-d tree of `points` (N, 3) for a few exact nearest or within-reach queries.

    Sliding-midpoint splits, uncompacted nodes and leaves of 32 points instead of scipy's
    balanced, compacted tree of 16: it builds in about half the time, and a tree that answers
    a few hundred queries is mostly its building. The answers are the same: the queries are
    exact whatever the tree (only which of two equally near points is named may differ).
    """
    return cKDTree(points, leafsize=32, balanced_tree=False, compact_nodes=False)


def warm_up() -> None:
    """Compile (or load) the kernels on a tiny input."""
    points = np.zeros((2, 3))
    cells, span, order, sorted_keys = cell_grid(points, 1.0, 1)
    cell_start(sorted_keys, cell_key(1, 1, 1, span))
    neighbour_distances(points, np.arange(2), 0, np.arange(2))
    points.flags.writeable = False
    neighbour_distances(points, np.arange(2), 0, np.arange(2))
