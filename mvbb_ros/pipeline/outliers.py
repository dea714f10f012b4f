"""
Statistical outlier removal, compiled (numba): Open3D's ``remove_statistical_outlier``, exactly.

The last step of :func:`mvbb_ros.pipeline.filtering.filter_points`. What Open3D 0.19 computes,
established by probing it (``test/test_outliers.py`` pins each point) rather than by reading
its code:

- every point's mean distance to its ``k = min(nb_neighbors, N)`` nearest points, the point
  itself included (its own zero distance is one of the ``k``): the mean of the ``k - 1``
  nearest other points times ``(k - 1) / k``;
- the cloud's mean ``m`` of those mean distances, summed over the points whose mean distance is
  > 0 but divided by ``N``, and their standard deviation ``s`` with Bessel's correction
  (``N - 1``), again over the points whose mean distance is > 0;
- a point is kept when its mean distance is > 0 and strictly below ``m + std_ratio * s``: a
  point with ``k`` copies of itself (mean distance 0) is removed, one point or two points give
  nothing, and ``nb_neighbors < 1`` or ``std_ratio <= 0`` is an error.

Distances are the square roots of ``(dx*dx + dy*dy) + dz*dz`` in float64, summed from the
nearest to the farthest, and the cloud's sums run in point order, so the mean distances and the
threshold come out with Open3D's rounding (ties in the k-th distance change which neighbour is
taken, never the distance). The kept indices are Open3D's on every cloud tested.

The k nearest neighbours come from a kd-tree built for the call: median splits on the widest
axis of each node's bounding box down to leaves of at most :data:`LEAF_SIZE` points, points
copied into tree order (each leaf is contiguous), nodes in an implicit binary layout (no child
pointers). The points are queried leaf by leaf, in tree order, so that consecutive leaves are
neighbours: a leaf's points share one walk of the tree, which collects the points within a
reach of the leaf's box (the previous leaf's largest k-th distance, widened a little); each
point's k nearest are the k smallest of its distances to those, kept sorted by insertion, when
at least k of them lie within the reach (a point left out is farther than the reach). A point
with fewer, and every point of a range's first leaf, walks the tree itself: nearest child
first, pruning nodes farther than the current k-th distance, bounded from the start by the
previous point's k-th distance plus the step between the two (triangle inequality). A kd-tree
rather than a uniform grid: it adapts to the density, which on a lidar sweep's voxel centroids
varies by orders of magnitude between near and far (a grid sized for the near field makes the
far queries scan thousands of empty cells).

Cost: below Open3D's own ``remove_statistical_outlier`` on the same centroids
(``docs/performance.md``); the profile is dominated by mispredicted branches in the k-best
insertion, not by arithmetic. Tried and measured no faster: a max-heap with a final sort, leaf
sizes 6 to 64, a branch-free vectorised insertion, ranking the candidates by counting, sorting
a leaf's candidates by their distance to the leaf's centre.
"""

from __future__ import annotations

import itertools
from typing import Any

from mvbb_ros.common.workers import chunks, Workers, workers
from numba import njit, types
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ['LEAF_SIZE', 'mean_neighbor_distances', 'remove_statistical_outliers']

#: Largest number of points in a kd-tree leaf.
LEAF_SIZE = 12
#: Deepest tree :func:`_build` makes (2**40 leaves: more points than memory holds).
_MAX_DEPTH = 40
#: A kd-tree leaf's points share the candidates within this factor of the previous leaf's
#: largest k-th distance of the leaf's box (:func:`_fill`): 1.1-1.2 measured alike.
LEAF_REACH = 1.15
#: Each point first takes the candidates within this factor of the previous point's k-th
#: distance (squared), a guess that mostly holds k of them and few more (:func:`_fill`).
FIRST_GUESS = 1.15
#: Fewer points than this are queried on one thread (a split would cost more than it saves).
MIN_SPLIT_POINTS = 2000
#: A split cloud's queries go in ranges of whole leaves, about this many points (at least
#: :data:`MIN_RANGES_PER_WORKER` per thread), taken by whichever thread is free: a range's first
#: leaf has no previous one to share candidates with.
RANGE_POINTS = 256
MIN_RANGES_PER_WORKER = 4


