"""
The `mvbb` command: decompose a cloud file, the demo, the bag tools, the fleet and the evaluation.

`mvbb decompose` runs the node's per-cloud function (:func:`~mvbb_ros.pipeline.process.
process_points`) with the node's settings, so a file gives the boxes the node publishes for the
same cloud; ``--preset paper`` gives the paper's algorithm. The settings' flags are the node's
parameters (:mod:`mvbb_ros.cli.options`). Each subcommand imports the heavy layers it needs
(Open3D, matplotlib, rclpy) when it runs, so `mvbb --help` stays fast and only the ROS commands
load ROS.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Sequence
from dataclasses import asdict
import importlib.metadata
import json
import os
from pathlib import Path
import signal
import sys
import threading
import time
from typing import Any, TYPE_CHECKING

from mvbb_ros.cli.options import add_settings_options, settings_from_args
from mvbb_ros.cli.stop import exit_code, STOP_SIGNALS, Stopped, StopSignals
from mvbb_ros.common.atomic import atomic_open
from mvbb_ros.common.progress import ProgressBar
from mvbb_ros.evaluation.gripper import (
    DEFAULT_DEPTH_FACTOR,
    DEFAULT_WIDTH_FACTOR,
    ParallelJawGripper,
)
from mvbb_ros.evaluation.spherical import DEFAULT_SPHERICAL_STEP_DEG
from mvbb_ros.evaluation.wrench import DEFAULT_CONE_EDGES, DEFAULT_FRICTION
from mvbb_ros.pipeline.settings import defaults, PipelineSettings
from mvbb_ros.pipeline.settings_text import format_assignment
import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:  # the pipeline loads numba: imported when a command runs (see below)
    from mvbb_ros.pipeline.process import PipelineResult

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
#: The reader of stdout closed it: the shell's code for a process killed by SIGPIPE.
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE
#: `mvbb bag play`'s default wait for subscribers, seconds (``bag_play.DEFAULT_WAIT_S``, which
#: this module does not import: the ROS modules load only in the commands that need them).
PLAY_WAIT_S = 30.0


def _positive_float(text: str) -> float:
    value = float(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f'must be > 0, got {text}')
    return value


def _non_negative_float(text: str) -> float:
    value = float(text)
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return value


def _add_progress_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        '--progress',
        action=argparse.BooleanOptionalAction,
        default=None,
        help='progress bar on stderr (default: only when stderr is a terminal)',
    )


def _add_bag_commands(commands: argparse._SubParsersAction) -> None:
    """Add `mvbb bag play` and `mvbb bag process`."""
    bag = commands.add_parser(
        'bag',
        help='replay bags through the decomposer, live (play) or offline (process)',
        description='Bag tools built on rosbags: they read rosbag2 bags (a directory with '
        'metadata.yaml, sqlite3 or MCAP, or a bare .db3/.mcap file) and ROS 1 .bag files.',
    )
    bag_commands = bag.add_subparsers(dest='bag_command', metavar='BAG_COMMAND')
    bag_commands.required = True

    play = bag_commands.add_parser(
        'play',
        help='publish the PointCloud2 messages of a bag on the live graph',
        description='Publish the PointCloud2 messages of a bag on their recorded topics, with '
        'the recorded timing divided by --rate, optionally with /clock for use_sim_time. Ends '
        'at the end of the bag (with --loop: at SIGINT); SIGINT exits 0.',
    )
    play.add_argument(
        'bag', type=Path, metavar='BAG', help='rosbag2 directory, .db3 or .mcap file, or .bag'
    )
    play.add_argument('--topic', help='play only this PointCloud2 topic (default: all of them)')
    play.add_argument(
        '--rate', type=_positive_float, default=1.0, help='speed factor (default 1: real time)'
    )
    play.add_argument('--loop', action='store_true', help='start again at the end, until SIGINT')
    play.add_argument(
        '--clock', action='store_true', help='also publish /clock (bag time) for use_sim_time'
    )
    play.add_argument(
        '--clock-hz',
        type=_positive_float,
        default=40.0,
        metavar='HZ',
        help='/clock rate (default 40 Hz)',
    )
    play.add_argument(
        '--wait-for-subscribers',
        type=_non_negative_float,
        default=PLAY_WAIT_S,
        metavar='SECONDS',
        help='wait until a subscriber is matched on every cloud topic before playing, so no '
        f'cloud is lost to discovery; after this long without one, play nothing and exit 1 '
        f'(default {PLAY_WAIT_S:g}; 0 plays at once, subscribed or not)',
    )
    _add_progress_option(play)
    play.set_defaults(handler=_run_bag_play)

    process = bag_commands.add_parser(
        'process',
        help="run the node's pipeline on every cloud of a bag and write a bag of the results",
        description="Run exactly the node's pipeline on every cloud of IN, offline, and write "
        'the boxes (MarkerArray), the hierarchy (MarkerArray, unless publish_tree:=false) and '
        'the grasps (PoseArray) into the rosbag2 OUT at the input timestamps, stamped with the '
        'input headers; OUT is written atomically. Prints one line per cloud and totals.',
    )
    process.add_argument('input', type=Path, metavar='IN', help='the input bag (any format)')
    process.add_argument('output', type=Path, metavar='OUT', help='the rosbag2 directory to write')
    process.add_argument(
        '--topic', help='the PointCloud2 topic (needed when IN has more than one)'
    )
    process.add_argument(
        '--with-input', action='store_true', help='also write the input clouds, on their topic'
    )
    process.add_argument(
        '--namespace',
        default='/decomposer',
        help='prefix of the output topics (default /decomposer, as the node)',
    )
    process.add_argument(
        '--storage',
        choices=('mcap', 'sqlite3'),
        default='mcap',
        help='rosbag2 storage of OUT (default mcap, as ros2 bag in Jazzy)',
    )
    process.add_argument(
        '--compress', action='store_true', help='zstd compression (MCAP chunks, sqlite3 messages)'
    )
    process.add_argument('--force', action='store_true', help='replace OUT if it exists')
    process.add_argument('--quiet', action='store_true', help='print only the totals')
    _add_progress_option(process)
    add_settings_options(process, node=True)
    process.set_defaults(handler=_run_bag_process)


def _version() -> str:
    """Return the installed package's version (setup.py's, which package.xml repeats)."""
    try:
        return importlib.metadata.version('mvbb_ros')
    except importlib.metadata.PackageNotFoundError:  # run from a source tree, not installed
        return 'unknown (not installed)'


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser of the `mvbb` command."""
    parser = argparse.ArgumentParser(
        prog='mvbb',
        description='Minimum-volume bounding box decomposition of point clouds into boxes and '
        'grasp poses (Huebner, Ruthotto and Kragic, ICRA 2008).',
    )
    parser.add_argument('--version', action='version', version=f'%(prog)s {_version()}')
    commands = parser.add_subparsers(dest='command', metavar='COMMAND')
    commands.required = True

    decompose = commands.add_parser(
        'decompose',
        help='decompose a point cloud file (.npy, .ply, .pcd) into boxes and grasps',
        description="Run the node's pipeline (filter, decompose, grasp) on a point cloud file "
        "with the node's settings; print the boxes and grasps, optionally write JSON and a "
        "picture. --preset paper runs the paper's algorithm on the raw points instead.",
    )
    decompose.add_argument('file', type=Path, help='point cloud: .npy (N x 3), .ply or .pcd')
    decompose.add_argument('--json', type=Path, help='write the boxes, tree and grasps as JSON')
    decompose.add_argument('--png', type=Path, help='write a picture (three views)')
    add_settings_options(decompose)
    decompose.set_defaults(handler=_run_decompose)

    demo = commands.add_parser(
        'demo',
        help='run the node on a replayed synthetic stream, end to end (--offline: one object)',
        description='Run the main job on data the project makes itself: write a small bag of a '
        'synthetic table-top scene seen by a moving depth camera with sensor noise, start the '
        'decomposer node, play the bag through it (mvbb bag play) and print what it publishes '
        'for each frame, then write the processed bag (mvbb bag process) and a picture. With '
        '--offline: decompose one synthetic object without ROS and write JSON and a picture.',
    )
    demo.add_argument('--out', type=Path, default=Path('out'), help='output folder (default out/)')
    demo.add_argument(
        '--offline',
        action='store_true',
        help='decompose one synthetic object without ROS (the earlier demo)',
    )
    demo.add_argument(
        '--object',
        default='mug',
        help='with --offline: synthetic object kind: mug, can or box (default mug)',
    )
    demo.add_argument(
        '--frames', type=int, default=6, help='frames in the demo bag (default 6, at 5 Hz)'
    )
    demo.add_argument(
        '--rate', type=_positive_float, default=1.0, help='playback rate (default 1)'
    )
    add_settings_options(demo, node=True)
    demo.set_defaults(handler=_run_demo)

    _add_bag_commands(commands)
    _add_fleet_command(commands)
    _add_evaluate_command(commands)
    return parser


