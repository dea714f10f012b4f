"""
Benchmark `mvbb fleet`: 24 bags with 1 and 2 Ray workers, and the bytes against serial runs.

The bags: the three shared bags (read in place) and 21 demo scenes (the demo's table-top scene
with other seeds, seen by its moving depth camera, written with the project's bag writer,
alternately MCAP and sqlite3) under ``OUT/bags``. Every bag first goes through `mvbb bag process`
one after another (the serial reference, timed), then `mvbb fleet` runs over all of them with
``--workers 1`` and ``--workers 2`` in turn, ``--repeats`` times, each run in a fresh output
folder; each run's outputs are compared byte for byte with the serial ones. The machine's load
(``/proc/loadavg``) is printed before and after each run: the figures mean little on a machine
busy with other work.

Throughput is clouds per second over the whole run (Ray's start and the workers' warm-up
included) and over the processing (first to last finished cloud, from the summary's ``done_s``).

Usage::

    .venv/bin/python benchmarks/fleet.py [--out out/fleet_bench] [--repeats 2] [--frames 10]
"""

from __future__ import annotations

import argparse
import filecmp
import os
from pathlib import Path
import statistics
import subprocess
import sys
import time

#: Topics of the shared bags; the demo scenes use the demo's own topic.
SHARED_TOPICS = ('/segmented_object', '/luminar_pointcloud')
SHARED_BAGS = (
    'embag_luminar_lidar_ros1.bag',
    'embag_luminar_lidar_ros2',
    'constructed_real_objects_ros2',
)
DEMO_BAGS = 21
REPO = Path(__file__).resolve().parents[1]


def _load() -> str:
    return ' '.join(Path('/proc/loadavg').read_text().split()[:3])


def make_bags(folder: Path, frames: int, shared: Path) -> list[Path]:
    """Write the demo scenes (if not there yet); return all 24 bags."""
    from mvbb_ros.cli.demo import demo_clouds, DEMO_FRAME, DEMO_TOPIC
    from mvbb_ros.ros.bag import write_cloud_bag

    bags = [shared / name for name in SHARED_BAGS if (shared / name).exists()]
    for k in range(DEMO_BAGS):
        path = folder / f'demo_scene_{k:02d}'
        if not path.exists():
            storage = 'mcap' if k % 2 == 0 else 'sqlite3'
            write_cloud_bag(
                path, DEMO_TOPIC, DEMO_FRAME, demo_clouds(frames, seed=100 + k), storage=storage
            )
        bags.append(path)
    return bags


def _topic(bag: Path) -> str:
    from mvbb_ros.cli.demo import DEMO_TOPIC
    from mvbb_ros.ros.bag import CloudBag

    with CloudBag(bag) as reader:
        present = {topic.name for topic in reader.cloud_topics()}
    return next(topic for topic in (*SHARED_TOPICS, DEMO_TOPIC) if topic in present)


def _name(bag: Path) -> str:
    return bag.stem if bag.is_file() else bag.name


def serial_reference(bags: list[Path], folder: Path) -> float:
    """Run `mvbb bag process` on every bag, one after another; return the wall seconds."""
    start = time.perf_counter()
    for bag in bags:
        target = folder / _name(bag)
        if target.exists():
            continue
        command = [sys.executable, '-m', 'mvbb_ros.cli.main', 'bag', 'process', str(bag)]
        command += [str(target), '--quiet', '--topic', _topic(bag)]
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def _identical(left: Path, right: Path) -> bool:
    names = sorted(path.name for path in left.iterdir()) if left.is_dir() else None
    if names is None or names != sorted(path.name for path in right.iterdir()):
        return False
    return all(filecmp.cmp(left / name, right / name, shallow=False) for name in names)


def fleet_run(manifest: Path, output: Path, workers: int) -> dict[str, float | str]:
    """Run `mvbb fleet` over the manifest; return its figures."""
    import pyarrow.parquet as pq
    from mvbb_ros.cli.demo import DEMO_TOPIC

    command = [sys.executable, '-m', 'mvbb_ros.cli.main', 'fleet', str(manifest)]
    command += ['--output', str(output), '--workers', str(workers), '--no-progress']
    for topic in (*SHARED_TOPICS, DEMO_TOPIC):
        command += ['--topic', topic]
    before = _load()
    start = time.perf_counter()
    text = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    wall = time.perf_counter() - start
    busy = next((line for line in text.splitlines() if line.startswith('workers: ')), '')
    rows = pq.read_table(output / 'summary.parquet').to_pylist()
    done = sorted(row['done_s'] for row in rows if row['done_s'] is not None)
    span = done[-1] - done[0] if len(done) > 1 else float('nan')
    return {
        'workers': workers,
        'wall_s': wall,
        'clouds': len(done),
        'per_s': len(done) / wall,
        'processing_per_s': (len(done) - 1) / span,
        'first_done_s': done[0],
        'load_before': before,
        'load_after': _load(),
        'failed': sum(1 for row in rows if row['status'] == 'failed'),
        'cpu_share': busy.split('(')[1].split(':')[0] if '(' in busy else '?',
    }


def main() -> int:
    """Make the bags, run the serial reference and the fleet runs, print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', type=Path, default=REPO / 'out' / 'fleet_bench')
    parser.add_argument('--repeats', type=int, default=2)
    parser.add_argument(
        '--first-repeat', type=int, default=0, help='number of the first repeat (to add runs)'
    )
    parser.add_argument('--frames', type=int, default=10, help='clouds per demo scene')
    parser.add_argument('--shared', type=Path, default=Path('/work/shared/data/bags'))
    args = parser.parse_args()
    os.environ.setdefault('RAY_USAGE_STATS_ENABLED', '0')
    (args.out / 'bags').mkdir(parents=True, exist_ok=True)
    bags = make_bags(args.out / 'bags', args.frames, args.shared)
    manifest = args.out / 'bags.txt'
    manifest.write_text(''.join(f'{bag}\n' for bag in bags))
    print(f'{len(bags)} bags; load {_load()}', flush=True)
    header = '| workers | wall s | clouds | clouds/s | processing clouds/s | first cloud s '
    header += "| load before | load after | identical | failed | workers' CPU share |"
    serial_s = serial_reference(bags, args.out / 'serial')
    print(
        f'serial bag process (bags not done before): {serial_s:.1f} s; load {_load()}',
        flush=True,
    )
    print(header, flush=True)
    runs = []
    for repeat in range(args.first_repeat, args.first_repeat + args.repeats):
        for workers in (1, 2):
            output = args.out / f'run{repeat}_w{workers}'
            if output.exists():
                subprocess.run(['rm', '-rf', str(output)], check=True)
            figures = fleet_run(manifest, output, workers)
            same = sum(
                _identical(output / _name(bag), args.out / 'serial' / _name(bag)) for bag in bags
            )
            figures['identical'] = f'{same}/{len(bags)}'
            runs.append(figures)
            row = (
                '| {workers} | {wall_s:.1f} | {clouds} | {per_s:.2f} | {processing_per_s:.2f} '
                '| {first_done_s:.1f} | {load_before} | {load_after} | {identical} | {failed} '
                '| {cpu_share} |'
            )
            print(row.format(**figures), flush=True)
    for key in ('per_s', 'processing_per_s'):
        one = statistics.median(run[key] for run in runs if run['workers'] == 1)
        two = statistics.median(run[key] for run in runs if run['workers'] == 2)
        print(f'{key}: median 1 worker {one:.2f}, 2 workers {two:.2f}: {two / one:.2f} x')
    return 0


if __name__ == '__main__':
    sys.exit(main())
