"""
Benchmark the minimum-volume bounding box against Open3D and trimesh, in one run.

For every ``.npy`` cloud under the shared data's ``models/`` and ``scans/`` folders, and for three
generated solid clouds (a box, a sphere, an ellipsoid; 300k points each, rotated and moved off the
origin), it prints, for ours (:func:`mvbb_ros.geometry.boxfit.fit.minimum_bounding_box`), Open3D's
PCA box (``get_oriented_bounding_box``), Open3D's minimal box
(``get_minimal_oriented_bounding_box``) and ``trimesh.bounds.oriented_bounds``:

* the volume divided by the best-known volume (``mvbb_reference.json``; for generated clouds the
  smallest enclosing box of this run, marked ``*``), and whether the box encloses every point
  (tolerance 1e-9 of its size, as :meth:`mvbb_ros.geometry.box.Box.contains`);
* the median time over ``--repeats`` calls, the methods taking turns so that load on the machine
  affects them alike, each after a 5 ms rest (Open3D's point cloud is built outside the timing);
* our median time divided by each peer's.

It ends with the targets of issue 17 (volume <= 1.01 x best known on every reference cloud; every
box of ours encloses its cloud; median time <= 1.0 x Open3D 0.19's minimal box and <= 0.25 x
trimesh on every cloud of >= 1000 points) and exits with status 1 when one fails. ``--scaling``
adds a table of time against hull size (points on a sphere: every point is a hull vertex).

Usage::

    .venv/bin/python benchmarks/mvbb.py [--repeats 5] [--quick] [--scaling] [--data DIR]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
import json
from pathlib import Path
import statistics
import sys
import time

from mvbb_ros.evaluation.shared_data import shared_data_folder
from mvbb_ros.geometry.box import Box, right_handed
from mvbb_ros.geometry.boxfit.fit import minimum_bounding_box
import numpy as np
import open3d as o3d
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation
import trimesh

DEFAULT_DATA = shared_data_folder()
GENERATED_POINTS = 300_000
#: Clouds used by --quick: the paper's three models, three kinds of scans, one generated cloud.
QUICK = (
    'models/bunny_vertices.npy',
    'models/graspit_mug_vertices.npy',
    'models/homer_vertices.npy',
    'scans/bunny_rangescan_bun000.npy',
    'scans/mosd_learn33_obj1.npy',
    'scans/pcl_stereo_mug.npy',
    'generated/box',
)
METHODS = ('ours', 'o3d_pca', 'o3d_min', 'trimesh')
PEERS = METHODS[1:]
QUALITY_BOUND = 1.01
SPEED_BOUNDS = {'o3d_min': 1.0, 'trimesh': 0.25}
SPEED_MIN_POINTS = 1000
#: Seconds of rest before each timed call.
PAUSE = 0.005


@dataclass
class Result:
    """One method on one cloud: its box, whether it encloses the cloud, its median time (s)."""

    box: Box
    encloses: bool
    seconds: float


def _open3d_box(obb: o3d.geometry.OrientedBoundingBox) -> Box:
    return Box(
        center=np.asarray(obb.center),
        rotation=right_handed(np.asarray(obb.R)),
        extents=np.asarray(obb.extent),
    )


def _trimesh_box(result: tuple[np.ndarray, np.ndarray]) -> Box:
    to_origin, extents = result
    # to_origin maps world points into the box frame: local = R x + t.
    rotation = to_origin[:3, :3].T
    return Box(
        center=-rotation @ to_origin[:3, 3], rotation=right_handed(rotation), extents=extents
    )


def methods_for(points: np.ndarray) -> dict[str, tuple[Callable[[], object], Callable]]:
    """Return, per method, a call to time and a converter of its result to a Box."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    return {
        'ours': (lambda: minimum_bounding_box(points), lambda box: box),
        'o3d_pca': (cloud.get_oriented_bounding_box, _open3d_box),
        'o3d_min': (cloud.get_minimal_oriented_bounding_box, _open3d_box),
        'trimesh': (lambda: trimesh.bounds.oriented_bounds(points), _trimesh_box),
    }