def _format_vector(values: Iterable[float]) -> str:
    return ' '.join(f'{value:9.4f}' for value in values)


def print_report(result: PipelineResult, seconds: float, settings: PipelineSettings) -> None:
    """Print the counts, the leaf boxes (by object) and the best grasps as plain-text tables."""
    from mvbb_ros.pipeline.explain import empty_grasps_note

    grasps, counts, leaves = result.grasps, result.counts, result.leaves
    dropped = sum(len(item.decomposition.dropped_point_indices) for item in result.objects)
    print(
        f'{counts.finite} points, {counts.inliers} after filtering -> '
        f'{len(result.objects)} object(s), {len(leaves)} boxes '
        f'(t = {settings.decomposition.gain_threshold:g}, '
        f'completion {settings.view.completion}, {dropped} points dropped) '
        f'in {seconds * 1e3:.1f} ms'
    )
    for line in result.notes:
        print(f'note: {line}')
    support = result.support
    if support is not None:
        a, b, c, d = support.coefficients
        print(
            f'support plane ({"fixed" if support.fixed else "fitted"}): '
            f'{a:.4f} x {b:+.4f} y {c:+.4f} z {d:+.4f} = 0, {support.inliers} points of its fit '
            f'on it, outline of {len(support.outline)} corners'
        )
    elif result.support_note is not None:
        print(f'no support plane: {result.support_note}')
    up = 'unknown' if result.up is None else _format_vector(result.up).strip()
    print(f'up: {up} (from {result.up_source})')
    print(f'{"obj":>3} {"box":>3} {"points":>7}  {"centre":^29}  {"extents":^29}  {"volume":>11}')
    rows = zip(leaves, result.leaf_object_indices, result.leaf_observed_counts, strict=True)
    for index, (box, obj, count) in enumerate(rows):
        print(
            f'{obj:3d} {index:3d} {count:7d}  {_format_vector(box.center)}  '
            f'{_format_vector(box.extents)}  {box.volume:11.4g}'
        )
    print(f'{len(grasps)} grasp hypotheses (best first)')
    note = '' if grasps else empty_grasps_note(result, settings)
    if note:
        print(f'no grasps: {note}')
    if grasps:
        print(
            f'{"rank":>4} {"obj":>3} {"box":>3} {"face":>4}  {"position":^29}  {"width":>8} '
            f'{"score":>6}'
        )
    for rank, grasp in enumerate(grasps[:10]):
        print(
            f'{rank:4d} {grasp.object_index:3d} {grasp.box_index:3d} {grasp.face:4d}  '
            f'{_format_vector(grasp.position)}  {grasp.width:8.4f} {grasp.score:6.3f}'
        )
    if len(grasps) > 10:
        print(f'... {len(grasps) - 10} more')


