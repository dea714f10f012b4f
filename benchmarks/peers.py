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


#: The CPU features that change how fast the compiled kernels run (their vector lanes).
VECTOR_FEATURES = ('avx512f', 'avx2', 'fma')


def machine(cpuinfo: str = '/proc/cpuinfo') -> str:
    """
    Return the CPU's model, its vector features and clock, for a benchmark's header.

    A machine can change under the same name between sessions (on 2026-12-08 an EPYC without
    AVX-512 took 1.4-1.6 x as long as the day before): every timing says which it was.
    ``unknown CPU`` where the file cannot be read (not Linux).
    """
    try:
        with open(cpuinfo, encoding='utf-8', errors='replace') as stream:
            text = stream.read()
    except OSError:
        return 'unknown CPU'
    fields: dict[str, str] = {}
    for line in text.splitlines():
        name, _, value = line.partition(':')
        fields.setdefault(name.strip(), value.strip())
    flags = set(fields.get('flags', '').split())
    features = [name for name in VECTOR_FEATURES if name in flags]
    missing = [name for name in VECTOR_FEATURES if name not in flags]
    parts = [fields.get('model name', 'unknown CPU')]
    if features:
        parts.append(' '.join(features))
    if flags and missing:
        parts.append('no ' + ' '.join(missing))
    if 'cpu MHz' in fields:
        parts.append(f'{float(fields["cpu MHz"]) / 1000.0:.2f} GHz')
    return ', '.join(parts)
