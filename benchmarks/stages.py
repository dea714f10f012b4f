"""
Every stage's time, and what the pipeline decided, on table-top frames and resampled scans.

    taskset -c 0 .venv/bin/python benchmarks/stages.py --save /tmp/new.json
    cd ../main && taskset -c 0 .venv/bin/python ../new/benchmarks/stages.py --save /tmp/old.json
    .venv/bin/python benchmarks/stages.py --compare /tmp/old.json /tmp/new.json --stage scene

It measures the package it imports (run it from a checkout's root: the current directory comes
first on the path), so two checkouts can be measured by one copy of this script, one after the
other (alternate them, and pin both to one core: ``taskset -c 0``). The clouds: the raw
640 x 480 frames of ``table_top_frame(seed, 1 + seed % 5)`` for ``--seeds`` (made into a
PointCloud2, through ``process_cloud``), and every shared scan resampled as issue 41 did
(``benchmarks/workers.py``: 300k points, 1.5 mm noise, seed 3; through ``process_points``).
The settings are the node's defaults with one worker. Per cloud, one warm-up run, then
``--runs`` runs; each stage's time is the median of the result's ``timings_ms[stage]``, and
``total`` the whole call's.

Besides the times it keeps what each cloud's run decided: the support plane's coefficients
and outline, the reason when there is none, the warning, and a digest of the objects, boxes
and grasps (``workers.fingerprint``). ``--compare`` prints each cloud's time ratio of one
``--stage`` (second over first), whether all of that is the same bit for bit, and the median
ratio of the frames and of the scans.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import statistics
import sys

sys.path.insert(0, os.getcwd())


def measure(seeds: list[int], runs: int, scans: bool) -> dict[str, dict]:
    """Return, per cloud, every stage's times (ms) and what the pipeline decided."""
    from dataclasses import replace

    from mvbb_ros.evaluation.shared_data import missing
    from mvbb_ros.evaluation.synthetic import table_top_frame
    from mvbb_ros.pipeline.process import process_cloud, process_points
    from mvbb_ros.pipeline.settings import PipelineSettings
    from mvbb_ros.ros.encode import create_cloud_xyz
    import numpy as np
    import time
    from workers import fingerprint, resampled, SHARED_DATA

    base = PipelineSettings()
    settings = replace(base, execution=replace(base.execution, workers=1))
    clouds = []
    for seed in seeds:
        grid = table_top_frame(seed, 1 + seed % 5).points
        cloud = create_cloud_xyz(
            grid.reshape(-1, 3), organized_shape=grid.shape[:2], frame_id='cam'
        )
        clouds.append((f'frame {seed}', lambda c=cloud: process_cloud(c, settings)))
    if scans:
        if (reason := missing(SHARED_DATA / 'scans')) is not None:
            print(f'{reason}: the scans are left out', file=sys.stderr)
        for path in sorted((SHARED_DATA / 'scans').glob('*.npy')):
            points = resampled(path)
            clouds.append((path.stem, lambda p=points: process_points(p, settings)))
    found = {}
    for name, run in clouds:
        result = run()
        times: dict[str, list[float]] = {}
        for _ in range(runs):
            start = time.perf_counter()
            result = run()
            total = (time.perf_counter() - start) * 1e3
            for stage, value in {**result.timings_ms, 'total': total}.items():
                times.setdefault(stage, []).append(value)
        support = result.support
        found[name] = {
            'times': times,
            'coefficients': None if support is None else list(support.coefficients),
            'outline': None if support is None else np.asarray(support.outline).tolist(),
            'reason': result.support_note,
            'warning': result.warning,
            'digest': fingerprint(result),
        }
    return found


def compare(first: dict[str, dict], second: dict[str, dict], stage: str) -> None:
    """Print each cloud's time ratio of `stage`, second over first, and whether outcomes agree."""
    ratios: dict[str, list[float]] = {'frames': [], 'scans': []}
    for name, mine in first.items():
        other = second[name]
        ratio = statistics.median(other['times'][stage]) / statistics.median(mine['times'][stage])
        ratios['frames' if name.startswith('frame') else 'scans'].append(ratio)
        differ = [key for key in mine if key != 'times' and mine[key] != other[key]]
        print(
            f'{name:28s} {ratio:.2f}  ' + ('same' if not differ else 'differ: ' + ' '.join(differ))
        )
    for kind, values in ratios.items():
        if values:
            print(f'{kind}: median ratio {statistics.median(values):.3f} ({len(values)} clouds)')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', default='0,1,2,3', help='table-top frame seeds (0,1,2,3)')
    parser.add_argument('--runs', type=int, default=7, help='timed runs per cloud (7)')
    parser.add_argument('--no-scans', action='store_true', help='only the table-top frames')
    parser.add_argument('--save', type=Path, help='write the times and outcomes here (JSON)')
    parser.add_argument('--compare', nargs=2, type=Path, help='compare two saved runs')
    parser.add_argument('--stage', default='scene', help='the stage compared (scene), or total')
    args = parser.parse_args()
    if args.compare:
        first, second = (json.loads(path.read_text()) for path in args.compare)
        compare(first, second, args.stage)
        return 0
    seeds = [int(word) for word in args.seeds.split(',') if word]
    found = measure(seeds, args.runs, not args.no_scans)
    for name, item in found.items():
        medians = ' '.join(
            f'{stage} {statistics.median(values):.2f}' for stage, values in item['times'].items()
        )
        print(f'{name:28s} {medians} (ms)')
    if args.save:
        args.save.write_text(json.dumps(found))
    return 0


if __name__ == '__main__':
    sys.exit(main())