def measure(points: np.ndarray, repeats: int, names: tuple[str, ...] = METHODS) -> dict:
    """Time every method on one cloud, taking turns, and check its box."""
    calls = methods_for(points)
    times: dict[str, list[float]] = {name: [] for name in names}
    outputs = {name: calls[name][0]() for name in names}  # warm-up, and the result we check
    for _ in range(repeats):
        for name in names:
            # Let worker threads that the previous call left spinning (OpenMP, BLAS) go idle.
            time.sleep(PAUSE)
            start = time.perf_counter()
            calls[name][0]()
            times[name].append(time.perf_counter() - start)
    results = {}
    for name in names:
        box = calls[name][1](outputs[name])
        results[name] = Result(
            box=box,
            encloses=bool(box.contains(points).all()),
            seconds=statistics.median(times[name]),
        )
    return results


def generated_clouds(count: int) -> dict[str, np.ndarray]:
    """Solid box, sphere and ellipsoid (metres), randomly rotated and moved off the origin."""
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    ball = directions * rng.uniform(size=(count, 1)) ** (1.0 / 3.0)
    shapes = {
        'generated/box': rng.uniform(-0.5, 0.5, size=(count, 3)) * [0.3, 0.2, 0.1],
        'generated/sphere': 0.1 * ball,
        'generated/ellipsoid': ball * [0.15, 0.1, 0.05],
    }
    clouds = {}
    for index, (name, local) in enumerate(shapes.items()):
        rotation = Rotation.random(random_state=index + 1).as_matrix()
        clouds[name] = local @ rotation.T + np.array([0.6, -0.3, 1.2])
    return clouds