def result_document(result: PipelineResult, settings: PipelineSettings) -> dict[str, Any]:
    """
    Return the JSON document of one cloud's result.

    ``objects``: per object its decomposition's own dict
    (:meth:`~mvbb_ros.geometry.decomposition.result.Decomposition.to_dict`: the tree, the leaves by
    node index, each box) with its index, observed point count, completion (and why it was
    skipped, or None) and mirror plane; ``leaves``: every leaf box in the order grasps number
    them (``box_index``), with its object, node and observed point count; then the grasps, the
    support plane (``coefficients`` (a, b, c, d) of ``a x + b y + c z + d = 0`` with (a, b, c)
    the unit normal pointing up, ``outline`` corners in the cloud frame, ``inliers``; or None
    and ``support_note`` says why), the up direction used and its source, the filter counts and
    every parameter in force.
    """
    objects = []
    leaves = []
    for item in result.objects:
        entry = item.decomposition.to_dict()
        plane = item.shape.plane
        entry.update(
            index=item.index,
            observed_points=item.shape.observed,
            completion=item.shape.method,
            completion_skipped=item.shape.skipped,
            mirror_plane=None
            if plane is None
            else {'normal': plane.normal.tolist(), 'point': plane.point.tolist()},
        )
        objects.append(entry)
        for node, count in zip(
            item.decomposition.leaf_nodes, item.leaf_observed_counts, strict=True
        ):
            leaves.append(
                {
                    'object': item.index,
                    'node': node.index,
                    'observed_points': count,
                    'box': node.box.to_dict(),
                }
            )
    return {
        'objects': objects,
        'leaves': leaves,
        'grasps': [grasp.to_dict() for grasp in result.grasps],
        'support': None
        if result.support is None
        else {
            'coefficients': list(result.support.coefficients),
            'outline': result.support.outline.tolist(),
            'inliers': result.support.inliers,
            'fixed': result.support.fixed,
        },
        'support_note': result.support_note,
        'up': None if result.up is None else list(result.up),
        'up_source': result.up_source,
        'filter_counts': asdict(result.counts),
        'parameters': settings.parameters(),
    }


