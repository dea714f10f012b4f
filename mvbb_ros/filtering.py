"""
Point cloud filtering before the box fit: crop, voxel down-sampling, statistical outliers.

Each step is Open3D's and each can be turned off (see :mod:`mvbb_ros.settings`). Steps run in
that order: cropping first makes the others cheaper, and outlier statistics are steadier on the
evenly spaced voxel centroids than on raw sensor points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
import open3d as o3d


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
) -> tuple[NDArray[np.float64], FilterCounts]:
    """
    Crop, voxel-downsample and remove statistical outliers from finite `points` (N, 3).

    :param points: finite points in metres.
    :param voxel_size: voxel edge in metres; each occupied voxel becomes the centroid of its
        points. 0 turns it off.
    :param outlier_neighbors: neighbours used by the statistical outlier removal; 0 turns it off.
    :param outlier_std_ratio: points whose mean distance to their neighbours is more than this
        many standard deviations above the cloud's mean are removed.
    :param crop_min: lower corner of an axis-aligned crop box (metres); None or empty: no crop.
    :param crop_max: upper corner of the crop box; given together with `crop_min`.
    :return: the filtered points (M, 3) as float64, and the counts after each step.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    count_in = len(pts)
    if crop_min is not None and len(crop_min) and crop_max is not None and len(crop_max):
        low = np.asarray(crop_min, dtype=np.float64)
        high = np.asarray(crop_max, dtype=np.float64)
        pts = pts[np.all((pts >= low) & (pts <= high), axis=1)]
    count_cropped = len(pts)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    if voxel_size > 0.0 and len(pts):
        cloud = cloud.voxel_down_sample(voxel_size)
    count_downsampled = len(cloud.points)
    if outlier_neighbors > 0 and count_downsampled > outlier_neighbors:
        cloud, _ = cloud.remove_statistical_outlier(
            nb_neighbors=int(outlier_neighbors), std_ratio=float(outlier_std_ratio)
        )
    filtered = np.asarray(cloud.points, dtype=np.float64)
    counts = FilterCounts(count_in, count_cropped, count_downsampled, len(filtered))
    return filtered, counts