@njit
def _select(keys: Any, order: Any, low: Any, high: Any, nth: Any) -> None:
    """Reorder ``order[low:high]`` so that ``keys[order[nth]]`` is in its sorted place (Hoare)."""
    while high - low > 1:
        middle = (low + high) // 2
        # Median of three as the pivot value.
        a, b, c = keys[order[low]], keys[order[middle]], keys[order[high - 1]]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = low, high - 1
        while i <= j:
            while keys[order[i]] < pivot:
                i += 1
            while keys[order[j]] > pivot:
                j -= 1
            if i <= j:
                order[i], order[j] = order[j], order[i]
                i += 1
                j -= 1
        if nth <= j:
            high = j + 1
        elif nth >= i:
            low = i
        else:
            return


@njit
def _depth(count: Any) -> Any:
    depth = 0
    while depth < _MAX_DEPTH and (count + (1 << depth) - 1) >> depth > LEAF_SIZE:
        depth += 1
    return depth


@njit
def _build(points: Any) -> Any:
    """
    Build the kd-tree of `points` (N, 3).

    :return: ``(tree_points, order, lower, upper, depth)``: the points in tree order, the
        original index of each, each node's bounding box (nodes numbered heap-like: the
        children of ``n`` are ``2n + 1`` and ``2n + 2``), and the depth of the leaves. Node
        ``n`` at depth ``d`` holds ``order[start:end]`` where the range is halved at each level
        (the left half gets the smaller coordinates along the node's widest axis).
    """
    count = points.shape[0]
    depth = _depth(count)
    nodes = (1 << (depth + 1)) - 1
    lower = np.empty((nodes, 3), dtype=np.float64)
    upper = np.empty((nodes, 3), dtype=np.float64)
    order = np.arange(count)
    keys = np.empty(count, dtype=np.float64)
    starts = np.zeros(nodes + 1, dtype=np.int64)
    ends = np.zeros(nodes + 1, dtype=np.int64)
    ends[0] = count
    for node in range(nodes):
        start, end = starts[node], ends[node]
        for axis in range(3):
            lower[node, axis] = np.inf
            upper[node, axis] = -np.inf
        for i in range(start, end):
            for axis in range(3):
                value = np.float64(points[order[i], axis])
                lower[node, axis] = min(lower[node, axis], value)
                upper[node, axis] = max(upper[node, axis], value)
        left = 2 * node + 1
        if left >= nodes:
            continue
        middle = (start + end) // 2
        spans = (
            upper[node, 0] - lower[node, 0],
            upper[node, 1] - lower[node, 1],
            upper[node, 2] - lower[node, 2],
        )
        axis = 2
        if spans[0] >= spans[1] and spans[0] >= spans[2]:
            axis = 0
        elif spans[1] >= spans[2]:
            axis = 1
        for i in range(start, end):
            keys[order[i]] = points[order[i], axis]
        if end - start > 1:
            _select(keys, order, start, end, middle)
        starts[left], ends[left] = start, middle
        starts[left + 1], ends[left + 1] = middle, end
    tree_points = np.empty((count, 3), dtype=np.float64)
    for i in range(count):
        for axis in range(3):
            tree_points[i, axis] = points[order[i], axis]
    return tree_points, order, lower, upper, depth, starts, ends


@njit
def _box_distance(x: Any, y: Any, z: Any, lower: Any, upper: Any, node: Any) -> Any:
    """Squared distance from a point to a node's bounding box (0 inside)."""
    dx = max(lower[node, 0] - x, 0.0, x - upper[node, 0])
    dy = max(lower[node, 1] - y, 0.0, y - upper[node, 1])
    dz = max(lower[node, 2] - z, 0.0, z - upper[node, 2])
    return (dx * dx + dy * dy) + dz * dz


@njit(inline='always')
def _insert(best: Any, at: Any, value: Any) -> None:
    """Put `value` into the ascending ``best[1:at + 1]``, dropping ``best[at]``."""
    # best[0] is -inf: the shift stops there without an index test.
    while best[at - np.uint64(1)] > value:
        best[at] = best[at - np.uint64(1)]
        at -= np.uint64(1)
    best[at] = value


