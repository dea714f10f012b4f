"""
The peer the speed benchmarks time beside the pipeline: Open3D's filter chain, written by hand.

A user of Open3D who filters a cloud as the node does writes ``PointCloud(Vector3dVector(
points))``, ``voxel_down_sample(voxel_size)`` and ``remove_statistical_outlier(
outlier_neighbors, outlier_std_ratio)``. ``benchmarks/pipeline.py`` and
``benchmarks/workers.py`` time it on the same clouds, in the same process, taking turns with the
pipeline: a machine's speed moves a ratio against it less than it moves a time.
"""

from __future__ import annotations

import time


def open3d_filter_chain_ms(points, filtering) -> float:
    """
    Return the wall clock (ms) of Open3D's voxel grid and statistical outlier removal.

    :param points: (N, 3) C-contiguous float64 points (the float64 copy is not timed).
    :param filtering: the pipeline's :class:`~mvbb_ros.pipeline.stage_settings.FilterSettings`
        (its voxel size and outlier removal's neighbours and ratio).
    """
    import open3d as o3d

    start = time.perf_counter()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud = cloud.voxel_down_sample(filtering.voxel_size)
    cloud.remove_statistical_outlier(
        nb_neighbors=filtering.outlier_neighbors, std_ratio=filtering.outlier_std_ratio
    )
    return (time.perf_counter() - start) * 1e3
