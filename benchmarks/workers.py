"""
``process_points`` with 1 and with more workers, on every shared scan resampled to 300k points.

    .venv/bin/python benchmarks/workers.py                 # workers 1 and 2, 5 runs per scan
    .venv/bin/python benchmarks/workers.py --workers 1,2,4 --runs 9
    .venv/bin/python benchmarks/workers.py --only mosd_learn26

The clouds (issue 41's recipe): each ``scans/*.npy`` of the shared data (metres) gives 300,000
points drawn from it with replacement (``numpy.random.default_rng(3)``, a generator per scan),
plus isotropic Gaussian noise of 1.5 mm from the same generator, as float32 (what the node
decodes). The settings are the node's defaults (``PipelineSettings()``) with ``workers`` set.

Per scan, one warm-up run per worker count, then ``--runs`` rounds; each round runs every
worker count once, in turn (interleaved, so a change of the machine's load falls on all of
them alike). The time is the wall clock of ``process_points``; the stage columns are the medians
of the result's ``timings_ms`` (the stages of more than one object add up; with workers, a
stage's time may include waiting for a helper). ``same`` says whether every run of every worker
count gave the same result, bit for bit: the objects' points, every node of every
decomposition (box centre, rotation, extents, point indices, cut, gain) and every grasp
(pose, width, score, box and object). The last lines give, per worker count, the median and the
worst of the per-scan medians, and the load average before and after.

The peer: after a scan's rounds, Open3D's filter chain as a user writes it by hand with the
node's filter settings (:mod:`peers`: voxel grid, statistical outlier removal; the float64 copy
of the cloud is not timed; Open3D's own OpenMP threads, one per CPU the process may use), on the
same cloud in the same process, one warm-up run and ``--runs`` timed. ``open3d`` is its median
per scan, and the last lines give each count's median over the scans of its time over the
chain's: a machine's speed moves such a ratio less than a time. The chain runs apart from the
rounds because OpenMP's threads keep running for a while after it (timed inside the rounds, a
one-worker run that followed used about 9 ms more CPU than its calling thread, on the core a
helper needs); the next scan starts with untimed warm-up runs.

``caller CPU`` is the CPU time of the thread that called ``process_points``, ``CPU`` that of
the whole process (every thread), medians in ms. On a machine shared with other work the wall
clock of more workers says little (the helpers wait for a core); the calling thread's CPU time
does not depend on that: it is what is left on one thread, a floor under the wall clock that
a quiet machine with enough cores approaches, while ``CPU`` over the wall clock says how many
cores the run kept busy.

Threads: nothing is set for the run; ``process_points`` itself holds OpenBLAS to one thread
(:mod:`mvbb_ros.common.blas`), so the workers are the only threads that compute, as in the
node. The process keeps the CPUs it was given (``taskset`` to choose them).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import hashlib
import os
from pathlib import Path
import subprocess
import sys
import time

from mvbb_ros.evaluation.shared_data import missing, shared_data_folder

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the peer chain (peers.py)

SHARED_DATA = shared_data_folder()
#: The stage columns, in pipeline order (keys of ``PipelineResult.timings_ms``).
STAGES = ('scene', 'filter', 'objects', 'completion', 'decompose', 'grasps', 'refine')
POINTS = 300_000
NOISE_M = 0.0015
SEED = 3


def resampled(path: Path):
    """Return issue 41's cloud of one scan: 300k points drawn with replacement, 1.5 mm noise."""
    import numpy as np

    scan = np.load(path).astype(np.float64)
    rng = np.random.default_rng(SEED)
    cloud = scan[rng.integers(0, len(scan), POINTS)] + rng.normal(0.0, NOISE_M, (POINTS, 3))
    return cloud.astype(np.float32)