@njit
def _query(
    tree_points: Any,
    lower: Any,
    upper: Any,
    starts: Any,
    ends: Any,
    first_leaf: Any,
    x: Any,
    y: Any,
    z: Any,
    k: Any,
    bound: Any,
    best: Any,
    stack: Any,
    stack_distances: Any,
) -> Any:
    """
    Fill ``best[1:k + 1]`` with the k smallest squared distances from (x, y, z), ascending.

    `bound` is a squared distance within which there are at least k points (inf when unknown):
    until k candidates are in, nodes and points farther than it are skipped; after that, nodes
    farther than the k-th best. Candidates go into the sorted `best` by insertion (``best[0]``
    is a -inf sentinel).

    :return: how many distances were found (k unless `bound` was wrong).
    """
    filled = 0
    worst = bound
    top = 0
    stack[0] = 0
    stack_distances[0] = 0.0
    while top >= 0:
        node = stack[top]
        distance = stack_distances[top]
        top -= 1
        if distance >= worst:
            continue  # everything in it is at least as far as the k-th best: no change
        if node >= first_leaf:
            for i in range(starts[node], ends[node]):
                dx = tree_points[i, 0] - x
                dy = tree_points[i, 1] - y
                dz = tree_points[i, 2] - z
                squared = (dx * dx + dy * dy) + dz * dz
                if filled < k:
                    if squared > bound:
                        continue
                    filled += 1
                    at = np.uint64(filled)
                elif squared < worst:
                    at = np.uint64(k)
                else:
                    continue
                _insert(best, at, squared)
                if filled == k:
                    worst = best[k]
            continue
        left = 2 * node + 1
        left_distance = _box_distance(x, y, z, lower, upper, left)
        right_distance = _box_distance(x, y, z, lower, upper, left + 1)
        # Push the farther child first so that the nearer one is searched first.
        if left_distance <= right_distance:
            near, near_distance, far, far_distance = left, left_distance, left + 1, right_distance
        else:
            near, near_distance, far, far_distance = left + 1, right_distance, left, left_distance
        if far_distance < worst:
            top += 1
            stack[top] = far
            stack_distances[top] = far_distance
        if near_distance < worst:
            top += 1
            stack[top] = near
            stack_distances[top] = near_distance
    return filled


@njit
def _leaf_candidates(
    tree_points: Any,
    lower: Any,
    upper: Any,
    starts: Any,
    ends: Any,
    first_leaf: Any,
    leaf: Any,
    reach_squared: Any,
    stack: Any,
    xs: Any,
    ys: Any,
    zs: Any,
) -> Any:
    """
    Copy into `xs`, `ys`, `zs` every point within the root of `reach_squared` of a leaf's box.

    The leaves whose boxes are farther are skipped whole. Every point left out is farther than
    that from every point of the leaf, in floating point too: a rounded difference grows with
    its operands, so a point's distance to a point of the box is at least its distance to the
    box. :return: how many points were copied.
    """
    copied = 0
    top = 0
    stack[0] = 0
    while top >= 0:
        node = stack[top]
        top -= 1
        dx = max(lower[node, 0] - upper[leaf, 0], 0.0, lower[leaf, 0] - upper[node, 0])
        dy = max(lower[node, 1] - upper[leaf, 1], 0.0, lower[leaf, 1] - upper[node, 1])
        dz = max(lower[node, 2] - upper[leaf, 2], 0.0, lower[leaf, 2] - upper[node, 2])
        if (dx * dx + dy * dy) + dz * dz > reach_squared:
            continue
        if node < first_leaf:
            top += 1
            stack[top] = 2 * node + 2
            top += 1
            stack[top] = 2 * node + 1
            continue
        for i in range(starts[node], ends[node]):
            x, y, z = tree_points[i, 0], tree_points[i, 1], tree_points[i, 2]
            dx = max(lower[leaf, 0] - x, 0.0, x - upper[leaf, 0])
            dy = max(lower[leaf, 1] - y, 0.0, y - upper[leaf, 1])
            dz = max(lower[leaf, 2] - z, 0.0, z - upper[leaf, 2])
            # Written always, kept when near (no branch on the distance).
            xs[copied], ys[copied], zs[copied] = x, y, z
            copied += (dx * dx + dy * dy) + dz * dz <= reach_squared
    return copied


@njit
def _within(squared: Any, count: Any, bound: Any, chosen: Any) -> Any:
    """Copy the first `count` squared distances that are at most `bound` into `chosen`."""
    taken = 0
    for i in range(count):
        chosen[taken] = squared[i]
        taken += squared[i] <= bound
    return taken


