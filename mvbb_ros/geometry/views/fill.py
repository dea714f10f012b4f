"""
The inside of a single view's solid: samples of the space the sensor never saw to be free.

The shape completion (:mod:`mvbb_ros.geometry.views.completion`) samples each observed point's
ray behind it, every point spacing: to the estimated far side (:func:`fill_to_far_side`), or
until it leaves the observed points' box (:func:`fill_to_box`); on a support, it also samples
straight down from the top of every footprint column (:func:`fill_down`). :func:`one_per_cell`
keeps one sample per cubic cell. The sampling loops are numba kernels.
"""

from __future__ import annotations

import functools

from mvbb_ros.arrays import BoolArray, FloatArray, IndexArray, perpendicular_axes, read_only
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.views.raster import MAX_RASTER_SIDE, view_raster, ViewRaster
import numba as nb
import numpy as np

#: The estimated part keeps one point per cube this many point spacings wide ...
SOLID_CELLS = 1.0
#: ... or wider, so that there are at most this many cubes along a side.
MAX_SOLID_SIDE = 96
#: Most samples of an object's estimated part (a coarser step beyond: the solid's bounds are
#: what the decomposition uses, and they do not need more).
MAX_SAMPLES = 40_000


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
def one_per_cell(points: FloatArray, keep: BoolArray, cell: float) -> IndexArray:
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


@functools.lru_cache(maxsize=8)
def cached_perpendicular_axes(x: float, y: float, z: float) -> tuple[FloatArray, FloatArray]:
    """Return :func:`perpendicular_axes` of (x, y, z) (read-only; one object's up, asked often)."""
    first, second = perpendicular_axes(np.array([x, y, z]))
    return read_only(first), read_only(second)


def fill_down(points: FloatArray, up: FloatArray, lowest: float, step: float) -> FloatArray:
    """
    Sample straight down from the top of every footprint column to the height `lowest`.

    The footprint is cut into `step`-wide columns across `up` (coarser when that would make
    more than :data:`MAX_RASTER_SIDE` columns along a side); each column's highest point is the
    top of a column of samples every `step` (the object stands on something below it).
    """
    first, second = cached_perpendicular_axes(*up.tolist())
    across, along, height = points @ first, points @ second, points @ up
    widest = max(float(np.ptp(across)), float(np.ptp(along)))
    tops = _column_tops(across, along, height, max(step, widest / MAX_RASTER_SIDE))
    down = np.repeat(-up[None, :], len(tops), axis=0)
    return _samples(points[tops], down, height[tops] - lowest, step)


def warm_up() -> None:
    """Run every kernel of this module once on a tiny view (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(np.linspace(-0.05, 0.05, 6), np.linspace(0.0, 0.1, 6)), -1)
    points = np.column_stack([grid.reshape(-1, 2), np.full(36, 0.8)])
    raster = view_raster(points, np.zeros(3), 0.02)
    fill = fill_to_far_side(points, points + [0.0, 0.0, 0.1], raster, 0.02)
    down = fill_down(np.concatenate([points, fill]), np.array([0.0, -1.0, 0.0]), -0.1, 0.02)
    one_per_cell(down, np.ones(len(down), dtype=np.bool_), 0.02)
