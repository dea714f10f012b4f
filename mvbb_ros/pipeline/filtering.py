"""
Point cloud filtering before the objects and the box fit: crop, voxel grid, outliers.

Each step can be turned off (:class:`~mvbb_ros.pipeline.stage_settings.FilterSettings`, whose
defaults turn them all off; the node turns the voxel grid and the outliers on). Steps run in
that order: cropping first makes the others cheaper, and outlier statistics are steadier on the
evenly spaced voxel centroids than on raw sensor points. The voxel grid and the crop are
compiled kernels here (numba); the statistical outlier removal is in
:mod:`mvbb_ros.pipeline.outliers`. Both compute exactly what Open3D's ``voxel_down_sample`` and
``remove_statistical_outlier`` compute (``test/test_filtering.py`` and ``test/test_outliers.py``
compare them bit for bit), faster on one core (``docs/performance.md``), and the pipeline needs
no Open3D, whose import alone the node's start must not pay.

The crop and the decoder
------------------------
The crop box is applied by the decoder while it decodes a message
(:func:`mvbb_ros.pipeline.decode.decode_points`, on :func:`inside_box` and :func:`crop_box`
from here), which also measures the kept points' bounds and counts the finite points:
:func:`filter_points` takes both (`bounds`, `finite`) and then neither crops again nor measures
the points again. Given plain points, it crops them itself, fused with the voxel pass.

The voxel grid: Open3D's centroids, sorted by voxel
---------------------------------------------------
What it computes is Open3D's ``voxel_down_sample``: the grid is anchored half a voxel below the
minimum corner of the (cropped) cloud, a point falls in voxel ``floor((p - anchor) / size)``
computed in float64 (a true division, as Open3D), and every occupied voxel becomes the float64
mean of its points, summed in input order and divided by the count, as Open3D does. So the
centroids are Open3D's bit for bit. Their order is ours: sorted by voxel index (x slowest, z
fastest), not the order in which voxels are first met (which the kernel produces) nor Open3D's
hash order. The decomposition depends on the order of its points (the box fit samples them), so
the order is a choice with consequences: sorted, the same points in any order give the same
centroids in the same order, so the same boxes (a driver or a file that lists the points
differently changes nothing), and the boxes are those of the numpy grid this replaced. The sort
orders the occupied voxels, not the points, so it is cheap (first-met order would have made
the boxes of one shared scan in 30 change with the row order of the sensor).

Two passes over the points, float32 or float64 as they come from the decoder (no float64 copy):

1. :func:`_crop_bounds`: count the points inside the crop box (bounds included) and take their
   bounding box; a non-finite point stops it with an error. Skipped when the decoder already
   measured the bounds.
2. :func:`_voxel_grid`: group the points by voxel in one sequential pass, block by block.

Why the second pass is fast:

- *SIMD divisions.* Each block of 512 points first gets its voxel indices in a plain loop that
  compiles to vector divisions (:func:`_block_voxels`); one float64 division at a time was
  most of the pass.
- *Runs are summed in registers.* While consecutive points stay in one voxel (about 6 points
  per run on a depth frame at 5 mm), the voxel's sums live in registers; they are loaded when
  the run starts and stored when it ends, so every point is still added in input order (the
  same rounding as Open3D's per-point sums).
- *Lookup on change only*: in a dense grid of slot numbers when the grid has at most
  :data:`DENSE_CELLS_PER_POINT` cells per point (an object or a work surface at 5 mm: one array
  read, no hashing), else in an open-addressing hash table keyed by the three voxel indices (a
  lidar sweep over hundreds of metres). On a depth frame's runs the two cost the same; on
  points in no particular order (a resampled or merged cloud: a lookup at almost every point)
  the dense grid takes about a fifth off the pass (``docs/performance.md``). Slots (and the
  hash table) start at 4096 and double, so memory is linear in the number of occupied voxels
  or, for the dense grid, bounded by the number of points.

Limits: as Open3D, each axis may hold up to ``2**31 - 1`` voxels; a larger grid (a voxel too
small for the extent, or absurd coordinates such as 1e38) is refused with a ValueError before
anything is allocated.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import threading
from typing import Any

from mvbb_ros.arrays import column_max, column_min
from mvbb_ros.common.workers import Workers
from mvbb_ros.pipeline.outliers import (
    check_std_ratio,
    checked_points,
    kept_points,
    MIN_SPLIT_POINTS,
    NeighbourQueries,
    remove_statistical_outliers,
    split_queries,
)
from mvbb_ros.pipeline.stage_settings import FilterSettings
from numba import njit, types
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    'BOX',
    'FilterCounts',
    'Voxels',
    'crop_box',
    'crop_points',
    'filter_points',
    'finite_bounds',
    'inside_box',
    'outlier_step',
    'voxel_down_sample',
    'voxel_step',
]

#: Largest voxel index along one axis (Open3D's limit: a C int).
MAX_AXIS_VOXELS = 2**31 - 1

_POINT_TYPES = (types.float32, types.float64)


def _points_type(dtype: Any) -> Any:
    return types.Array(dtype, 2, 'C', readonly=True)


#: A crop box as a tuple (x0, y0, z0, x1, y1, z1): scalars the compiler keeps in registers
#: (read from an array inside the loop, the bounds made the pass several times slower).
BOX = types.UniTuple(types.float64, 6)


@njit
def inside_box(x: Any, y: Any, z: Any, box: Any) -> Any:
    """Tell whether a point is inside ``box = (x0, y0, z0, x1, y1, z1)``, bounds included."""
    # & rather than `and`: no branches, so that the loops around it compile to SIMD code.
    inside_x = (box[0] <= x) & (x <= box[3])
    return inside_x & (box[1] <= y) & (y <= box[4]) & (box[2] <= z) & (z <= box[5])


def crop_box(
    crop_min: ArrayLike | None, crop_max: ArrayLike | None
) -> tuple[tuple[float, ...], bool]:
    """
    Return the crop box as (x0, y0, z0, x1, y1, z1) and whether there is one.

    A corner left empty leaves the box open on that side (so either corner can be set or
    cleared on its own, as ``ros2 param set`` does one parameter at a time).

    :param crop_min: lower corner; None or empty: open below.
    :param crop_max: upper corner; None or empty: open above. Both empty: no crop.
    :return: the box (zeros when there is none) and whether to crop.
    :raises ValueError: a corner is not a 3-vector without NaN.
    """
    given = [corner is not None and np.size(corner) > 0 for corner in (crop_min, crop_max)]
    if not any(given):
        return (0.0,) * 6, False
    lower = np.asarray(crop_min, float).reshape(-1) if given[0] else np.full(3, -np.inf)
    upper = np.asarray(crop_max, float).reshape(-1) if given[1] else np.full(3, np.inf)
    corners = np.concatenate([lower, upper])
    if corners.shape != (6,) or np.isnan(corners).any():
        raise ValueError(
            f'crop corners must be 3-vectors without NaN, got {crop_min!r}, {crop_max!r}'
        )
    return tuple(float(value) for value in corners), True


#: The corners of no point: (x0, y0, z0, x1, y1, z1) that any point widens.
NO_CORNERS = (np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf)


@njit
def widened(corners: Any, x: Any, y: Any, z: Any) -> Any:
    """Return ``corners = (x0, y0, z0, x1, y1, z1)`` grown to hold the point (x, y, z)."""
    low_x, low_y, low_z, high_x, high_y, high_z = corners
    return (
        min(low_x, x), min(low_y, y), min(low_z, z), max(high_x, x), max(high_y, y), max(high_z, z)
    )  # fmt: skip


@njit
def store_corners(bounds: Any, corners: Any) -> None:
    """Write ``corners = (x0, y0, z0, x1, y1, z1)`` into the (2, 3) array `bounds`."""
    bounds[0, 0], bounds[0, 1], bounds[0, 2] = corners[0], corners[1], corners[2]
    bounds[1, 0], bounds[1, 1], bounds[1, 2] = corners[3], corners[4], corners[5]


@njit(
    [
        types.int64(_points_type(dtype), BOX, types.boolean, types.float64[:, ::1])
        for dtype in _POINT_TYPES
    ],
    cache=True,
    nogil=True,
)
def _crop_bounds(points: Any, box: Any, crop: Any, bounds: Any) -> Any:
    """
    Count the points inside the crop box and write their min/max corners into `bounds`.

    :return: the count, or ``-1 - i`` when point ``i`` is not finite (then nothing is valid).
    """
    corners = NO_CORNERS
    count = 0
    for i in range(points.shape[0]):
        x = np.float64(points[i, 0])
        y = np.float64(points[i, 1])
        z = np.float64(points[i, 2])
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            return -1 - i
        if not crop or inside_box(x, y, z, box):
            count += 1
            corners = widened(corners, x, y, z)
    store_corners(bounds, corners)
    return count


@njit
def _hash(i: Any, j: Any, k: Any, mask: Any) -> Any:
    mixed = (
        np.uint64(i) * np.uint64(0x9E3779B97F4A7C15)
        ^ np.uint64(j) * np.uint64(0xC2B2AE3D27D4EB4F)
        ^ np.uint64(k) * np.uint64(0x165667B19E3779F9)
    )
    return np.int64((mixed ^ (mixed >> np.uint64(31))) & mask)


@njit
def _clamped(ratio: Any, top: Any) -> Any:
    """Return ``int(ratio)`` clamped to ``[0, top]`` (0 for NaN: the conversion is defined)."""
    low = ratio if ratio >= 0.0 else 0.0
    return np.int64(low if low <= top else top)


@njit
def _block_voxels(
    flat: Any,
    start: Any,
    count: Any,
    anchor: Any,
    size: Any,
    top: Any,
    box: Any,
    crop: Any,
    voxel_x: Any,
    voxel_y: Any,
    voxel_z: Any,
    keep: Any,
) -> Any:
    """
    Voxel indices of points ``start .. start + count`` (exact float64 division) and crop flags.

    A plain loop over a flat view with unsigned indices, so that it compiles to SIMD divisions
    (several times faster than one division at a time). Indices are clamped to ``[0, top]``: a
    point outside the crop box may be anywhere, and the clamp keeps every index inside the grid
    whatever the points are (a kept point inside the bounds is never clamped).

    :return: how many kept points fall outside the grid (bounds that do not hold the points).
    """
    anchor_x, anchor_y, anchor_z = anchor
    top_x, top_y, top_z = top
    first = np.uint64(3) * np.uint64(start)
    escaped = 0
    for j in range(np.uint64(count)):
        at = first + np.uint64(3) * j
        x = np.float64(flat[at])
        y = np.float64(flat[at + np.uint64(1)])
        z = np.float64(flat[at + np.uint64(2)])
        # (p - anchor) >= 0 inside the bounds, so truncation is Open3D's floor.
        ratio_x = (x - anchor_x) / size
        ratio_y = (y - anchor_y) / size
        ratio_z = (z - anchor_z) / size
        voxel_x[j] = _clamped(ratio_x, top_x)
        voxel_y[j] = _clamped(ratio_y, top_y)
        voxel_z[j] = _clamped(ratio_z, top_z)
        kept = not crop or inside_box(x, y, z, box)
        keep[j] = kept
        # Written so that NaN counts as outside (a non-finite point with trusted bounds).
        inside = (ratio_x >= 0.0) & (ratio_y >= 0.0) & (ratio_z >= 0.0)
        inside &= (ratio_x < top_x + 1.0) & (ratio_y < top_y + 1.0) & (ratio_z < top_z + 1.0)
        escaped += kept & ~inside
    return escaped


#: Points per block of :func:`_group` (index buffers of 4 x 512 values stay in L1).
_BLOCK = 512
#: Voxel slots to start with (doubled as needed).
_FIRST_CAPACITY = 4096
#: A grid of at most this many cells per point (inside the crop box) looks its voxels up in a
#: dense array of slot numbers instead of the hash table: at most 3 bytes of table a point, and
#: faster up to there on points in random order (0.75 cells a point: 18.6 against 25.6 ms; one
#: cell a point: 42 against 38 ms, 300k points).
DENSE_CELLS_PER_POINT = 0.75


@njit
def _save(state: Any, x: Any, y: Any, z: Any, slot: Any, count: Any, used: Any) -> None:
    state[0], state[1], state[2], state[3], state[4], state[5] = x, y, z, slot, count, used


@njit
def _group(
    points: Any,
    box: Any,
    crop: Any,
    anchor: Any,
    size: Any,
    shape: Any,
    table: Any,
    voxels: Any,
    sums: Any,
    counts: Any,
    state: Any,
    running: Any,
    dense: Any,
) -> Any:
    """
    Add points to their voxels from ``state[5]`` on, until the end or until the arrays are full.

    `table` maps a voxel to its slot in `sums`, `counts` and `voxels`: with `dense`, one entry
    per grid cell (C order of the voxel indices), else a hash table (open addressing, linear
    probing); slots are given in the order voxels are first met. The loop state
    lives in `state` (current voxel x, y, z, its slot, its count, slots used, next point) and
    `running` (the current voxel's sums): while consecutive points stay in one voxel its sums
    stay in registers, loaded when the run starts and stored when it ends, so each point is
    still added to its voxel's sum in input order. Returns early, before taking a new slot, when
    the slot arrays are full or the hash table would be more than half full: the caller grows
    them and calls again. The arrays are arguments, never reassigned here (reassigning arrays
    inside the loop made numba's code count references, much slower).

    :return: the index of the next point to add (``len(points)`` when done), or -1 when a
        point falls outside the grid (the bounds given do not hold the points).
    """
    flat = points.reshape(-1)
    top = (float(shape[0] - 1), float(shape[1] - 1), float(shape[2] - 1))
    mask = np.uint64(table.shape[0] - 1)
    block_x = np.empty(_BLOCK, dtype=np.int64)
    block_y = np.empty(_BLOCK, dtype=np.int64)
    block_z = np.empty(_BLOCK, dtype=np.int64)
    keep = np.empty(_BLOCK, dtype=np.bool_)
    current_x, current_y, current_z = state[0], state[1], state[2]
    slot, count, used, first = state[3], state[4], state[5], state[6]
    sum_x, sum_y, sum_z = running[0], running[1], running[2]
    total = points.shape[0]
    for start in range(first, total, _BLOCK):
        length = min(_BLOCK, total - start)
        if _block_voxels(
            flat, start, length, anchor, size, top, box, crop, block_x, block_y, block_z, keep
        ):
            return -1
        for j in range(length):
            if not keep[j]:
                continue
            index_x, index_y, index_z = block_x[j], block_y[j], block_z[j]
            if index_x != current_x or index_y != current_y or index_z != current_z:
                if dense:  # one cell per entry: the entry is this voxel's
                    at = (index_x * shape[1] + index_y) * shape[2] + index_z
                    found = table[at]
                else:
                    at = _hash(index_x, index_y, index_z, mask)
                    found = table[at]
                    while found >= 0 and not (
                        voxels[found, 0] == index_x
                        and voxels[found, 1] == index_y
                        and voxels[found, 2] == index_z
                    ):
                        at = (at + 1) & np.int64(mask)
                        found = table[at]
                full = used == sums.shape[0] or (not dense and 2 * (used + 1) > table.shape[0])
                if found < 0 and full:
                    _save(state, current_x, current_y, current_z, slot, count, used)
                    state[6] = start + j
                    running[0], running[1], running[2] = sum_x, sum_y, sum_z
                    return start + j
                if slot >= 0:  # close the run of the previous voxel
                    sums[slot, 0] = sum_x
                    sums[slot, 1] = sum_y
                    sums[slot, 2] = sum_z
                    counts[slot] = count
                current_x, current_y, current_z = index_x, index_y, index_z
                if found < 0:  # a new voxel
                    found = used
                    used += 1
                    table[at] = found
                    voxels[found, 0] = index_x
                    voxels[found, 1] = index_y
                    voxels[found, 2] = index_z
                    sums[found, 0] = sums[found, 1] = sums[found, 2] = 0.0
                    counts[found] = 0
                slot = found
                sum_x = sums[slot, 0]
                sum_y = sums[slot, 1]
                sum_z = sums[slot, 2]
                count = counts[slot]
            row = start + j
            sum_x += np.float64(points[row, 0])
            sum_y += np.float64(points[row, 1])
            sum_z += np.float64(points[row, 2])
            count += 1
    if slot >= 0:
        sums[slot, 0] = sum_x
        sums[slot, 1] = sum_y
        sums[slot, 2] = sum_z
        counts[slot] = count
    _save(state, current_x, current_y, current_z, slot, count, used)
    state[6] = total
    return total


@njit
def _doubled(array: Any, used: Any) -> Any:
    bigger = np.empty((2 * array.shape[0], array.shape[1]), dtype=array.dtype)
    for row in range(used):  # loops, not slices: numba's slice code takes seconds to compile
        for column in range(array.shape[1]):
            bigger[row, column] = array[row, column]
    return bigger


@njit
def _rehashed(voxels: Any, used: Any, length: Any) -> Any:
    """Return a hash table of `length` slots (a power of two) for voxels ``0 .. used - 1``."""
    table = np.full(length, -1, dtype=np.int32)
    mask = np.uint64(length - 1)
    for slot in range(used):
        at = _hash(voxels[slot, 0], voxels[slot, 1], voxels[slot, 2], mask)
        while table[at] >= 0:
            at = (at + 1) & np.int64(mask)
        table[at] = slot
    return table


@njit(
    [
        types.Tuple((types.float64[:, ::1], types.int64[::1], types.int64[:, ::1], types.boolean))(
            _points_type(dtype),
            types.int64,
            BOX,
            types.boolean,
            types.UniTuple(types.float64, 3),
            types.float64,
            types.UniTuple(types.int64, 3),
        )
        for dtype in _POINT_TYPES
    ],
    cache=True,
    nogil=True,
)
def _voxel_grid(
    points: Any, inside: Any, box: Any, crop: Any, anchor: Any, size: Any, shape: Any
) -> Any:
    """
    Group the points (inside the crop box) by voxel; return centroids, counts, voxels, success.

    Voxels come in the order they are first met. `inside` is the number of points inside the
    crop box, `shape` the number of voxels along each axis. Slots (and the hash table) start
    small and double, so memory stays linear in the number of voxels whatever the extent, or in
    the number of points for the dense table (:data:`DENSE_CELLS_PER_POINT`).
    """
    capacity = max(1, min(inside, _FIRST_CAPACITY))
    # In float: the product of three axes of up to 2**31 voxels overflows int64.
    cells = float(shape[0]) * float(shape[1]) * float(shape[2])
    dense = cells <= DENSE_CELLS_PER_POINT * inside
    length = 16  # a power of two (the hash is masked), at least twice the slots
    while length < 2 * capacity:
        length *= 2
    if dense:
        length = shape[0] * shape[1] * shape[2]
    table = np.full(length, -1, dtype=np.int32)
    sums = np.empty((capacity, 3), dtype=np.float64)
    counts = np.empty((capacity, 1), dtype=np.int64)
    voxels = np.empty((capacity, 3), dtype=np.int64)
    state = np.array([-1, -1, -1, -1, 0, 0, 0], dtype=np.int64)
    running = np.zeros(3, dtype=np.float64)
    while True:
        position = _group(
            points, box, crop, anchor, size, shape, table, voxels, sums, counts[:, 0],
            state, running, dense,
        )  # fmt: skip
        if position == points.shape[0]:
            break
        if position < 0:
            empty = np.empty((0, 3), dtype=np.int64)
            return np.empty((0, 3), dtype=np.float64), np.empty(0, dtype=np.int64), empty, False
        used = state[5]
        if used == sums.shape[0]:
            sums = _doubled(sums, used)
            counts = _doubled(counts, used)
            voxels = _doubled(voxels, used)
        if not dense and 2 * (used + 1) > table.shape[0]:
            table = _rehashed(voxels, used, 2 * table.shape[0])
    used = state[5]
    centroids = np.empty((used, 3), dtype=np.float64)
    indices = np.empty((used, 3), dtype=np.int64)
    for voxel in range(used):
        centroids[voxel, 0] = sums[voxel, 0] / counts[voxel, 0]
        centroids[voxel, 1] = sums[voxel, 1] / counts[voxel, 0]
        centroids[voxel, 2] = sums[voxel, 2] / counts[voxel, 0]
        for axis in range(3):
            indices[voxel, axis] = voxels[voxel, axis]
    return centroids, counts[:used, 0].copy(), indices, True


def _readonly_points(points: ArrayLike) -> NDArray[np.floating]:
    array = np.asarray(points)
    if array.dtype not in (np.float32, np.float64):
        array = array.astype(np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        array = array.reshape(-1, 3)
    array = np.ascontiguousarray(array).view()
    array.flags.writeable = False
    return array


def _checked_bounds(
    points: NDArray[np.floating], box: tuple[float, ...], crop: bool
) -> tuple[int, NDArray[np.float64]]:
    bounds = np.empty((2, 3))
    count = _crop_bounds(points, box, crop, bounds)
    if count < 0:
        bad = -1 - count
        raise ValueError(f'points must be finite; point {bad} is {points[bad].tolist()}')
    return count, bounds


def _voxel_order(voxels: NDArray[np.int64], shape: tuple[int, ...]) -> NDArray[np.intp]:
    """Return the order that sorts voxels by index, x slowest and z fastest."""
    if float(shape[0]) * float(shape[1]) * float(shape[2]) < 2.0**62:
        keys = (voxels[:, 0] * shape[1] + voxels[:, 1]) * shape[2] + voxels[:, 2]
        return _radix_order(keys)  # the keys are distinct: any sort gives one order
    return np.lexsort((voxels[:, 2], voxels[:, 1], voxels[:, 0]))


#: The radix sort's digit: this many bits (a table of 2**bits counts).
RADIX_BITS = 11


@njit('int64[::1](int64[::1])', cache=True, nogil=True)
def _radix_order(keys: Any) -> Any:
    """
    Return the stable order that sorts the non-negative `keys` (``np.argsort(kind='stable')``).

    A least-significant-digit radix sort, :data:`RADIX_BITS` bits a pass, as many passes as the
    largest key needs: a few linear passes instead of numpy's comparison sort (a scene sample's
    16k voxels: about 0.15 instead of 0.6 ms). Not numba's sort (see
    :mod:`mvbb_ros.geometry.views.cells`).
    """
    count = keys.shape[0]
    order = np.arange(count)
    if count < 2:
        return order
    top = keys.max()
    spare = np.empty(count, dtype=np.int64)
    digits = np.int64(1) << RADIX_BITS
    mask = digits - 1
    starts = np.empty(digits, dtype=np.int64)
    shift = 0
    while shift < 63 and (top >> shift) > 0:
        starts[:] = 0
        for i in range(count):
            starts[(keys[i] >> shift) & mask] += 1
        total = 0
        for digit in range(digits):
            total, starts[digit] = total + starts[digit], total
        for i in range(count):
            at = order[i]
            digit = (keys[at] >> shift) & mask
            spare[starts[digit]] = at
            starts[digit] += 1
        order, spare = spare, order
        shift += RADIX_BITS
    return order


def voxel_down_sample(
    points: ArrayLike,
    voxel_size: float,
    *,
    crop_min: ArrayLike | None = None,
    crop_max: ArrayLike | None = None,
    bounds: ArrayLike | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """
    Replace the points of each occupied voxel by their centroid (Open3D's voxel_down_sample).

    With a crop box, only the points inside it (bounds included) count, as if the cloud had
    been cropped first; the grid is then anchored on the cropped points. With `bounds` (from
    :func:`mvbb_ros.pipeline.decode.decode_xyz`, which measures them while decoding) the pass
    that checks the points and measures them is skipped: the points are then trusted to be
    finite, and a point outside the bounds is still caught (ValueError), never indexed out of
    the grid.

    :param points: finite points ``(N, 3)``, float32 or float64 (other types are converted).
    :param voxel_size: voxel edge in metres, finite and > 0.
    :param crop_min: lower corner of an axis-aligned crop box; None or empty: no crop.
    :param crop_max: upper corner of the crop box.
    :param bounds: ``(2, 3)``: min and max corners of the points (inside the crop box), if
        known.
    :return: the centroids ``(M, 3)`` as float64, sorted by voxel index (x slowest, z fastest;
        see the module docstring), and how many points each voxel holds ``(M,)`` (their sum is
        the number of cropped points).
    :raises ValueError: for a voxel size that is not finite and positive, a non-finite point, or
        a grid with more than ``2**31 - 1`` voxels along an axis.
    """
    if not (np.isfinite(voxel_size) and voxel_size > 0.0):
        raise ValueError(f'voxel_size must be finite and > 0, got {voxel_size!r}')
    size = float(voxel_size)
    array = _readonly_points(points)
    box, crop = crop_box(crop_min, crop_max)
    if bounds is None:
        count, bounds = _checked_bounds(array, box, crop)
    else:
        bounds = np.array(bounds, dtype=np.float64).reshape(2, 3)
        count = len(array)
        if count and not (np.isfinite(bounds).all() and (bounds[0] <= bounds[1]).all()):
            raise ValueError(f'bounds must be finite min and max corners, got {bounds.tolist()}')
    if count == 0:
        return np.empty((0, 3)), np.empty(0, dtype=np.int64)
    anchor = bounds[0] - size * 0.5
    # The largest index along each axis comes from the largest coordinate (rounding is
    # monotonic); checked in float64 before any integer conversion or allocation.
    top = np.floor((bounds[1] - anchor) / size)
    if not np.all(top <= MAX_AXIS_VOXELS - 1):
        extent = bounds[1] - bounds[0]
        raise ValueError(
            f'voxel_size {voxel_size} is too small for a cloud spanning {extent.tolist()}: '
            f'more than {MAX_AXIS_VOXELS} voxels along an axis'
        )
    shape = tuple(int(value) + 1 for value in top)
    centroids, counts, voxels, done = _voxel_grid(
        array, count, box, crop, tuple(anchor.tolist()), size, shape
    )
    if not done:
        raise ValueError(f'points outside the given bounds {bounds.tolist()}')
    order = _voxel_order(voxels, shape)
    return centroids[order], counts[order]


@njit(
    [types.int64(_points_type(dtype), BOX, types.Array(dtype, 2, 'C')) for dtype in _POINT_TYPES],
    cache=True,
    nogil=True,
)
def _crop(points: Any, box: Any, out: Any) -> Any:
    """Copy the points inside the crop box to the first rows of `out`; return how many."""
    count = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if inside_box(np.float64(x), np.float64(y), np.float64(z), box):
            out[count, 0] = x
            out[count, 1] = y
            out[count, 2] = z
            count += 1
    return count


def finite_bounds(points: ArrayLike) -> NDArray[np.float64] | None:
    """
    Return the ``(2, 3)`` min and max corners of `points` ``(N, 3)``, N >= 1, in one pass.

    None when a point is not finite (the filters then say which).
    """
    array = _readonly_points(points)
    box, _ = crop_box(None, None)
    bounds = np.empty((2, 3))
    return None if _crop_bounds(array, box, False, bounds) < 0 else bounds


def crop_points(
    points: ArrayLike, crop_min: ArrayLike | None, crop_max: ArrayLike | None
) -> NDArray[np.floating]:
    """
    Keep the points inside an axis-aligned box, bounds included (the crop when voxels are off).

    :param points: points ``(N, 3)``, float32 or float64 (other types are converted); NaN
        points are never inside.
    :param crop_min: lower corner; None or empty: no crop (the points are returned as they are).
    :param crop_max: upper corner.
    :return: the points inside, in their order and dtype.
    """
    array = _readonly_points(points)
    box, crop = crop_box(crop_min, crop_max)
    if not crop:
        return array
    out = np.empty_like(array)
    return out[: _crop(array, box, out)]


@dataclass(frozen=True)
class FilterCounts:
    """Finite input points, then the count after each step (unchanged when a step is off)."""

    finite: int
    cropped: int
    downsampled: int
    inliers: int


def filter_points(
    points: ArrayLike,
    *,
    voxel_size: float = 0.0,
    outlier_neighbors: int = 0,
    outlier_std_ratio: float = 2.0,
    crop_min: ArrayLike | None = None,
    crop_max: ArrayLike | None = None,
    bounds: ArrayLike | None = None,
    finite: int | None = None,
    pool: Workers | None = None,
) -> tuple[NDArray[np.float64], FilterCounts]:
    """
    Crop, voxel-downsample and remove statistical outliers from finite `points` (N, 3).

    :param points: finite points in metres, float32 or float64 (float32 is kept as it is until
        the voxel step, which returns float64 centroids).
    :param voxel_size: voxel edge in metres; each occupied voxel becomes the centroid of its
        points. 0 turns it off.
    :param outlier_neighbors: neighbours used by the statistical outlier removal; 0 turns it off
        (and it is skipped when no more points than this are left).
    :param outlier_std_ratio: points whose mean distance to their neighbours is more than this
        many standard deviations above the cloud's mean are removed.
    :param crop_min: lower corner of an axis-aligned crop box (metres); None or empty: no crop.
    :param crop_max: upper corner of the crop box; None or empty: open above.
    :param bounds: ``(2, 3)`` min and max corners of `points` when the decoder measured them
        (:class:`mvbb_ros.pipeline.decode.Decoded`): the points are then taken as already
        cropped to the crop box, and the voxel grid skips its own measuring pass.
    :param finite: with `bounds`: how many finite points the cloud had before the crop (the
        first of the counts); None: ``len(points)``.
    :param pool: workers to split the outlier removal's neighbour queries over (the same
        points with any), or None.
    :return: the filtered points (M, 3) as float64, and the counts after each step.
    """
    voxels = voxel_step(
        points,
        voxel_size=voxel_size,
        crop_min=crop_min,
        crop_max=crop_max,
        bounds=bounds,
        finite=finite,
    )
    return outlier_step(voxels, outlier_neighbors, outlier_std_ratio, pool)


@dataclass(frozen=True)
class Voxels:
    """The points after :func:`filter_points`' crop and voxel grid, and the counts so far."""

    points: NDArray[np.floating]
    finite: int
    cropped: int


