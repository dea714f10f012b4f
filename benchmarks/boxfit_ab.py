r"""
Time this tree's box fits against an older copy of the box fit package, in one process.

The older package is a copy of ``mvbb_ros/geometry/boxfit`` from another commit, renamed
``oldboxfit`` (its imports rewritten), under ``--old DIR``::

    mkdir -p /tmp/old && git archive f32f56c mvbb_ros/geometry/boxfit | tar -x -C /tmp/old
    mv /tmp/old/mvbb_ros/geometry/boxfit /tmp/old/oldboxfit
    sed -i 's/mvbb_ros\.geometry\.boxfit/oldboxfit/g' /tmp/old/oldboxfit/*.py
    taskset -c 1 .venv/bin/python benchmarks/boxfit_ab.py --old /tmp/old --rounds 5

Each round times, old and new taking turns (the order swapped every round), the default fit
(``minimum_bounding_box``) of every shared model and scan cloud and of ``benchmarks/mvbb.py``'s
three generated 300k-point solids, ``decompose`` at t = 0.94 of
every scan (the decomposition's fits switched between the two packages) and the Bunny's vertices
at t = 0.98 (median of 5). It prints the medians over rounds and the paper's Table I box counts
with each package.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
from pathlib import Path
import statistics
import sys
import time
from typing import Any

from mvbb_ros.evaluation.shared_data import missing, shared_data_folder
from mvbb_ros.geometry.boxfit import fit as new_fit
from mvbb_ros.geometry.decomposition import tree
import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = shared_data_folder()
WORKLOADS = ('default fits', 'decompose scans', 'bunny 0.98')


def main(argv: list[str] | None = None) -> int:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--old', type=Path, required=True, help='folder holding oldboxfit/')
    parser.add_argument('--rounds', type=int, default=5, help='rounds, old and new in turn')
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA, help='shared data folder')
    args = parser.parse_args(argv)
    if (reason := missing(args.data)) is not None:
        sys.exit(reason)
    sys.path.insert(0, str(args.old))
    old_fit = importlib.import_module('oldboxfit.fit')
    paths = sorted(args.data.glob('models/*.npy')) + sorted(args.data.glob('scans/*.npy'))
    clouds = {f'{p.parent.name}/{p.stem}': np.load(p).astype(np.float64) for p in paths}
    # benchmarks/mvbb.py's three 300k-point solids: the grid coreset's clouds.
    spec = importlib.util.spec_from_file_location('mvbb_bench', REPO / 'benchmarks' / 'mvbb.py')
    assert spec is not None and spec.loader is not None
    mvbb_bench = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mvbb_bench
    spec.loader.exec_module(mvbb_bench)
    clouds.update(mvbb_bench.generated_clouds(mvbb_bench.GENERATED_POINTS))
    scans = [points for name, points in clouds.items() if name.startswith('scans/')]
    models = {name: points for name, points in clouds.items() if name.startswith('models/')}
    bunny = clouds['models/bunny_vertices']

    def old_part(points: Any, *, seed: int = 0, full: bool = False) -> Any:
        # An older package has one part search: the light one (decompose()'s default).
        return old_fit.fit_part(points, seed=seed)

    fits = {
        'old': (old_part, old_fit.minimum_bounding_box),
        'new': (new_fit.fit_part, new_fit.minimum_bounding_box),
    }

    def use(name: str) -> None:
        tree.fit_part, tree.minimum_bounding_box = fits[name]  # type: ignore[assignment]

    times: dict[tuple[str, str], list[float]] = {(n, w): [] for n in fits for w in WORKLOADS}
    for name in fits:  # compile and warm
        use(name)
        tree.decompose(bunny, gain_threshold=0.98)
    for number in range(args.rounds):
        for name in ('old', 'new') if number % 2 == 0 else ('new', 'old'):
            use(name)
            start = time.perf_counter()
            for points in clouds.values():
                fits[name][1](points)
            times[(name, 'default fits')].append(time.perf_counter() - start)
            start = time.perf_counter()
            for points in scans:
                tree.decompose(points, gain_threshold=0.94)
            times[(name, 'decompose scans')].append(time.perf_counter() - start)
            bunny_times = []
            for _ in range(5):
                start = time.perf_counter()
                tree.decompose(bunny, gain_threshold=0.98)
                bunny_times.append(time.perf_counter() - start)
            times[(name, 'bunny 0.98')].append(statistics.median(bunny_times))
    print(f'{args.rounds} rounds; {len(clouds)} clouds fitted, {len(scans)} scans decomposed')
    print('| workload | old ms | new ms | new / old |')
    print('|---|---|---|---|')
    for workload in WORKLOADS:
        old = statistics.median(times[('old', workload)])
        new = statistics.median(times[('new', workload)])
        print(f'| {workload} | {old * 1e3:.1f} | {new * 1e3:.1f} | {new / old:.3f} |')
    for name in fits:
        use(name)
        counts = [
            len(tree.decompose(models[f'models/{model}_vertices'], gain_threshold=t).leaves)
            for model in ('bunny', 'graspit_mug', 'homer')
            for t in (0.90, 0.94, 0.98)
        ]
        print(f'Table I counts, {name} (Bunny, Mug, Homer at t = 0.90/0.94/0.98): {counts}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
