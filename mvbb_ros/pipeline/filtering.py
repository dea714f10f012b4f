"""
Point cloud filtering before the box fit: crop, voxel down-sampling, statistical outliers.

Each step can be turned off (:class:`~mvbb_ros.pipeline.settings.FilterSettings`, whose
defaults turn them all off; the node turns the voxel grid and the outliers on). Steps run in
that order:
cropping first makes the others cheaper, and outlier statistics are steadier on the evenly spaced
voxel centroids than on raw sensor points.

Voxel down-sampling: numpy by default, Open3D's as an option
----------------------------------------------------------------
The filters were Open3D's at first. The voxel step is now computed with numpy by default
(``voxel_backend = 'numpy'``, :func:`voxel_down_sample`) because on full depth frames it
was the most expensive step around the decomposition, and Open3D's needs a float64 copy of the
whole cloud first: on a 300k-point frame (one core, ``benchmarks/pipeline.py``) the Open3D
conversion and ``voxel_down_sample`` took about 1 + 7.5 ms, the numpy grid about 2-3 ms straight
from the decoder's float32 points. It computes the same thing as Open3D's: the grid is anchored
where Open3D anchors it (half a voxel below the cloud's minimum corner), a point falls in voxel
``floor((p - anchor) / voxel_size)`` computed in float64, and each occupied voxel becomes the
float64 mean of its points. So the centroids are Open3D's up to float rounding of the sums
(``test/test_filtering.py`` checks this); only their order differs (numpy: sorted by voxel
index; Open3D: its hash map's order). Measured effect on the 29 shared scans and the Bunny with
the default settings: 29 of 30 give the same boxes and leaf volume; ``bunny_rangescan_bun090``
gives 8 boxes (401 cm^3) instead of 6 (507 cm^3). That one is the decomposition's sensitivity to
point order, not a different filter: the same Open3D centroids give 6 or 8 boxes depending on
how they are shuffled (1 of 6 shuffles gives 8). ``voxel_backend = 'open3d'`` restores
Open3D's step.

How the voxels are grouped: when the cloud's grid has at most :data:`DENSE_GRID_FACTOR` times as
many cells as there are points (a segmented object: tens of thousands of cells), the points are
counted and summed with ``np.bincount`` on the dense grid (linear time, no sort); otherwise (a
lidar sweep spanning tens of metres) the voxel keys are sorted with ``np.unique``.

The statistical outlier removal stays Open3D's ``remove_statistical_outlier`` in both cases: it
runs on the voxel centroids (about a thousand for one object), where it costs a millisecond or
two, and scipy's KD-tree was not faster.
"""

from __future__ import annotations

from dataclasses import dataclass

from mvbb_ros.pipeline.settings import VOXEL_BACKENDS, VoxelBackend
import numpy as np
from numpy.typing import ArrayLike, NDArray
import open3d as o3d

#: The dense grid (bincount) is used when it has at most this many cells per point.
DENSE_GRID_FACTOR = 8
#: ... or at most this many cells in all, whatever the point count (a few MB of counts).
DENSE_GRID_MIN_CELLS = 1 << 18


@dataclass(frozen=True)
class FilterCounts:
    """Finite input points, then the count after each step (unchanged when a step is off)."""

    finite: int
    cropped: int
    downsampled: int
    inliers: int


def _voxel_keys(
    columns: list[NDArray[np.float64]], voxel_size: float
) -> tuple[NDArray[np.int64], int]:
    """
    Return each point's voxel as one integer key, and the number of cells of the grid.

    The grid is anchored where Open3D anchors it, half a voxel below the minimum corner, and a
    point's voxel along each axis is ``floor((p - anchor) / voxel_size)`` in float64: Open3D's
    arithmetic on the same values. The key is the row-major index in the grid (z fastest).
    """
    size = np.float64(voxel_size)
    lows = [column.min() for column in columns]
    highs = [column.max() for column in columns]
    anchors = [low - size * 0.5 for low in lows]
    # Rounding is monotonic, so the largest coordinate gives the largest index.
    shape = [int((high - anchor) / size) + 1 for high, anchor in zip(highs, anchors, strict=True)]
    cells = float(shape[0]) * float(shape[1]) * float(shape[2])
    if cells >= 2.0**62:
        raise ValueError(f'voxel_size {voxel_size} is too small for a grid of {shape} voxels')
    keys = np.zeros(len(columns[0]), dtype=np.int64)
    for column, anchor, length in zip(columns, anchors, shape, strict=True):
        ratio = column - anchor
        ratio /= size
        # (p - anchor) >= 0, so truncation is the floor.
        keys *= length
        keys += ratio.astype(np.int64)
    return keys, int(cells)