@njit
def _fill(
    tree_points: Any,
    order: Any,
    lower: Any,
    upper: Any,
    depth: Any,
    starts: Any,
    ends: Any,
    k: Any,
    begin: Any,
    end: Any,
    result: Any,
) -> None:
    """
    Write the mean distances of the points of the leaves ``begin:end`` into `result`.

    The leaves are numbered from 0 in tree order. A leaf's points share one list of candidates:
    the points within :data:`LEAF_REACH` times the previous leaf's largest k-th distance of the
    leaf's box (:func:`_leaf_candidates`). Each point's k nearest are then the k smallest of its
    distances to them, taken from those within a first guess (:data:`FIRST_GUESS` times the
    previous point's k-th distance, squared), else within that distance plus the step between
    the two points (triangle inequality), else within the whole reach; a point with fewer than
    k candidates within the reach asks the tree (:func:`_query`), as does every point of a
    range's first leaf. Each point's answer is its own k nearest distances whatever came before
    it, so the ranges of a split give the points the same values as one pass.
    """
    count = tree_points.shape[0]
    first_leaf = (1 << depth) - 1
    best = np.empty(k + 1, dtype=np.float64)
    best[0] = -np.inf  # a sentinel for the insertion
    stack = np.empty(2 * _MAX_DEPTH + 2, dtype=np.int64)
    stack_distances = np.empty(2 * _MAX_DEPTH + 2, dtype=np.float64)
    xs = np.empty(count, dtype=np.float64)
    ys = np.empty(count, dtype=np.float64)
    zs = np.empty(count, dtype=np.float64)
    squared = np.empty(count, dtype=np.float64)
    chosen = np.empty(count, dtype=np.float64)
    reach_squared = np.inf  # none before the range's first leaf
    previous_x = previous_y = previous_z = 0.0
    radius = -1.0  # the previous point's k-th distance (none yet)
    for leaf in range(first_leaf + begin, first_leaf + end):
        if ends[leaf] <= starts[leaf]:
            continue
        candidates = 0
        if reach_squared < np.inf:
            candidates = _leaf_candidates(
                tree_points, lower, upper, starts, ends, first_leaf, leaf, reach_squared, stack,
                xs, ys, zs,
            )  # fmt: skip
        widest = 0.0  # the leaf's largest k-th distance, squared
        for i in range(starts[leaf], ends[leaf]):
            x, y, z = tree_points[i, 0], tree_points[i, 1], tree_points[i, 2]
            step = np.sqrt((x - previous_x) ** 2 + (y - previous_y) ** 2 + (z - previous_z) ** 2)
            # k points lie within radius + step of this one (triangle inequality); the factor
            # covers rounding.
            chained = ((radius + step) * (1.0 + 1e-9)) ** 2 if radius >= 0.0 else np.inf
            for j in range(candidates):
                dx = xs[j] - x
                dy = ys[j] - y
                dz = zs[j] - z
                squared[j] = (dx * dx + dy * dy) + dz * dz
            taken = 0
            if radius >= 0.0:
                guess = min(reach_squared, FIRST_GUESS * radius**2)
                taken = _within(squared, candidates, guess, chosen)
                if taken < k:
                    taken = _within(squared, candidates, min(reach_squared, chained), chosen)
            if taken < k and candidates > 0:
                taken = _within(squared, candidates, reach_squared, chosen)
            if taken >= k:
                # The k smallest of the chosen are the k nearest: every point left out is
                # farther than the reach, and the chosen are within it.
                filled = 0
                for j in range(taken):
                    value = chosen[j]
                    if filled < k:
                        filled += 1
                        at = np.uint64(filled)
                    elif value < best[k]:
                        at = np.uint64(k)
                    else:
                        continue
                    _insert(best, at, value)
            else:
                found = _query(
                    tree_points, lower, upper, starts, ends, first_leaf, x, y, z, k, chained,
                    best, stack, stack_distances,
                )  # fmt: skip
                if found < k:  # cannot happen in exact arithmetic; a safety net
                    _query(
                        tree_points, lower, upper, starts, ends, first_leaf, x, y, z, k, np.inf,
                        best, stack, stack_distances,
                    )  # fmt: skip
            total = 0.0
            for j in range(1, k + 1):  # nearest first, as Open3D sums them
                total += np.sqrt(best[j])
            result[order[i]] = total / k
            radius = np.sqrt(best[k])
            widest = max(widest, best[k])
            previous_x, previous_y, previous_z = x, y, z
        reach_squared = widest * LEAF_REACH**2


