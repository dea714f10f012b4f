"""
Object separation (``separate_objects``) without voxels: time against the number of points.

A shared scan and two shared table-top scenes (finite points), each resampled with replacement to
50k, 100k and 200k points with 1.5 mm Gaussian noise (seed 3), are separated at a 2 cm
tolerance and at the pipeline's floor of three point spacings (at least 5 mm: thousands of
small clusters on the scenes), ``min_points`` 20. Prints the median of ``--repeats`` calls and
the object count.

Usage::

    taskset -c 1 .venv/bin/python benchmarks/separation.py [--repeats 3] [--data DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path
import statistics
import sys
import time

from mvbb_ros.evaluation.shared_data import missing, shared_data_folder
from mvbb_ros.geometry.views.objects import separate_objects
from mvbb_ros.pipeline.process import CLUSTER_SPACINGS, point_spacing
import numpy as np
import open3d as o3d

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = shared_data_folder()
SIZES = (50_000, 100_000, 200_000)
NOISE_M = 0.0015


def _clouds(data: Path) -> dict[str, np.ndarray]:
    """Return the base clouds: one scan and two scenes (finite points), metres."""
    clouds = {'pcl_kinect_laptop scan': np.load(data / 'scans' / 'pcl_kinect_laptop.npy')}
    for name in ('pcl_kinect_laptop_box_frame', 'mosd_learn33'):
        points = np.asarray(o3d.io.read_point_cloud(str(data / 'scenes' / f'{name}.pcd')).points)
        clouds[f'{name} scene'] = points[np.isfinite(points).all(axis=1)]
    return {name: points.astype(np.float64) for name, points in clouds.items()}


def main(argv: list[str] | None = None) -> int:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=3, help='timed calls per case')
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA, help='shared data folder')
    args = parser.parse_args(argv)
    if (reason := missing(args.data)) is not None:
        sys.exit(reason)
    rng = np.random.default_rng(3)
    separate_objects(np.zeros((3, 3)) + [[0, 0, 0], [0.01, 0, 0], [1, 0, 0]], 0.02, spacing=0.01)
    print('| cloud | points | tolerance (mm) | objects | median s |')
    print('|---|---|---|---|---|')
    for name, base in _clouds(args.data).items():
        for floor in (0.02, 0.005):
            for size in SIZES:
                points = base[rng.integers(0, len(base), size)]
                points = points + rng.normal(scale=NOISE_M, size=points.shape)
                spacing = point_spacing(points, 0.0)
                tolerance = max(floor, CLUSTER_SPACINGS * spacing)
                seconds = []
                for _ in range(args.repeats):
                    start = time.perf_counter()
                    groups = separate_objects(points, tolerance, spacing=spacing, min_points=20)
                    seconds.append(time.perf_counter() - start)
                print(
                    f'| {name} | {size} | {tolerance * 1e3:.1f} | {len(groups)} | '
                    f'{statistics.median(seconds):.3f} |'
                )
    return 0


if __name__ == '__main__':
    sys.exit(main())
