"""
The physics trial's own figures: seconds per trial and per settle, a sanity check, CoACD's cost.

    .venv/bin/python benchmarks/physics_trial.py                 # 20 development objects
    .venv/bin/python benchmarks/physics_trial.py --objects 40 --hand wide
    .venv/bin/python benchmarks/physics_trial.py --coacd /work/shared/data --cache /tmp/parts

What runs: random objects 000.. of the development set (never the validation set), each settled
on the table by the engine (seed 0) and tried with the primitive top-down grasp across the
narrower side of its footprint (:func:`mvbb_ros.evaluation.physics.grasps.top_down_grasp`), then
with the same grasp moved 5 cm along its x axis (mostly misses). It prints how many lift, the
stages, and the median seconds per settle and per trial (wall time, this machine, single
thread). This is a sanity check of the instrument, not a tuning set: nothing is tuned on it.

``--coacd DATA`` also decomposes the shared meshes (:func:`shared_mesh_objects`) into a cache
folder (``--cache``, default a fresh temporary folder so that every mesh is decomposed): seconds
per mesh, parts, and the cache's size; then reads them again (cache hits).
"""

from __future__ import annotations

import argparse
from collections import Counter
import json
from pathlib import Path
import statistics
import sys
import tempfile
import time

from mvbb_ros.common.atomic import atomic_open
from mvbb_ros.evaluation.physics import (
    HANDS,
    random_object,
    settle,
    shared_mesh_objects,
    try_grasps,
)
from mvbb_ros.evaluation.physics.grasps import top_down_grasp
import numpy as np


def _trials(count: int, hand_name: str) -> dict:
    hand = HANDS[hand_name]
    load_seconds, settle_seconds, trial_seconds, cpu_seconds = [], [], [], []
    stages: Counter[str] = Counter()
    lifted = 0
    for index in range(count):
        started = time.perf_counter()
        obj = random_object(index)
        _ = obj.volume  # the parts' union volume (the mass), counted once per object
        load_seconds.append(time.perf_counter() - started)
        started = time.perf_counter()
        pose = settle(obj, seed=0)
        settle_seconds.append(time.perf_counter() - started)
        grasp = top_down_grasp(obj, pose, hand)
        beside = grasp.copy()
        beside[:3, 3] += 0.05 * grasp[:3, 0]
        cpu = time.process_time()
        results = try_grasps(obj, pose, np.stack([grasp, beside]), hand)
        cpu_seconds.append((time.process_time() - cpu) / len(results))
        trial_seconds.extend(result.seconds for result in results)
        stages[results[0].stage] += 1
        lifted += results[0].success
        print(
            f'{obj.name}: longest side {obj.extent.max() * 100:4.1f} cm, '
            f'{obj.mass * 1000:5.0f} g, {len(obj.parts):2d} parts: top-down {results[0].stage:9s}'
            f' ({results[0].detail}); 5 cm beside: {results[1].stage}',
            flush=True,
        )
    return {
        'objects': count,
        'hand': hand_name,
        'top_down_lifted': lifted,
        'top_down_stages': dict(stages),
        'seconds_per_object_load_median': statistics.median(load_seconds),
        'seconds_per_settle_median': statistics.median(settle_seconds),
        'seconds_per_trial_median': statistics.median(trial_seconds),
        'cpu_seconds_per_trial_median': statistics.median(cpu_seconds),
        'trials': len(trial_seconds),
    }


def _coacd(data: Path, cache: Path) -> dict:
    started = time.perf_counter()
    objects = shared_mesh_objects(data, cache)
    first = time.perf_counter() - started
    started = time.perf_counter()
    shared_mesh_objects(data, cache)
    again = time.perf_counter() - started
    size = sum(file.stat().st_size for file in cache.glob('*.npz'))
    for obj in objects:
        print(f'{obj.name}: {len(obj.parts)} parts, {obj.mass * 1000:.0f} g')
    return {
        'meshes': len(objects),
        'parts': {obj.name: len(obj.parts) for obj in objects},
        'seconds_first': first,
        'seconds_cached': again,
        'cache_files': len(list(cache.glob('*.npz'))),
        'cache_bytes': size,
    }


def main(argv: list[str] | None = None) -> int:
    """Run the figures and print them (and write them as JSON with ``--json``)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--objects', type=int, default=20, help='development objects (from 000)')
    parser.add_argument('--hand', choices=sorted(HANDS), default='franka')
    parser.add_argument('--coacd', type=Path, help='shared data folder: time CoACD on its meshes')
    parser.add_argument('--cache', type=Path, help='cache folder for --coacd (default: fresh)')
    parser.add_argument('--json', type=Path, help='write the figures here')
    args = parser.parse_args(argv)
    if not 1 <= args.objects <= 500:
        parser.error('--objects must be 1-500 (the development set)')
    figures = {'trials': _trials(args.objects, args.hand)}
    summary = figures['trials']
    print(
        f'top-down grasps that lift: {summary["top_down_lifted"]} of {summary["objects"]} '
        f'({summary["top_down_stages"]})'
    )
    print(
        f'median seconds: {summary["seconds_per_object_load_median"]:.3f} per object load, '
        f'{summary["seconds_per_settle_median"]:.3f} per settle, '
        f'{summary["seconds_per_trial_median"]:.3f} per trial ({summary["trials"]} trials; '
        f'{summary["cpu_seconds_per_trial_median"]:.3f} s of CPU per trial)'
    )
    if args.coacd is not None:
        with tempfile.TemporaryDirectory() as fresh:
            cache = args.cache if args.cache is not None else Path(fresh)
            figures['coacd'] = _coacd(args.coacd, cache)
        coacd = figures['coacd']
        print(
            f'CoACD: {coacd["meshes"]} meshes in {coacd["seconds_first"]:.1f} s '
            f'({coacd["seconds_cached"]:.2f} s from the cache), {coacd["cache_files"]} files, '
            f'{coacd["cache_bytes"] / 1e6:.2f} MB'
        )
    if args.json is not None:
        with atomic_open(args.json) as handle:
            json.dump(figures, handle, indent=2)
    return 0


if __name__ == '__main__':
    sys.exit(main())