def load_clouds(data: Path, quick: bool) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Read the shared clouds (float64) and their best-known volumes, add the generated ones."""
    reference = json.loads((data / 'mvbb_reference.json').read_text())
    clouds = {}
    for folder in ('models', 'scans'):
        for path in sorted((data / folder).glob('*.npy')):
            key = f'{folder}/{path.name}'
            if not quick or key in QUICK:
                clouds[key] = np.load(path).astype(np.float64)
    for name, points in generated_clouds(GENERATED_POINTS).items():
        if not quick or name in QUICK:
            clouds[name] = points
    best = {key: float(entry['volume']) for key, entry in reference.items() if key in clouds}
    return clouds, best


def _volume_cell(result: Result, best: float) -> str:
    return f'{result.box.volume / best:7.4f}{"" if result.encloses else "!"}'


def run_comparison(clouds: dict, best_known: dict, repeats: int) -> list[str]:
    """Print the comparison table; return the failed targets."""
    header = f'{"cloud":36s} {"points":>7s} {"hull":>5s}'
    for name in METHODS:
        header += f' | {name + " vol":>12s} {"ms":>8s}'
    header += ' | ' + ' '.join(f'{"/" + peer:>8s}' for peer in PEERS)
    print(header)
    print('-' * len(header))
    failures = []
    worst_quality = 0.0
    worst_speed = dict.fromkeys(SPEED_BOUNDS, 0.0)
    for key, points in clouds.items():
        results = measure(points, repeats)
        hull_size = len(ConvexHull(points).vertices)
        if key in best_known:
            best, mark = best_known[key], ' '
        else:
            best = min(r.box.volume for r in results.values() if r.encloses)
            mark = '*'
        row = f'{key + mark:36s} {len(points):7d} {hull_size:5d}'
        for name in METHODS:
            row += (
                f' | {_volume_cell(results[name], best):>12s} {1e3 * results[name].seconds:8.2f}'
            )
        ratios = {peer: results['ours'].seconds / results[peer].seconds for peer in PEERS}
        row += ' | ' + ' '.join(f'{ratios[peer]:8.3f}' for peer in PEERS)
        print(row, flush=True)
        ours = results['ours']
        if not ours.encloses:
            failures.append(f'{key}: our box does not enclose every point')
        if key in best_known:
            quality = ours.box.volume / best
            worst_quality = max(worst_quality, quality)
            if quality > QUALITY_BOUND:
                failures.append(f'{key}: volume {quality:.4f} x best known > {QUALITY_BOUND}')
        if len(points) >= SPEED_MIN_POINTS:
            for peer, bound in SPEED_BOUNDS.items():
                worst_speed[peer] = max(worst_speed[peer], ratios[peer])
                if ratios[peer] > bound:
                    failures.append(f'{key}: time {ratios[peer]:.3f} x {peer} > {bound}')
    print()
    print("'!' after a volume: that box misses points; '*': best known is this run's best box.")
    print(f'worst volume / best known (reference clouds): {worst_quality:.4f}')
    for peer, bound in SPEED_BOUNDS.items():
        print(
            f'worst time ratio vs {peer} (clouds >= {SPEED_MIN_POINTS} points): '
            f'{worst_speed[peer]:.3f} (target {bound})'
        )
    return failures


def run_scaling(repeats: int, peer_limit: float) -> None:
    """Print time against hull size, on points drawn on a unit sphere (all are hull vertices)."""
    print()
    print('Cost against hull size (points on a sphere, every point a hull vertex), median ms:')
    print(f'{"hull":>7s} {"ours":>9s} {"us/vertex":>9s} {"trimesh":>9s} {"o3d_min":>9s}')
    rng = np.random.default_rng(1)
    skip: set[str] = set()
    for count in (300, 1000, 3000, 10_000, 30_000, 100_000):
        points = rng.normal(size=(count, 3))
        points /= np.linalg.norm(points, axis=1)[:, None]
        names = tuple(name for name in ('ours', 'trimesh', 'o3d_min') if name not in skip)
        results = measure(points, repeats, names)
        cells = {name: f'{1e3 * r.seconds:9.1f}' for name, r in results.items()}
        for name, result in results.items():
            if result.seconds > peer_limit:
                skip.add(name)
        per_vertex = 1e6 * results['ours'].seconds / count
        print(
            f'{count:7d} {cells["ours"]} {per_vertex:9.2f} '
            f'{cells.get("trimesh", "skipped"):>9s} {cells.get("o3d_min", "skipped"):>9s}',
            flush=True,
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    parser.add_argument('--repeats', type=int, default=5, help='timed calls per method and cloud')
    parser.add_argument('--quick', action='store_true', help=f'only these clouds: {QUICK}')
    parser.add_argument('--scaling', action='store_true', help='add the hull-size table')
    parser.add_argument(
        '--peer-limit',
        type=float,
        default=5.0,
        help='in --scaling, stop timing a method once one call takes longer (s)',
    )
    parser.add_argument('--data', type=Path, default=DEFAULT_DATA, help='shared data folder')
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error('--repeats must be >= 1')
    if not (args.data / 'mvbb_reference.json').exists():
        print(f'shared data not found: {args.data} (use --data or MVBB_SHARED_DATA)')
        return 2
    clouds, best_known = load_clouds(args.data, args.quick)
    print(
        f'{len(clouds)} clouds, {args.repeats} timed calls each; numpy {np.__version__}, ', end=''
    )
    print(f'open3d {o3d.__version__}, trimesh {trimesh.__version__}')
    print()
    failures = run_comparison(clouds, best_known, args.repeats)
    if args.scaling:
        run_scaling(args.repeats, args.peer_limit)
    print()
    if failures:
        print(f'FAILED targets ({len(failures)}):')
        for failure in failures:
            print(f'  {failure}')
        return 1
    print('all targets met')
    return 0


if __name__ == '__main__':
    sys.exit(main())