@njit(
    types.float64[::1](types.Array(types.float64, 2, 'C', readonly=True), types.int64),
    cache=True,
    nogil=True,
)
def _mean_distances(points: Any, neighbors: Any) -> Any:
    """Each point's mean distance to its ``min(neighbors, N)`` nearest points, itself included."""
    count = points.shape[0]
    result = np.zeros(count, dtype=np.float64)
    if count == 0:
        return result
    tree_points, order, lower, upper, depth, starts, ends = _build(points)
    _fill(tree_points, order, lower, upper, depth, starts, ends, min(neighbors, count), 0,
          1 << depth, result)  # fmt: skip
    return result


@njit(cache=True, nogil=True)
def _tree(points: Any) -> Any:
    """Return :func:`_build` of `points` (for the queries split over workers)."""
    return _build(points)


@njit(cache=True, nogil=True)
def _fill_range(
    tree_points: Any,
    order: Any,
    lower: Any,
    upper: Any,
    depth: Any,
    starts: Any,
    ends: Any,
    k: Any,
    begin: Any,
    end: Any,
    result: Any,
) -> None:
    """Run :func:`_fill` on one range of the leaves in tree order (one worker's share)."""
    _fill(tree_points, order, lower, upper, depth, starts, ends, k, begin, end, result)


class NeighbourQueries:
    """
    The mean neighbour distances of one cloud, in ranges of leaves any thread may take.

    :meth:`take` computes ranges that no thread has taken yet until none is left, so the threads
    that call it share the work whenever each comes free (a helper may start before the
    caller). The distances are :func:`_mean_distances`' whoever computed which range: each
    point's answer is its own k nearest. They are complete once every :meth:`take` has returned.
    """

    def __init__(self, points: NDArray[np.float64], neighbors: int, ranges: int) -> None:
        count = points.shape[0]
        self.distances = np.zeros(count, dtype=np.float64)
        self._tree = _tree(points) if count else None
        self._k = min(int(neighbors), count)
        leaves = 1 << self._tree[4] if self._tree is not None else 0
        self._ranges = chunks(leaves, ranges) if count else []
        self._next = itertools.count()  # next() on it is atomic: each range is taken once
        self._cancelled = False

    def take(self) -> None:
        """Compute the ranges nobody has taken, until none is left or :meth:`cancel`."""
        tree = self._tree
        while tree is not None and not self._cancelled:
            index = next(self._next)
            if index >= len(self._ranges):
                return
            part = self._ranges[index]
            tree_points, order, lower, upper, depth, starts, ends = tree
            _fill_range(
                tree_points, order, lower, upper, depth, starts, ends, self._k, part.start,
                part.stop, self.distances,
            )  # fmt: skip

    def cancel(self) -> None:
        """Stop taking ranges (the distances are not wanted any more)."""
        self._cancelled = True


def split_queries(points: NDArray[np.float64], neighbors: int, pool: Workers) -> NeighbourQueries:
    """Return the :class:`NeighbourQueries` of `points` in ranges for `pool`'s threads."""
    ranges = max(pool.count * MIN_RANGES_PER_WORKER, len(points) // RANGE_POINTS)
    return NeighbourQueries(points, neighbors, ranges)


def _mean_distances_split(
    points: NDArray[np.float64], neighbors: int, pool: Workers
) -> NDArray[np.float64]:
    """Return :func:`_mean_distances`, the queries shared by the threads of `pool`."""
    queries = split_queries(points, neighbors, pool)
    pool.spread(lambda _: queries.take(), range(pool.count))
    return queries.distances


@njit(types.int64[::1](types.float64[::1], types.float64), cache=True, nogil=True)
def _kept(mean_distances: Any, std_ratio: Any) -> Any:
    """Open3D's statistics over the mean distances (see the module docstring); kept indices."""
    count = mean_distances.shape[0]
    total = 0.0
    for distance in mean_distances:
        if distance > 0.0:
            total += distance
    mean = total / count
    squares = 0.0
    for distance in mean_distances:
        if distance > 0.0:
            squares += (distance - mean) * (distance - mean)
    threshold = mean + std_ratio * np.sqrt(squares / (count - 1))
    kept = np.empty(count, dtype=np.int64)
    used = 0
    for i in range(count):
        if mean_distances[i] > 0.0 and mean_distances[i] < threshold:
            kept[used] = i
            used += 1
    return kept[:used].copy()


def _readonly_points(points: ArrayLike) -> NDArray[np.float64]:
    # float64 only (one compiled signature): the voxel centroids are float64 already; raw
    # float32 points are converted (exactly) here.
    array = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3)).view()
    array.flags.writeable = False
    return array