def voxel_step(
    points: ArrayLike,
    *,
    voxel_size: float = 0.0,
    crop_min: ArrayLike | None = None,
    crop_max: ArrayLike | None = None,
    bounds: ArrayLike | None = None,
    finite: int | None = None,
) -> Voxels:
    """Return the first steps of :func:`filter_points` (same arguments): crop, voxel grid."""
    pts = _readonly_points(points)
    count_in = len(pts) if finite is None else int(finite)
    if bounds is None and voxel_size <= 0.0:
        pts = crop_points(pts, crop_min, crop_max)
    count_cropped = len(pts)
    if voxel_size > 0.0 and len(pts):
        if bounds is None:
            pts, members = voxel_down_sample(pts, voxel_size, crop_min=crop_min, crop_max=crop_max)
            count_cropped = int(members.sum())
        else:
            pts, _ = voxel_down_sample(pts, voxel_size, bounds=bounds)
    return Voxels(pts, count_in, count_cropped)


def outlier_step(
    voxels: Voxels,
    outlier_neighbors: int = 0,
    outlier_std_ratio: float = 2.0,
    pool: Workers | None = None,
) -> tuple[NDArray[np.float64], FilterCounts]:
    """Return :func:`filter_points`' result from its :func:`voxel_step`: the outliers removed."""
    kept = None
    if outlier_neighbors > 0 and len(voxels.points) > outlier_neighbors:
        kept = remove_statistical_outliers(
            voxels.points, int(outlier_neighbors), float(outlier_std_ratio), pool
        )
    return _filtered(voxels, kept)


