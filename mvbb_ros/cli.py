"""
The `mvbb` command: offline decomposition, the demo, and (later) bag tools.

Each subcommand imports what it needs when it runs, so `mvbb --help` stays fast and the offline
commands work without a ROS graph.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import json
from pathlib import Path
import sys
import time

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2


def _add_decomposition_options(parser: argparse.ArgumentParser) -> None:
    """Add the decomposition and grasp options shared by `decompose` and `demo`."""
    group = parser.add_argument_group('decomposition (Huebner et al. 2008)')
    group.add_argument(
        '--gain-threshold',
        '-t',
        type=float,
        default=0.94,
        help='accept a split while the volume gain Theta* is below this (paper t; default 0.94)',
    )
    group.add_argument(
        '--min-points',
        type=int,
        default=None,
        help='drop boxes with fewer points as noise (default: the library default)',
    )
    group.add_argument(
        '--split-measure',
        choices=('area', 'volume'),
        default='area',
        help="split measure theta: 'area' = the paper's 2D projection (default), "
        "'volume' = product of the parts' three extents",
    )
    group.add_argument(
        '--rescore-cuts',
        type=int,
        default=0,
        help='re-score the best K cuts with real box fits (0 = the paper; default 0)',
    )
    group.add_argument('--seed', type=int, default=0, help='random seed of the box fit')
    grasp = parser.add_argument_group('grasp hypotheses')
    grasp.add_argument(
        '--gripper-max-width',
        type=float,
        default=None,
        help='maximum gripper opening, in the cloud units (default: library default, metres)',
    )
    grasp.add_argument(
        '--standoff',
        type=float,
        default=None,
        help='pre-grasp distance off the face, in the cloud units (default: library default)',
    )
    grasp.add_argument(
        '--strategy',
        choices=('largest', 'smallest', 'outermost', 'nearest'),
        default=None,
        help='grasp ranking strategy (default: library default)',
    )


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser of the `mvbb` command."""
    parser = argparse.ArgumentParser(
        prog='mvbb',
        description='Minimum-volume bounding box decomposition of point clouds into boxes and '
        'grasp poses (Huebner, Ruthotto and Kragic, ICRA 2008).',
    )
    commands = parser.add_subparsers(dest='command', metavar='COMMAND')
    commands.required = True

    decompose = commands.add_parser(
        'decompose',
        help='decompose a point cloud file (.npy, .ply, .pcd) into boxes and grasps',
        description='Decompose a point cloud file into boxes; print a table, optionally write '
        'JSON and a picture.',
    )
    decompose.add_argument('file', type=Path, help='point cloud: .npy (N x 3), .ply or .pcd')
    _add_decomposition_options(decompose)
    decompose.add_argument('--json', type=Path, help='write the boxes, tree and grasps as JSON')
    decompose.add_argument('--png', type=Path, help='write a picture (three views)')
    decompose.set_defaults(handler=_run_decompose)

    demo = commands.add_parser(
        'demo',
        help='decompose the built-in synthetic sample and write JSON and a picture',
        description='Run the main job on a sample the project makes itself: a mug ray-cast from '
        'a virtual depth camera with sensor noise.',
    )
    demo.add_argument('--out', type=Path, default=Path('out'), help='output folder (default out/)')
    demo.add_argument(
        '--object',
        default='mug',
        help='synthetic object kind: mug, can or box (default mug)',
    )
    _add_decomposition_options(demo)
    demo.set_defaults(handler=_run_demo)
    return parser


def _decomposition_kwargs(args: argparse.Namespace) -> dict:
    kwargs = {
        'gain_threshold': args.gain_threshold,
        'split_measure': args.split_measure,
        'rescore_cuts': args.rescore_cuts,
        'seed': args.seed,
    }
    if args.min_points is not None:
        kwargs['min_points'] = args.min_points
    return kwargs


def _grasp_kwargs(args: argparse.Namespace) -> dict:
    names = ('gripper_max_width', 'standoff', 'strategy')
    return {name: getattr(args, name) for name in names if getattr(args, name) is not None}


