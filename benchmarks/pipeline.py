"""
Per-frame cost of the whole pipeline on one core, against Open3D's hand-written filter chain.

    .venv/bin/python benchmarks/pipeline.py            # every case and the scaling
    .venv/bin/python benchmarks/pipeline.py --quick    # fewer frames, for a first look

What runs, per frame, is what the node does for one cloud: :func:`mvbb_ros.pipeline.process.
process_cloud` (decode, filter, objects, completion of the hidden side, decompose, grasps and
their refinement on the points), :func:`mvbb_ros.ros.messages.output_messages` (message
building) and publishing the messages on
a real rclpy node (nobody subscribes, so this is serialization and the middleware's write). The
decomposition is split into its box fits (every call of the minimum-volume box fit, timed by
wrapping it) and the rest (the cut search of the splits). ``total`` is the wall clock of the
whole frame, not the sum of the steps; ``p99`` its 99th percentile. ``kept`` counts the points
after the filters, ``solid`` the points decomposed (the objects' observed points and the
estimate of their hidden side).

In the same loop, on the same frames, the reference chain a user would write by hand runs:
``PointCloud2(Vector3dVector(points))``, ``voxel_down_sample(voxel_size)`` and
``remove_statistical_outlier(outlier_neighbors, outlier_std_ratio)``, with the pipeline's
settings, given the already decoded float64 points (so the chain is not charged for decoding
or for the float32 -> float64 copy). ``ratio`` is our median total over the chain's median.

Frames:

- ``camera 640x480``: a 640 x 480 organized frame from the package's virtual depth camera
  (:mod:`mvbb_ros.evaluation.camera`, on a :mod:`mvbb_ros.evaluation.synthetic` scene), close
  enough that the mug fills most of the view (about 250k of the 307k pixels); pixels off the object
  are NaN, as an organized segmentation delivers them. Four noise seeds.
- ``table-top 640x480``: a raw 640 x 480 frame of a table-top scene
  (:func:`mvbb_ros.evaluation.synthetic.table_top_frame`: 1 to 4 objects on a table, a wall behind
  it and the floor, nothing segmented): the scene stage finds the table and keeps what stands
  on it. Four seeds.
- ``organized 300k``: :func:`mvbb_ros.evaluation.synthetic.organized_frame` with 300 000 object
  points (1214 x 910). Four noise seeds.
- every real scan in the shared ``scans`` folder and the Bunny's vertices, as float32 clouds;
- every cloud in the shared bags, read with :class:`mvbb_ros.ros.bag.CloudBag` and deserialized
  into rclpy messages as the node receives them.

Then the scaling: organized frames of 1k to 1M object points, median total per size, and the
exponent ``b`` of ``time ~ n**b`` fitted by least squares on log-log between 10k and 1M points.

One core: before numpy or Open3D is imported, OMP_NUM_THREADS, OPENBLAS_NUM_THREADS,
MKL_NUM_THREADS and NUMEXPR_NUM_THREADS are set to 1 and the process is pinned to one CPU
(``--core``, default 0) with ``os.sched_setaffinity``; the Open3D chain runs under the same
conditions in the same process. Medians and p99 are over all timed frames of a case
(``--repeats`` passes over its frames after one warm-up pass).
"""

from __future__ import annotations

import argparse
import gc
import os
from pathlib import Path
import random
import subprocess
import sys
import time

from mvbb_ros.evaluation.shared_data import missing, shared_data_folder

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the peer chain (peers.py)

SHARED_DATA = shared_data_folder()
THREAD_VARIABLES = (
    'OMP_NUM_THREADS',
    'OPENBLAS_NUM_THREADS',
    'MKL_NUM_THREADS',
    'NUMEXPR_NUM_THREADS',
)
STEPS = (
    'decode',
    'filter',
    'scene',
    'objects',
    'completion',
    'fit',
    'splits',
    'grasps',
    'refine',
    'messages',
    'publish',
)
SCALING_SIZES = (1_000, 3_000, 10_000, 30_000, 100_000, 300_000, 1_000_000)