def _filtered(
    voxels: Voxels, kept: NDArray[np.intp] | None
) -> tuple[NDArray[np.float64], FilterCounts]:
    """Return the `kept` voxel points (all for None) as float64, and the counts."""
    pts = voxels.points if kept is None else voxels.points[kept]
    filtered = np.ascontiguousarray(pts, dtype=np.float64)
    counts = FilterCounts(voxels.finite, voxels.cropped, len(voxels.points), len(filtered))
    return filtered, counts


class BackgroundFilter:
    """
    :func:`filter_points` begun on a helper of a pool while the calling thread does other work.

    The helper makes the voxel grid and the outlier removal's kd-tree, then takes ranges of the
    neighbour queries (:class:`~mvbb_ros.pipeline.outliers.NeighbourQueries`); :meth:`result`
    has the calling thread take the ranges left, so the two share them, and returns what
    :func:`filter_points` returns with the same settings, bounds and count, bit for bit.
    :meth:`cancel` stops the work when the points are not wanted (a table-top frame filters what
    stands on its table instead).
    """

    def __init__(
        self,
        pool: Workers,
        points: ArrayLike,
        settings: FilterSettings,
        *,
        bounds: ArrayLike | None = None,
        finite: int | None = None,
    ) -> None:
        if settings.outlier_neighbors > 0:
            check_std_ratio(settings.outlier_std_ratio)  # the caller's error, on its own thread
        self._neighbors = int(settings.outlier_neighbors)
        self._std_ratio = float(settings.outlier_std_ratio)
        self._pool = pool
        self._ready = threading.Event()
        self._queries: NeighbourQueries | None = None
        self._cancelled = False

        def voxels() -> Voxels:
            return voxel_step(
                points,
                voxel_size=settings.voxel_size,
                crop_min=settings.crop_min,
                crop_max=settings.crop_max,
                bounds=bounds,
                finite=finite,
            )

        self._task = pool.submit(lambda: self._run(voxels))

    def _run(self, make_voxels: Callable[[], Voxels]) -> Voxels:
        try:
            voxels = make_voxels()
            count = len(voxels.points)
            if 0 < self._neighbors < count and count >= MIN_SPLIT_POINTS and not self._cancelled:
                array = checked_points(voxels.points, self._neighbors)
                self._queries = split_queries(array, self._neighbors, self._pool)
        finally:
            self._ready.set()  # also after an error: result() raises it
        if self._queries is not None:
            if self._cancelled:
                self._queries.cancel()
            self._queries.take()
        return voxels

    def result(self) -> tuple[NDArray[np.float64], FilterCounts]:
        """Return :func:`filter_points`' answer, taking the query ranges no helper has taken."""
        self._task.run_if_waiting()  # no helper started it: all of it on this thread
        self._ready.wait()
        if self._queries is not None:
            self._queries.take()
        voxels = self._task.result()  # the helper's last range done (or its error raised)
        if self._queries is None:
            return outlier_step(voxels, self._neighbors, self._std_ratio)
        return _filtered(voxels, kept_points(self._queries.distances, self._std_ratio))

    def cancel(self) -> None:
        """Drop the work not yet done: its points are not wanted."""
        self._cancelled = True
        self._task.cancel()
        if self._queries is not None:
            self._queries.cancel()


def warm_up() -> None:
    """Run every kernel of this module once (see :mod:`mvbb_ros.kernels`)."""
    for dtype in (np.float32, np.float64):
        points = np.arange(12, dtype=dtype).reshape(4, 3)
        voxel_down_sample(points, 1.0, crop_min=(0, 0, 0), crop_max=(9, 9, 9))
        voxel_down_sample(points, 1.0, bounds=[column_min(points), column_max(points)])
        crop_points(points, (0, 0, 0), (5, 5, 5))