def fingerprint(result) -> str:
    """Return a digest of everything a result says about the objects, boxes and grasps."""
    import numpy as np

    digest = hashlib.sha256()

    def add(*values) -> None:
        for value in values:
            digest.update(np.ascontiguousarray(value).tobytes())

    add(np.asarray([len(result.objects), len(result.grasps)]))
    for item in result.objects:
        add(item.point_indices, item.shape.points)
        for node in item.decomposition.nodes:
            box = node.box
            add(box.center, box.rotation, box.extents, node.point_indices)
            digest.update(repr((node.children, node.cut, node.gain, node.stop_reason)).encode())
            if node.cut is not None:
                add(node.cut.point, node.cut.normal, np.asarray([node.cut.offset]))
    for grasp in result.grasps:
        add(grasp.position, grasp.quaternion, grasp.approach, grasp.closing)
        digest.update(
            repr(
                (grasp.width, grasp.score, grasp.box_index, grasp.object_index, grasp.depth)
            ).encode()
        )
    digest.update(repr(result.warning).encode())
    return digest.hexdigest()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--workers', default='1,2', help='worker counts to compare (1,2)')
    parser.add_argument('--runs', type=int, default=5, help='timed runs per scan and count (5)')
    parser.add_argument('--only', help='only the scans whose name contains this text')
    args = parser.parse_args()
    counts = [int(word) for word in args.workers.split(',')]
    from mvbb_ros.pipeline.process import process_points
    from mvbb_ros.pipeline.settings import PipelineSettings
    import numpy as np
    from peers import machine, open3d_filter_chain_ms

    commit = subprocess.run(
        ['git', 'log', '-1', '--format=%h %s'],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parent,
        check=False,
    ).stdout.strip()
    load_before = os.getloadavg()
    print(f'commit: {commit}')
    print(f'machine: {machine()}')
    print(
        f'CPUs {sorted(os.sched_getaffinity(0))}; numpy {np.__version__}; load average '
        + ' '.join(f'{value:.2f}' for value in load_before)
    )
    base = PipelineSettings()
    settings = {
        count: replace(base, execution=replace(base.execution, workers=count)) for count in counts
    }
    scans = sorted((SHARED_DATA / 'scans').glob('*.npy'))
    if args.only:
        scans = [path for path in scans if args.only in path.stem]
    if not scans:
        print(
            missing(SHARED_DATA / 'scans') or f'no scans in {SHARED_DATA / "scans"}',
            file=sys.stderr,
        )
        return 1
    header = ['scan', 'kept', 'boxes', 'grasps']
    for count in counts:
        header += [f'w{count} ms', f'w{count} caller CPU', f'w{count} CPU']
    header += ['open3d', 'same']
    print('\n## Per scan: medians in ms (wall clock, CPU of the calling thread, of the process)\n')
    print('| ' + ' | '.join(header) + ' |')
    print('|' + '---|' * len(header))
    totals: dict[int, list[float]] = {count: [] for count in counts}
    cpu: dict[int, list[float]] = {count: [] for count in counts}
    stage_rows: dict[int, list[list[float]]] = {count: [] for count in counts}
    chains: list[float] = []
    all_same = True
    for path in scans:
        cloud = resampled(path)
        peer_points = np.ascontiguousarray(cloud, dtype=np.float64)
        prints = set()
        times: dict[int, list[float]] = {count: [] for count in counts}
        caller: dict[int, list[float]] = {count: [] for count in counts}
        used: dict[int, list[float]] = {count: [] for count in counts}
        stages: dict[int, dict[str, list[float]]] = {
            count: {stage: [] for stage in STAGES} for count in counts
        }
        for count in counts:
            result = process_points(cloud, settings[count])
            prints.add(fingerprint(result))
        for _ in range(args.runs):
            for count in counts:
                start = time.perf_counter()
                thread_start, process_start = time.thread_time(), time.process_time()
                result = process_points(cloud, settings[count])
                times[count].append((time.perf_counter() - start) * 1e3)
                caller[count].append((time.thread_time() - thread_start) * 1e3)
                used[count].append((time.process_time() - process_start) * 1e3)
                for stage in STAGES:
                    stages[count][stage].append(result.timings_ms.get(stage, 0.0))
                prints.add(fingerprint(result))
        open3d_filter_chain_ms(peer_points, base.filtering)
        chain = [open3d_filter_chain_ms(peer_points, base.filtering) for _ in range(args.runs)]
        chains.append(float(np.median(chain)))
        same = len(prints) == 1
        all_same &= same
        cells = [
            path.stem,
            str(result.counts.inliers),
            str(len(result.leaves)),
            str(len(result.grasps)),
        ]
        for count in counts:
            median = float(np.median(times[count]))
            totals[count].append(median)
            cpu[count].append(float(np.median(caller[count])))
            cells += [
                f'**{median:.1f}**',
                f'{cpu[count][-1]:.1f}',
                f'{np.median(used[count]):.1f}',
            ]
            stage_rows[count].append([float(np.median(stages[count][stage])) for stage in STAGES])
        cells += [f'{chains[-1]:.1f}', 'yes' if same else '**NO**']
        print('| ' + ' | '.join(cells) + ' |', flush=True)
    print("\n## Stages (`timings_ms`): median over the scans of each scan's median, ms\n")
    print('| workers | ' + ' | '.join(STAGES) + ' | wall clock |')
    print('|' + '---|' * (len(STAGES) + 2))
    for count in counts:
        medians = np.median(np.asarray(stage_rows[count]), axis=0)
        cells = [f'{value:.1f}' for value in medians]
        print(f'| {count} | ' + ' | '.join(cells) + f' | {np.median(totals[count]):.1f} |')
    print()
    for count in counts:
        values = np.asarray(totals[count])
        worst = int(np.argmax(values))
        print(
            f'workers {count}: median {np.median(values):.1f} ms, worst {values[worst]:.1f} ms '
            f"({scans[worst].stem}) over {len(values)} scans; the calling thread's CPU time: "
            f'median {np.median(cpu[count]):.1f} ms, worst {np.max(cpu[count]):.1f} ms'
        )
    chain_ms = np.asarray(chains)
    print(f"Open3D's filter chain: median {np.median(chain_ms):.1f} ms over the scans")
    for count in counts:
        print(
            f"workers {count} / Open3D's chain: median ratio "
            f'{np.median(np.asarray(totals[count]) / chain_ms):.2f}'
        )
    if len(counts) > 1:
        first = np.asarray(totals[counts[0]])
        first_cpu = np.asarray(cpu[counts[0]])
        for count in counts[1:]:
            ratio = np.asarray(totals[count]) / first
            cpu_ratio = np.asarray(cpu[count]) / first_cpu
            print(
                f'workers {count} / workers {counts[0]}: median ratio {np.median(ratio):.2f} '
                f"(the calling thread's CPU time: {np.median(cpu_ratio):.2f})"
            )
    print(f'identical outputs for every worker count: {"yes" if all_same else "NO"}')
    print('load average after: ' + ' '.join(f'{value:.2f}' for value in os.getloadavg()))
    return 0 if all_same else 1


if __name__ == '__main__':
    sys.exit(main())
