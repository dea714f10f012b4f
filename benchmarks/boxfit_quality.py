"""
Box fit quality on thousands of varied clouds, against the slow exhaustive reference.

The clouds (rotated, cropped and sub-sampled shared scans, resampled dense bunny range scans,
random partial views of the shared meshes) and the reference are those of
``test/support/boxfit_reference.py``. For every cloud it fits the box four ways, as the package
does:

* ``default``: :func:`mvbb_ros.geometry.boxfit.fit.minimum_bounding_box` with its defaults;
* ``root``: the decomposition's root fit (the defaults with ``fit.ROOT_SEARCH``);
* ``part``: the decomposition's light part fit (:func:`mvbb_ros.geometry.boxfit.fit.fit_part`,
  ``part_search: light``);
* ``full part``: the node's part fit (``fit_part(points, full=True)``, ``part_search: full``);

and prints, per fit and cloud kind, the cloud count and the worst, 99th percentile and median
of the volume divided by the reference's (below 1 means the fit beat the reference), the
clouds where a box does not enclose every point (Box.contains, 1e-9 of its size), and the
worst clouds of each fit. Exits with status 1 when a ratio is above ``--limit`` or a box leaks.

Usage::

    .venv/bin/python benchmarks/boxfit_quality.py [--count 3000] [--seed 1] [--worst 5]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import importlib.util
from pathlib import Path
import sys
import time

from mvbb_ros.evaluation.shared_data import missing, shared_data_folder
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.boxfit.fit import fit_part, minimum_bounding_box, ROOT_SEARCH
import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = shared_data_folder()

FITS: dict[str, Callable[[np.ndarray], Box]] = {
    'default': minimum_bounding_box,
    'root': lambda points: minimum_bounding_box(points, **ROOT_SEARCH),
    'part': fit_part,
    'full part': lambda points: fit_part(points, full=True),
}


def _reference_module():
    """Import ``test/support/boxfit_reference.py`` (``test`` is also the standard library's)."""
    spec = importlib.util.spec_from_file_location(
        'boxfit_reference', REPO / 'test' / 'support' / 'boxfit_reference.py'
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> int:
    """Run the comparison; return 1 when a ratio is above the limit or a box leaks."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--count', type=int, default=3000, help='clouds, kinds in turn')
    parser.add_argument('--seed', type=int, default=1, help='seed of the clouds')
    parser.add_argument('--max-points', type=int, default=40_000, help='most points of a cloud')
    parser.add_argument('--worst', type=int, default=5, help='worst clouds listed per fit')
    parser.add_argument('--limit', type=float, default=1.01, help='largest ratio accepted')
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA, help='shared data folder')
    args = parser.parse_args(argv)
    if (reason := missing(args.data)) is not None:
        sys.exit(reason)
    reference = _reference_module()
    ratios: dict[tuple[str, str], list[float]] = {}
    names: dict[tuple[str, str], list[str]] = {}
    leaks: list[str] = []
    start = time.perf_counter()
    clouds = reference.varied_clouds(args.count, args.seed, args.data, max_points=args.max_points)
    for number, cloud in enumerate(clouds):
        if number % 250 == 0:
            print(f'{number} clouds, {time.perf_counter() - start:.0f} s', file=sys.stderr)
        best = reference.reference_box(cloud.points).volume
        for fit, function in FITS.items():
            box = function(cloud.points)
            if not box.contains(cloud.points).all():
                leaks.append(f'{fit}: {cloud.name}')
            ratios.setdefault((fit, cloud.kind), []).append(box.volume / best)
            names.setdefault((fit, cloud.kind), []).append(cloud.name)
    print(f'{args.count} clouds, seed {args.seed}, {time.perf_counter() - start:.0f} s')
    print('| fit | kind | clouds | worst | 99th pct | median | best |')
    print('|---|---|---|---|---|---|---|')
    failed = False
    for fit in FITS:
        every = []
        for kind in reference.KINDS:
            values = np.array(ratios.get((fit, kind), []))
            if not len(values):
                continue
            every.append(values)
            print(
                f'| {fit} | {kind} | {len(values)} | {values.max():.4f} | '
                f'{np.percentile(values, 99):.4f} | {np.median(values):.4f} | {values.min():.4f} |'
            )
        values = np.concatenate(every)
        failed |= bool(values.max() > args.limit)
        print(
            f'| {fit} | all | {len(values)} | {values.max():.4f} | '
            f'{np.percentile(values, 99):.4f} | {np.median(values):.4f} | {values.min():.4f} |'
        )
    for fit in FITS:
        rows = [
            (ratio, name)
            for kind in reference.KINDS
            for ratio, name in zip(
                ratios.get((fit, kind), []), names.get((fit, kind), []), strict=True
            )
        ]
        rows.sort(reverse=True)
        print(
            f'worst {fit}: '
            + '; '.join(f'{name} {ratio:.4f}' for ratio, name in rows[: args.worst])
        )
    print(
        f'boxes not enclosing their cloud: {len(leaks)}' + ''.join(f'\n  {leak}' for leak in leaks)
    )
    return 1 if failed or leaks else 0


if __name__ == '__main__':
    sys.exit(main())