def one_core(core: int) -> None:
    """Limit this process to one thread of BLAS/OpenMP and pin it to CPU `core`."""
    for name in THREAD_VARIABLES:
        os.environ[name] = '1'
    os.sched_setaffinity(0, {core})


def camera_frame(seed: int, fill: float = 2.0):
    """
    Return a 640 x 480 organized frame (H, W, 3) in which the mug fills most of the view.

    The camera looks at the mug's bounding-box centre from the distance at which the mug's
    bounding sphere radius is `fill` times the half image height.
    """
    import math

    from mvbb_ros.evaluation import camera, synthetic
    import numpy as np

    scene = synthetic.place_objects(['mug'], [synthetic.pose_matrix()])
    mesh = scene.objects[0].mesh
    center = np.asarray(mesh.get_axis_aligned_bounding_box().get_center())
    radius = float(np.max(np.linalg.norm(np.asarray(mesh.vertices) - center, axis=1)))
    half_fov = math.atan((camera.DEFAULT_HEIGHT / 2.0) / camera.DEFAULT_FOCAL)
    distance = radius / (fill * math.tan(half_fov))
    pose = camera.orbit_pose(center, distance, -60.0, 35.0)
    points, labels = camera.render_depth_cloud(scene, pose, seed=seed)
    points[labels != 0] = np.nan
    return points


def organized_cloud(grid):
    from mvbb_ros.ros.encode import create_cloud_xyz

    return create_cloud_xyz(
        grid.reshape(-1, 3), organized_shape=grid.shape[:2], frame_id='camera_optical_frame'
    )


def build_cases(quick: bool) -> list[tuple[str, list]]:
    """Return (name, [rclpy PointCloud2, ...]) for every case."""
    from mvbb_ros.evaluation.synthetic import organized_frame, table_top_frame
    from mvbb_ros.ros.bag import CloudBag
    from mvbb_ros.ros.encode import create_cloud_xyz
    import numpy as np

    seeds = range(2 if quick else 4)
    cases = [
        ('camera 640x480', [organized_cloud(camera_frame(seed)) for seed in seeds]),
        (
            'table-top 640x480',
            [organized_cloud(table_top_frame(seed, 1 + seed % 5).points) for seed in seeds],
        ),
        ('organized 300k', [organized_cloud(organized_frame(300_000, seed=s)) for s in seeds]),
    ]
    reason = missing(SHARED_DATA)
    if reason is not None:
        print(f'{reason}: the scan and bag cases are left out', file=sys.stderr)
        return cases
    scans = sorted((SHARED_DATA / 'scans').glob('*.npy'))
    scans.append(SHARED_DATA / 'models' / 'bunny_vertices.npy')
    for path in scans:
        points = np.load(path).astype(np.float32)
        cases.append((f'scan {path.stem}', [create_cloud_xyz(points, frame_id='scan')]))
    for bag_path in sorted((SHARED_DATA / 'bags').iterdir()):
        with CloudBag(bag_path) as bag:
            for topic in bag.select_topics():
                clouds = [item.message() for item in bag.clouds([topic])]
                cases.append((f'bag {bag_path.stem}{topic}', clouds))
    return cases