def voxel_down_sample(
    points: ArrayLike, voxel_size: float
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """
    Replace the points of each occupied voxel by their centroid (Open3D's voxel_down_sample).

    :param points: finite points (N, 3), float32 or float64.
    :param voxel_size: voxel edge in metres, > 0.
    :return: the centroids (M, 3) as float64, sorted by voxel index (x slowest, z fastest), and
        how many points each voxel holds (M,).
    :raises ValueError: for a non-positive voxel size or a grid too fine to index in 64 bits.
    """
    pts = np.asarray(points)
    if pts.dtype not in (np.float32, np.float64):
        pts = pts.astype(np.float64)
    pts = pts.reshape(-1, 3)
    if not voxel_size > 0.0:
        raise ValueError(f'voxel_size must be > 0, got {voxel_size!r}')
    if len(pts) == 0:
        return np.empty((0, 3)), np.empty(0, dtype=np.intp)
    # One contiguous float64 copy per axis: reductions and bincount weights run on these
    # (numpy's reductions along axis 0 of an (N, 3) array are several times slower).
    columns = [np.ascontiguousarray(pts[:, axis], dtype=np.float64) for axis in range(3)]
    keys, cells = _voxel_keys(columns, voxel_size)
    if cells <= max(DENSE_GRID_FACTOR * len(pts), DENSE_GRID_MIN_CELLS):
        # Dense grid: count and sum per cell, then keep the occupied cells (in key order).
        counts = np.bincount(keys, minlength=cells)
        occupied = np.flatnonzero(counts)
        counts = counts[occupied]
        centroids = np.empty((len(occupied), 3))
        for axis, column in enumerate(columns):
            sums = np.bincount(keys, weights=column, minlength=cells)
            np.divide(sums[occupied], counts, out=centroids[:, axis])
    else:
        # Sparse grid: sort the keys, then sum the runs of equal keys.
        order = np.argsort(keys, kind='stable')  # points keep their order: same sums
        sorted_keys = keys[order]
        starts = np.flatnonzero(np.diff(sorted_keys)) + 1
        starts = np.concatenate(([0], starts))
        counts = np.diff(np.append(starts, len(sorted_keys)))
        centroids = np.empty((len(starts), 3))
        for axis, column in enumerate(columns):
            sums = np.add.reduceat(column[order], starts)
            np.divide(sums, counts, out=centroids[:, axis])
    return centroids, counts.astype(np.intp, copy=False)


def filter_points(
    points: ArrayLike,
    *,
    voxel_size: float = 0.0,
    outlier_neighbors: int = 0,
    outlier_std_ratio: float = 2.0,
    crop_min: ArrayLike | None = None,
    crop_max: ArrayLike | None = None,
    voxel_backend: VoxelBackend = 'numpy',
) -> tuple[NDArray[np.float64], FilterCounts]:
    """
    Crop, voxel-downsample and remove statistical outliers from finite `points` (N, 3).

    :param points: finite points in metres, float32 or float64 (float32 is kept as it is until
        the voxel step, which returns float64 centroids).
    :param voxel_size: voxel edge in metres; each occupied voxel becomes the centroid of its
        points. 0 turns it off.
    :param outlier_neighbors: neighbours used by the statistical outlier removal; 0 turns it off.
    :param outlier_std_ratio: points whose mean distance to their neighbours is more than this
        many standard deviations above the cloud's mean are removed.
    :param crop_min: lower corner of an axis-aligned crop box (metres); None or empty: no crop.
    :param crop_max: upper corner of the crop box; given together with `crop_min`.
    :param voxel_backend: 'numpy' (:func:`voxel_down_sample`) or 'open3d' (Open3D's
        ``voxel_down_sample``); see the module docstring.
    :return: the filtered points (M, 3) as float64, and the counts after each step.
    :raises ValueError: for an unknown `voxel_backend`.
    """
    if voxel_backend not in VOXEL_BACKENDS:
        raise ValueError(f'voxel_backend must be one of {VOXEL_BACKENDS}, got {voxel_backend!r}')
    pts = np.asarray(points)
    if pts.dtype not in (np.float32, np.float64):
        pts = pts.astype(np.float64)
    pts = pts.reshape(-1, 3)
    count_in = len(pts)
    if crop_min is not None and np.size(crop_min) and crop_max is not None and np.size(crop_max):
        low = np.asarray(crop_min, dtype=np.float64)
        high = np.asarray(crop_max, dtype=np.float64)
        inside = (pts[:, 0] >= low[0]) & (pts[:, 0] <= high[0])
        inside &= (pts[:, 1] >= low[1]) & (pts[:, 1] <= high[1])
        inside &= (pts[:, 2] >= low[2]) & (pts[:, 2] <= high[2])
        pts = pts.compress(inside, axis=0)
    count_cropped = len(pts)
    cloud = None
    if voxel_size > 0.0 and len(pts):
        if voxel_backend == 'numpy':
            pts, _ = voxel_down_sample(pts, voxel_size)
        else:
            cloud = _open3d_cloud(pts).voxel_down_sample(voxel_size)
            pts = np.asarray(cloud.points)
    count_downsampled = len(pts)
    if outlier_neighbors > 0 and count_downsampled > outlier_neighbors:
        if cloud is None:
            cloud = _open3d_cloud(pts)
        _, kept = cloud.remove_statistical_outlier(
            nb_neighbors=int(outlier_neighbors), std_ratio=float(outlier_std_ratio)
        )
        pts = pts[np.asarray(kept, dtype=np.intp)]
    filtered = np.ascontiguousarray(pts, dtype=np.float64)
    counts = FilterCounts(count_in, count_cropped, count_downsampled, len(filtered))
    return filtered, counts


def _open3d_cloud(points: NDArray) -> o3d.geometry.PointCloud:
    return o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=np.float64))
    )