def checked_points(points: ArrayLike, nb_neighbors: int) -> NDArray[np.float64]:
    """
    Return `points` as the read-only float64 (N, 3) array the queries take, or raise.

    :raises ValueError: for ``nb_neighbors < 1`` or non-finite points.
    """
    if int(nb_neighbors) < 1:
        raise ValueError(f'nb_neighbors must be >= 1, got {nb_neighbors!r}')
    array = _readonly_points(points)
    if not np.isfinite(array).all():
        raise ValueError('points must be finite')
    return array


def check_std_ratio(std_ratio: float) -> None:
    """Raise ValueError unless `std_ratio` is finite and > 0 (Open3D refuses the rest)."""
    if not (np.isfinite(std_ratio) and std_ratio > 0.0):
        raise ValueError(f'std_ratio must be finite and > 0, got {std_ratio!r}')


def mean_neighbor_distances(
    points: ArrayLike, nb_neighbors: int, pool: Workers | None = None
) -> NDArray[np.float64]:
    """
    Return each point's mean distance to its nearest points, Open3D's way (itself included).

    :param points: finite points ``(N, 3)`` (converted to float64).
    :param nb_neighbors: k, >= 1; ``min(k, N)`` distances are averaged, the point's own zero
        distance among them.
    :param pool: workers to split the queries over (the same distances with any), or None.
    :return: the mean distances ``(N,)``, float64.
    :raises ValueError: for ``nb_neighbors < 1`` or non-finite points.
    """
    array = checked_points(points, nb_neighbors)
    if pool is not None and pool.parallel and len(array) >= MIN_SPLIT_POINTS:
        return _mean_distances_split(array, int(nb_neighbors), pool)
    return _mean_distances(array, int(nb_neighbors))


def remove_statistical_outliers(
    points: ArrayLike, nb_neighbors: int, std_ratio: float, pool: Workers | None = None
) -> NDArray[np.intp]:
    """
    Return the indices of the points that Open3D's ``remove_statistical_outlier`` keeps.

    :param points: finite points ``(N, 3)``, float32 or float64 (typically voxel centroids).
    :param nb_neighbors: neighbours of each point, itself included, >= 1.
    :param std_ratio: a point is kept when its mean neighbour distance is below the cloud's
        mean plus this many standard deviations; > 0.
    :param pool: workers to split the neighbour queries over (the same result with any).
    :return: the kept indices, increasing; empty for fewer than two points (Open3D's result).
    :raises ValueError: for ``nb_neighbors < 1``, ``std_ratio <= 0`` (Open3D refuses both) or
        non-finite points.
    """
    check_std_ratio(std_ratio)
    return kept_points(mean_neighbor_distances(points, nb_neighbors, pool), std_ratio)


def kept_points(mean_distances: NDArray[np.float64], std_ratio: float) -> NDArray[np.intp]:
    """
    Return the indices Open3D keeps given every point's mean neighbour distance.

    :param mean_distances: :func:`mean_neighbor_distances` of the cloud.
    :param std_ratio: as for :func:`remove_statistical_outliers` (checked there).
    """
    if len(mean_distances) < 2:
        return np.empty(0, dtype=np.intp)
    return _kept(mean_distances, float(std_ratio)).astype(np.intp, copy=False)


def warm_up() -> None:
    """Run every kernel of this module once (see :mod:`mvbb_ros.kernels`)."""
    points = np.arange(15, dtype=np.float64).reshape(5, 3) ** 2
    remove_statistical_outliers(points, 3, 1.0)
    _mean_distances_split(_readonly_points(points), 3, workers(1))