class Timer:
    """Accumulate the time spent in calls of a function (to split fits from the rest)."""

    def __init__(self, function) -> None:
        self.function = function
        self.seconds = 0.0

    def __call__(self, *args, **kwargs):
        """Call the function and add the time it took."""
        start = time.perf_counter()
        try:
            return self.function(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start


class Bench:
    """The node's work for one cloud, step by step, and the Open3D reference chain."""

    def __init__(self, settings) -> None:
        from mvbb_ros.geometry.decomposition import tree as decomposition
        from mvbb_ros.ros.messages import OUTPUT_TYPES
        import rclpy

        self.settings = settings
        os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        rclpy.init()
        self.node = rclpy.create_node('pipeline_benchmark')
        self.publishers = {
            suffix: self.node.create_publisher(kind, f'~/{suffix}', 5)
            for suffix, kind in OUTPUT_TYPES.items()
        }
        # The root's fit and the parts' (the lighter search) are both box fits.
        self.fit_timers = [
            Timer(decomposition.minimum_bounding_box),
            Timer(decomposition.fit_part),
        ]
        decomposition.minimum_bounding_box, decomposition.fit_part = self.fit_timers

    def close(self) -> None:
        """Destroy the node and shut rclpy down."""
        import rclpy

        self.node.destroy_node()
        rclpy.shutdown()

    def frame(self, cloud) -> tuple[dict[str, float], object]:
        """Run the node's work on one cloud; return step times (ms, with total) and result."""
        from mvbb_ros.pipeline.process import process_cloud
        from mvbb_ros.ros.messages import output_messages

        for timer in self.fit_timers:
            timer.seconds = 0.0
        start = time.perf_counter()
        result = process_cloud(cloud, self.settings)
        built = time.perf_counter()
        messages = output_messages(result, cloud.header, self.settings)
        published = time.perf_counter()
        for suffix, message in messages.items():
            self.publishers[suffix].publish(message)
        end = time.perf_counter()
        timings = result.timings_ms
        fit_ms = sum(timer.seconds for timer in self.fit_timers) * 1e3
        times = {
            'decode': timings.get('decode', 0.0),
            'filter': timings.get('filter', 0.0),
            'scene': timings.get('scene', 0.0),
            'objects': timings.get('objects', 0.0),
            'completion': timings.get('completion', 0.0),
            'fit': fit_ms,
            'splits': max(timings.get('decompose', 0.0) - fit_ms, 0.0),
            'grasps': timings.get('grasps', 0.0),
            'refine': timings.get('refine', 0.0),
            'messages': (published - built) * 1e3,
            'publish': (end - published) * 1e3,
            'total': (end - start) * 1e3,
        }
        return times, result

    def open3d_chain(self, points) -> float:
        """Time the hand-written Open3D chain on decoded float64 points (ms)."""
        from peers import open3d_filter_chain_ms

        return open3d_filter_chain_ms(points, self.settings.filtering)


def measure(bench: Bench, clouds: list, repeats: int) -> dict:
    """Time every step on `repeats` passes over `clouds` (after a warm-up pass)."""
    from mvbb_ros.pipeline.decode import read_xyz
    import numpy as np

    decoded = [np.ascontiguousarray(read_xyz(cloud), dtype=np.float64) for cloud in clouds]
    for cloud, points in zip(clouds, decoded, strict=True):
        bench.frame(cloud)
        bench.open3d_chain(points)
    gc.collect()
    gc.freeze()  # as the node does once started: full collections skip what start-up loaded
    rows: dict[str, list[float]] = {name: [] for name in (*STEPS, 'total', 'open3d')}
    result = None
    for _ in range(repeats):
        for cloud, points in zip(clouds, decoded, strict=True):
            times, result = bench.frame(cloud)
            for name, value in times.items():
                rows[name].append(value)
            rows['open3d'].append(bench.open3d_chain(points))
    stats = {name: np.asarray(values) for name, values in rows.items()}
    return {
        'points': int(np.mean([len(points) for points in decoded])),
        'filtered': result.counts.inliers,
        'solid': sum(len(item.shape.points) for item in result.objects),
        'boxes': len(result.leaves),
        'frames': len(rows['total']),
        'median': {name: float(np.median(values)) for name, values in stats.items()},
        'p99': {name: float(np.percentile(values, 99)) for name, values in stats.items()},
    }


def print_table(rows: list[tuple[str, dict]]) -> None:
    header = ['case', 'points', 'kept', 'solid', 'boxes', 'frames', *STEPS, 'total', 'p99']
    header.append('open3d')
    print('| ' + ' | '.join([*header, 'ratio']) + ' |')
    print('|' + '---|' * (len(header) + 1))
    for name, row in rows:
        median = row['median']
        cells = [
            name,
            str(row['points']),
            str(row['filtered']),
            str(row['solid']),
            str(row['boxes']),
            str(row['frames']),
            *(f'{median[step]:.2f}' for step in STEPS),
            f'**{median["total"]:.2f}**',
            f'{row["p99"]["total"]:.2f}',
            f'{median["open3d"]:.2f}',
            f'{median["total"] / median["open3d"]:.2f}',
        ]
        print('| ' + ' | '.join(cells) + ' |')


def scaling(bench: Bench, repeats: int, sizes) -> None:
    from mvbb_ros.evaluation.synthetic import organized_frame
    import numpy as np

    print('\n## Scaling with the number of object points (organized frames, ms)\n')
    print('| points | kept | boxes | decode | filter | total | p99 | open3d | ratio |')
    print('|---|---|---|---|---|---|---|---|---|')
    counts, ours, theirs = [], [], []
    for size in sizes:
        clouds = [organized_cloud(organized_frame(size, seed=seed)) for seed in range(2)]
        row = measure(bench, clouds, max(2, repeats // 2))
        median = row['median']
        counts.append(row['points'])
        ours.append(median['total'])
        theirs.append(median['open3d'])
        print(
            f'| {row["points"]} | {row["filtered"]} | {row["boxes"]} | {median["decode"]:.2f} '
            f'| {median["filter"]:.2f} | {median["total"]:.2f} | {row["p99"]["total"]:.2f} '
            f'| {median["open3d"]:.2f} | {median["total"] / median["open3d"]:.2f} |',
            flush=True,
        )
    counts, ours, theirs = np.asarray(counts), np.asarray(ours), np.asarray(theirs)
    band = (counts >= 10_000) & (counts <= 1_100_000)
    if band.sum() >= 2:
        slope = np.polyfit(np.log(counts[band]), np.log(ours[band]), 1)[0]
        reference = np.polyfit(np.log(counts[band]), np.log(theirs[band]), 1)[0]
        print(
            f'\nfitted exponent b (time ~ n**b, 10k to 1M points): pipeline {slope:.3f}, '
            f'Open3D chain {reference:.3f}'
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--core', type=int, default=0, help='CPU to pin to (default 0)')
    parser.add_argument('--repeats', type=int, default=25, help='timed passes per case (25)')
    parser.add_argument('--quick', action='store_true', help='fewer frames and passes')
    parser.add_argument('--no-scaling', action='store_true', help='skip the scaling table')
    parser.add_argument(
        '--only', help='run only the cases whose name contains this text (e.g. 300k)'
    )
    args = parser.parse_args()
    one_core(args.core)

    from mvbb_ros.pipeline.settings import PipelineSettings
    import numpy as np
    import open3d as o3d

    repeats = 4 if args.quick else args.repeats
    commit = subprocess.run(
        ['git', 'log', '-1', '--format=%h %s'],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parent,
        check=False,
    ).stdout.strip()
    from peers import machine

    print(f'commit: {commit}')
    print(f'machine: {machine()}')
    print(
        f'one core: CPU {sorted(os.sched_getaffinity(0))}, '
        + ', '.join(f'{name}={os.environ[name]}' for name in THREAD_VARIABLES)
        + f'; numpy {np.__version__}, open3d {o3d.__version__}; load average '
        + ' '.join(f'{value:.2f}' for value in os.getloadavg())
    )
    settings = PipelineSettings()
    print(
        f'settings: voxel_size {settings.filtering.voxel_size}, outlier_neighbors '
        f'{settings.filtering.outlier_neighbors}, outlier_std_ratio '
        f'{settings.filtering.outlier_std_ratio}'
    )
    bench = Bench(settings)
    try:
        cases = build_cases(args.quick)
        if args.only:
            cases = [(name, clouds) for name, clouds in cases if args.only in name]
        print('\n## Per-frame cost, medians in ms (p99 of the total; open3d = reference chain)\n')
        rows = []
        for name, clouds in cases:
            # Small clouds are cheap: give them more passes so their medians are steady too.
            passes = repeats * (1 if len(clouds) > 1 else 2)
            rows.append((name, measure(bench, clouds, passes)))
        print_table(rows)
        if not args.no_scaling:
            sizes = SCALING_SIZES[::2] + (SCALING_SIZES[-1],) if args.quick else SCALING_SIZES
            scaling(bench, repeats, sizes)
    finally:
        bench.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