def warm_kernels() -> None:
    """Warm the compiled kernels before the first cloud; one line on stderr when compiling."""
    from mvbb_ros.kernels import announce_cold_start, warm_up_logged

    announce_cold_start(lambda line: print(line, file=sys.stderr, flush=True))
    warm_up_logged(lambda line: print(line, file=sys.stderr, flush=True))


def decompose_and_report(
    points: ArrayLike,
    settings: PipelineSettings,
    *,
    json_path: Path | None,
    png_path: Path | None,
    title: str,
) -> None:
    """
    Run the node's pipeline on `points`, print the tables, write the JSON and picture if asked.

    :raises ValueError: when too few points are left after filtering (the node's warning).
    """
    # Deferred: the pipeline loads numba and its kernels, which `mvbb --help` does not need.
    from mvbb_ros.pipeline.process import process_points

    warm_kernels()
    start = time.perf_counter()
    result = process_points(points, settings)
    seconds = time.perf_counter() - start
    if not result.objects:
        raise ValueError(result.warning or 'no decomposition')
    print_report(result, seconds, settings)
    if json_path is not None:
        with atomic_open(json_path) as handle:
            json.dump(result_document(result, settings), handle, indent=2)
        print(f'wrote {json_path}')
    if png_path is not None:
        # Deferred: matplotlib, only when a picture is asked for.
        from mvbb_ros.cli.render import ground_frame, render_boxes

        observed = np.concatenate(
            [item.shape.points[: item.shape.observed] for item in result.objects]
        )
        # A scene stands on its table: the views look down onto it and from the sensor's side.
        frame: str | np.ndarray = 'box'
        if result.support is not None:
            frame = ground_frame(result.support.normal, settings.view.viewpoint, observed)
        render_boxes(
            png_path, observed, result.leaves, grasps=result.grasps, title=title, frame=frame
        )
        print(f'wrote {png_path}')


def _run_decompose(args: argparse.Namespace) -> int:
    # Deferred: cloud files are read with Open3D.
    from mvbb_ros.cli.cloud_io import load_cloud

    settings = settings_from_args(args)
    points = load_cloud(args.file)
    title = f'{args.file.name}: t = {settings.decomposition.gain_threshold:g}'
    decompose_and_report(points, settings, json_path=args.json, png_path=args.png, title=title)
    return EXIT_OK