def _format_vector(values: Sequence[float]) -> str:
    return ' '.join(f'{value:9.4f}' for value in values)


def print_report(decomposition: object, grasps: Sequence, seconds: float) -> None:
    """Print the leaf boxes and the best grasps as plain-text tables."""
    leaves = decomposition.leaves
    counts = [len(indices) for indices in decomposition.leaf_point_indices]
    root_volume = decomposition.root.box.volume
    total = sum(box.volume for box in leaves)
    print(
        f'{len(decomposition.points)} points -> {len(leaves)} boxes '
        f'(t = {decomposition.settings.gain_threshold:g}, '
        f'{len(decomposition.dropped_point_indices)} points dropped) in {seconds * 1e3:.1f} ms'
    )
    ratio = total / root_volume if root_volume > 0 else float('nan')
    print(f'leaf volume / root volume = {ratio:.3f}')
    print(f'{"box":>3} {"points":>7}  {"centre":^29}  {"extents":^29}  {"volume":>11}')
    for index, (box, count) in enumerate(zip(leaves, counts, strict=True)):
        print(
            f'{index:3d} {count:7d}  {_format_vector(box.center)}  '
            f'{_format_vector(box.extents)}  {box.volume:11.4g}'
        )
    print(f'{len(grasps)} grasp hypotheses (best first)')
    if grasps:
        print(f'{"rank":>4} {"box":>3} {"face":>4}  {"position":^29}  {"width":>8} {"score":>6}')
    for rank, grasp in enumerate(grasps[:10]):
        print(
            f'{rank:4d} {grasp.box_index:3d} {grasp.face:4d}  {_format_vector(grasp.position)}  '
            f'{grasp.width:8.4f} {grasp.score:6.3f}'
        )
    if len(grasps) > 10:
        print(f'... {len(grasps) - 10} more')


def decompose_and_report(
    points: object,
    args: argparse.Namespace,
    *,
    json_path: Path | None,
    png_path: Path | None,
    title: str,
) -> None:
    """Decompose `points`, print the tables, and write the JSON and picture when asked."""
    from mvbb_ros.decomposition import decompose
    from mvbb_ros.grasps import grasp_hypotheses

    start = time.perf_counter()
    decomposition = decompose(points, **_decomposition_kwargs(args))
    grasps = grasp_hypotheses(decomposition, **_grasp_kwargs(args))
    seconds = time.perf_counter() - start
    print_report(decomposition, grasps, seconds)
    if json_path is not None:
        from mvbb_ros.atomic import atomic_open

        document = decomposition.to_dict()
        document['grasps'] = [grasp.to_dict() for grasp in grasps]
        with atomic_open(json_path) as handle:
            json.dump(document, handle, indent=2)
        print(f'wrote {json_path}')
    if png_path is not None:
        from mvbb_ros.render import render_boxes

        render_boxes(
            png_path, decomposition.points, decomposition.leaves, grasps=grasps, title=title
        )
        print(f'wrote {png_path}')


def _run_decompose(args: argparse.Namespace) -> int:
    from mvbb_ros.cloud_io import load_cloud

    points = load_cloud(args.file)
    title = f'{args.file.name}: t = {args.gain_threshold:g}'
    decompose_and_report(points, args, json_path=args.json, png_path=args.png, title=title)
    return EXIT_OK


def _run_demo(args: argparse.Namespace) -> int:
    from mvbb_ros.synthetic import segmented_object_cloud

    points = segmented_object_cloud(args.object, seed=args.seed)
    print(f'demo: synthetic {args.object} seen by a virtual depth camera ({len(points)} points)')
    out = args.out
    decompose_and_report(
        points,
        args,
        json_path=out / f'demo_{args.object}.json',
        png_path=out / f'demo_{args.object}.png',
        title=f'synthetic {args.object}: t = {args.gain_threshold:g}',
    )
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `mvbb` command; return the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except (FileNotFoundError, ValueError) as error:
        print(f'mvbb {args.command}: error: {error}', file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        return EXIT_FAILURE


if __name__ == '__main__':
    sys.exit(main())