def _run_offline_demo(args: argparse.Namespace, settings: PipelineSettings) -> int:
    # Deferred: the synthetic scenes are ray-cast with Open3D.
    from mvbb_ros.evaluation.synthetic import segmented_object_cloud

    points = segmented_object_cloud(args.object, seed=settings.decomposition.seed)
    print(f'demo: synthetic {args.object} seen by a virtual depth camera ({len(points)} points)')
    out = args.out
    decompose_and_report(
        points,
        settings,
        json_path=out / f'demo_{args.object}.json',
        png_path=out / f'demo_{args.object}.png',
        title=f'synthetic {args.object}: t = {settings.decomposition.gain_threshold:g}',
    )
    return EXIT_OK


def node_assignments(settings: PipelineSettings) -> list[str]:
    """Return ``name:=value`` for every setting that differs from the node's defaults."""
    default = defaults()
    return [
        format_assignment(name, value)
        for name, value in settings.parameters().items()
        if value != default[name]
    ]


def _run_demo(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    if args.offline:
        return _run_offline_demo(args, settings)
    # Deferred: the demo runs the ROS graph; importing it is what `mvbb demo` pays for.
    from mvbb_ros.cli.demo import run_demo

    return run_demo(
        args.out, assignments=node_assignments(settings), frames=args.frames, rate=args.rate
    )


def _bag_error(args: argparse.Namespace, error: BaseException) -> int:
    print(f'mvbb bag {args.bag_command}: error: {error}', file=sys.stderr)
    return EXIT_FAILURE


def _run_bag_play(args: argparse.Namespace) -> int:
    # Deferred, like every ROS import of the tools: only the ROS commands load rclpy.
    from mvbb_ros.ros.bag import BagError
    from mvbb_ros.ros.bag_play import play_bag

    stop = threading.Event()
    previous = {number: signal.signal(number, lambda *_: stop.set()) for number in STOP_SIGNALS}
    try:
        stats = play_bag(
            args.bag,
            topic=args.topic,
            rate=args.rate,
            loop=args.loop,
            clock=args.clock,
            clock_hz=args.clock_hz,
            wait_for_subscribers=args.wait_for_subscribers,
            stop=stop,
            progress=args.progress,
        )
    except BagError as error:
        return _bag_error(args, error)
    except KeyboardInterrupt:
        return EXIT_OK
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
    if not stats.subscribers_found:
        return EXIT_FAILURE
    loops = f' ({stats.loops} complete loops)' if args.loop else ''
    clock = f', {stats.clock_messages} /clock messages' if args.clock else ''
    ending = 'stopped' if stats.interrupted else 'done'
    skipped = (
        f'; skipped {stats.skipped} messages that do not deserialize (corrupt)'
        if stats.skipped
        else ''
    )
    print(
        f'{ending}: published {stats.published} clouds on {", ".join(stats.topics)}{clock} '
        f'in {stats.seconds:.2f} s{loops}{skipped}',
        file=sys.stderr,
    )
    return EXIT_OK


def _run_bag_process(args: argparse.Namespace) -> int:
    # Deferred, like every ROS import of the tools: only the ROS commands load rclpy.
    from mvbb_ros.ros.bag import BagError
    from mvbb_ros.ros.offline import format_row, format_totals, process_bag, TABLE_HEADER

    try:
        settings = settings_from_args(args)
    except (OSError, ValueError) as error:
        return _bag_error(args, error)
    bar = ProgressBar(None, label='processing', enabled=args.progress)
    first: list[int] = []
    stops = StopSignals()

    def start(total: int) -> None:
        stops.check()
        bar.total = total
        if not args.quiet:
            print(TABLE_HEADER, flush=True)

    def report(row: Any, cloud: Any, result: Any) -> None:
        stops.check()
        if not first:
            first.append(row.timestamp_ns)
        if not args.quiet:
            bar.close()
            print(format_row(row, first[0]), flush=True)
        bar.update(
            row.index + 1, f'last: {row.boxes} boxes in {row.milliseconds:.0f} ms', force=True
        )

    def skip(message: Any) -> None:
        stops.check()
        if not args.quiet:
            bar.close()
            print(f'skip {message.describe()}', flush=True)

    print(f'{args.input} -> {args.output}', flush=True)
    try:
        with stops:
            warm_kernels()
            summary = process_bag(
                args.input,
                args.output,
                settings=settings,
                topic=args.topic,
                with_input=args.with_input,
                namespace=args.namespace,
                storage=args.storage,
                compress=args.compress,
                force=args.force,
                on_start=start,
                on_cloud=report,
                on_skip=skip,
            )
    except BagError as error:
        bar.close()
        return _bag_error(args, error)
    except KeyboardInterrupt as interrupt:
        bar.close()
        name = interrupt.args[0] if isinstance(interrupt, Stopped) else 'SIGINT'
        print(f'mvbb bag process: interrupted ({name}); nothing written', file=sys.stderr)
        return exit_code(interrupt)
    bar.close()
    for line in format_totals(summary):
        print(line)
    if summary.storage_error:  # the processed clouds are written; a script must still notice
        print(
            f'mvbb bag process: error: {summary.storage_error.rstrip(".")}; kept the '
            f'{summary.clouds} '
            f'clouds before it in {summary.output_path}',
            file=sys.stderr,
        )
        return EXIT_FAILURE
    return EXIT_OK


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be >= 1, got {text}')
    return value


def _add_fleet_command(commands: argparse._SubParsersAction) -> None:
    """Add `mvbb fleet` (many bags through `bag process` on Ray; see mvbb_ros.fleet)."""
    fleet = commands.add_parser(
        'fleet',
        help='run `bag process` over many bags on Ray, with one per-cloud summary',
        description="Run the node's pipeline over many bags in parallel on Ray: an embedded "
        'local Ray by default, or a running cluster (--cluster ADDRESS). Each bag gives '
        'DIR/<bag>/ with the bytes a serial `mvbb bag process` writes (DIR/<setting>/<bag>/ '
        'in a sweep), and DIR/summary.parquet, summary.csv and summary.png hold one row per '
        'cloud. A re-run skips bags whose outputs are complete with the same settings.',
    )
    fleet.add_argument(
        'inputs',
        nargs='+',
        metavar='INPUT',
        help='bags (rosbag2 folder, .bag, .db3, .mcap), globs, folders or manifest files '
        '(one input per line)',
    )
    fleet.add_argument('--output', type=Path, required=True, metavar='DIR', help='output folder')
    fleet.add_argument(
        '--cluster',
        default='',
        metavar='ADDRESS',
        help='a running Ray cluster (host:port, as `ray start --head` prints); default: an '
        'embedded local Ray sized to this machine',
    )
    fleet.add_argument(
        '--workers', type=_positive_int, help='at most N workers (default: one per CPU)'
    )
    fleet.add_argument(
        '--sweep',
        action='append',
        default=[],
        metavar='NAME=V1,V2,...',
        help='run every bag under each value of a parameter (repeat for a grid); outputs go '
        'to DIR/<setting>/<bag>/ and the summary has the setting as a column',
    )
    fleet.add_argument(
        '--topic',
        action='append',
        default=[],
        help='the PointCloud2 topic, needed for bags with several; repeat it for fleets '
        'recorded with different topics (each bag uses the first it has)',
    )
    fleet.add_argument(
        '--namespace',
        default='/decomposer',
        help='prefix of the output topics (default /decomposer)',
    )
    fleet.add_argument(
        '--storage', choices=('mcap', 'sqlite3'), default='mcap', help='rosbag2 storage of outputs'
    )
    fleet.add_argument('--compress', action='store_true', help='zstd compression of outputs')
    fleet.add_argument(
        '--retries',
        type=int,
        default=3,
        help='times a task runs again after its worker process died (default 3)',
    )
    fleet.add_argument(
        '--clouds-per-range',
        type=_positive_int,
        default=300,
        metavar='N',
        help='cut bags of more clouds into time ranges of about N clouds, run in parallel '
        '(default 300)',
    )
    fleet.add_argument('--no-picture', action='store_true', help='do not draw summary.png')
    _add_progress_option(fleet)
    # --workers is the fleet's (Ray workers); a bag's pipeline threads: -p workers:=N.
    add_settings_options(fleet, node=True, without=('workers',))
    fleet.set_defaults(handler=_run_fleet)


def _run_fleet(args: argparse.Namespace) -> int:
    # Deferred: only `mvbb fleet` loads Ray (and the ROS side of the bag tools).
    from mvbb_ros.fleet.inputs import expand_inputs, InputError, sweep_settings
    from mvbb_ros.fleet.run import FleetError, run_fleet

    try:
        settings = settings_from_args(args)
        bags = expand_inputs(args.inputs)
        grid = sweep_settings(settings, args.sweep)
    except (OSError, ValueError, InputError) as error:
        print(f'mvbb fleet: error: {error}', file=sys.stderr)
        return EXIT_FAILURE
    options = {
        'topics': tuple(args.topic),
        'namespace': args.namespace,
        'storage': args.storage,
        'compress': args.compress,
    }
    print(f'{len(bags)} bags x {len(grid)} settings -> {args.output}', flush=True)
    try:
        result = run_fleet(
            bags,
            grid,
            args.output,
            options=options,
            cluster=args.cluster,
            workers=args.workers,
            retries=args.retries,
            clouds_per_range=args.clouds_per_range,
            progress=args.progress,
            picture=not args.no_picture,
            log=lambda text: print(text, flush=True),
        )
    except (FleetError, InputError) as error:
        print(f'mvbb fleet: error: {error}', file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        print(
            'mvbb fleet: interrupted; complete bags kept (a re-run resumes), nothing half-written',
            file=sys.stderr,
        )
        return 130
    reports = result.reports
    counts = {
        status: sum(1 for r in reports if r.status == status)
        for status in ('processed', 'resumed', 'failed')
    }
    retries = sum(report.retries for report in reports)
    rate = result.clouds / result.wall_seconds if result.wall_seconds > 0 else 0.0
    skipped = (
        f'; skipped {result.skipped} messages that do not deserialize (corrupt; listed in the '
        'summary)'
        if result.skipped
        else ''
    )
    print(
        f'{counts["processed"]} processed, {counts["resumed"]} resumed, {counts["failed"]} '
        f'failed; {result.clouds} clouds in {result.wall_seconds:.1f} s ({rate:.2f} clouds/s, '
        f'{result.workers} workers, {retries} retries){skipped}'
    )
    wall, cpu = result.busy_seconds
    if wall > 0:
        print(
            f'workers: {wall:.1f} s in tasks, {cpu:.1f} s of CPU ({100 * cpu / wall:.0f} %: below '
            '100 when the machines are shared or storage is slow)'
        )
    for report in result.failed:
        label = f'{report.job.label}/' if report.job.label else ''
        print(f'failed: {label}{report.job.name}: {report.error}', file=sys.stderr)
    for report in result.truncated:  # as `bag process`: the prefix is written, exit code 1
        label = f'{report.job.label}/' if report.job.label else ''
        print(
            f'truncated: {label}{report.job.name}: {report.storage_error.rstrip(".")}; kept the '
            f'{len(report.rows)} clouds before it in {report.job.output}',
            file=sys.stderr,
        )
    if result.summary is not None:
        written = [result.summary.parquet, result.summary.csv, result.summary.png]
        print('wrote ' + ', '.join(str(path) for path in written if path is not None))
    return EXIT_FAILURE if result.failed or result.truncated else EXIT_OK


def _add_evaluate_command(commands: argparse._SubParsersAction) -> None:
    """Add `mvbb evaluate` (grasp quality, paper Fig. 6; see mvbb_ros.evaluation)."""
    evaluate = commands.add_parser(
        'evaluate',
        help='score box-face grasps against spherical grasps on a mesh (paper Fig. 6)',
        description='Simulate a parallel-jaw gripper on a triangle mesh and score grasps by the '
        'Ferrari-Canny epsilon and the wrench-space volume V: the spherical baseline, the root '
        "box's 24 grasps and the hypotheses of decompositions at each threshold. Lengths are "
        'relative to the object (its diameter D), so any mesh units work.',
    )
    evaluate.add_argument('mesh', type=Path, help='triangle mesh: .ply, .off, .obj, .stl')
    evaluate.add_argument(
        '--points', type=Path, help='cloud to fit the boxes to (default: the mesh vertices)'
    )
    evaluate.add_argument(
        '--thresholds',
        '-t',
        type=float,
        nargs='*',
        default=[0.90, 0.94, 0.98],
        help='decomposition gain thresholds (default 0.90 0.94 0.98; none: root box only)',
    )
    evaluate.add_argument(
        '--spherical-step',
        type=_non_negative_float,
        default=DEFAULT_SPHERICAL_STEP_DEG,
        metavar='DEG',
        help="angular step of the spherical baseline, dividing 180 (default 10: the paper's "
        '22104 grasps; 20 is 8x faster; 0 skips it)',
    )
    evaluate.add_argument(
        '--friction',
        type=_non_negative_float,
        default=DEFAULT_FRICTION,
        help=f'Coulomb mu (default {DEFAULT_FRICTION})',
    )
    evaluate.add_argument(
        '--cone-edges',
        type=int,
        default=DEFAULT_CONE_EDGES,
        help=f'friction cone edges ({DEFAULT_CONE_EDGES})',
    )
    evaluate.add_argument(
        '--contact-radius',
        type=_non_negative_float,
        default=None,
        help='soft-contact radius in mesh units (default finger width / 4; 0: hard contacts)',
    )
    evaluate.add_argument(
        '--width-factor',
        type=_positive_float,
        default=DEFAULT_WIDTH_FACTOR,
        help=f'opening / D (default {DEFAULT_WIDTH_FACTOR})',
    )
    evaluate.add_argument(
        '--depth-factor',
        type=_positive_float,
        default=DEFAULT_DEPTH_FACTOR,
        help=f'finger depth / D (default {DEFAULT_DEPTH_FACTOR})',
    )
    evaluate.add_argument('--seed', type=int, default=0, help='random seed of the box fit')
    evaluate.add_argument('--json', type=Path, help='write the summary as JSON')
    evaluate.add_argument('--png', type=Path, help='write the (epsilon, V) scatter plot')
    evaluate.set_defaults(handler=_run_evaluate)


def _run_evaluate(args: argparse.Namespace) -> int:
    # Deferred: the evaluation loads Open3D and matplotlib, which `mvbb --help` does not need.
    from mvbb_ros.evaluation.experiment import compare_grasp_sets
    from mvbb_ros.evaluation.mesh import GraspTarget
    from mvbb_ros.evaluation.report import format_comparison, plot_quality_space

    target = GraspTarget.from_mesh(args.mesh)
    points = None
    if args.points is not None:
        from mvbb_ros.cli.cloud_io import load_cloud  # deferred: Open3D

        points = load_cloud(args.points)
    comparison = compare_grasp_sets(
        target,
        points,
        name=args.mesh.stem,
        gripper=ParallelJawGripper.for_object(
            target.diameter, width_factor=args.width_factor, depth_factor=args.depth_factor
        ),
        thresholds=args.thresholds,
        spherical_step=args.spherical_step or None,
        friction=args.friction,
        cone_edges=args.cone_edges,
        contact_radius=args.contact_radius,
        seed=args.seed,
        progress=lambda message: print(message, file=sys.stderr),
    )
    print(comparison.describe())
    print(format_comparison(comparison, markdown=False))
    if args.json is not None:
        with atomic_open(args.json) as handle:
            json.dump(comparison.to_dict(), handle, indent=2)
        print(f'wrote {args.json}')
    if args.png is not None:
        plot_quality_space(comparison, args.png)
        print(f'wrote {args.png}')
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `mvbb` command; return the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = args.handler(args)
        sys.stdout.flush()  # here, where a closed pipe is caught, not at the interpreter's exit
        return code
    except (FileNotFoundError, ValueError) as error:
        print(f'mvbb {args.command}: error: {error}', file=sys.stderr)
        return EXIT_FAILURE
    except KeyboardInterrupt:
        return EXIT_FAILURE
    except BrokenPipeError:
        # The reader went away (`mvbb decompose FILE | head`): stop quietly, as a shell tool does.
        # What is still buffered would fail again at exit, so stdout goes to /dev/null.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except OSError as error:  # a read-only or full disk, a folder not allowed: one line
        where = f' {error.filename}' if error.filename else ''
        print(f'mvbb {args.command}: error:{where}: {error.strerror or error}', file=sys.stderr)
        return EXIT_FAILURE


if __name__ == '__main__':
    sys.exit(main())
