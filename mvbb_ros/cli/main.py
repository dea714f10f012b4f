"""
The `mvbb` command: decompose a cloud file, the demo, the bag tools, the fleet and the evaluation.

This module holds the parser (every subcommand and its flags) and the dispatch; what each
subcommand runs is in :mod:`mvbb_ros.cli.commands`. `mvbb decompose` runs the node's per-cloud
function (:func:`~mvbb_ros.pipeline.process.process_points`) with the node's settings, so a
file gives the boxes the node publishes for the same cloud; ``--preset paper`` gives the paper's
algorithm. The settings' flags are the node's parameters (:mod:`mvbb_ros.cli.options`). Each
subcommand imports the heavy layers it needs (Open3D, matplotlib, rclpy) when it runs, so
`mvbb --help` stays fast and only the ROS commands load ROS.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import importlib.metadata
import os
from pathlib import Path
import sys

from mvbb_ros.cli.commands import (
    bag_play_command,
    bag_process_command,
    decompose_command,
    demo_command,
    evaluate_command,
    EXIT_BROKEN_PIPE,
    EXIT_FAILURE,
    fleet_command,
)
from mvbb_ros.cli.options import add_settings_options
from mvbb_ros.evaluation.gripper import DEFAULT_DEPTH_FACTOR, DEFAULT_WIDTH_FACTOR
from mvbb_ros.evaluation.spherical import DEFAULT_SPHERICAL_STEP_DEG
from mvbb_ros.evaluation.wrench import DEFAULT_CONE_EDGES, DEFAULT_FRICTION

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
    play.set_defaults(handler=bag_play_command)

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
    process.set_defaults(handler=bag_process_command)


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
    decompose.set_defaults(handler=decompose_command)

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
    demo.set_defaults(handler=demo_command)

    _add_bag_commands(commands)
    _add_fleet_command(commands)
    _add_evaluate_command(commands)
    return parser


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
    fleet.set_defaults(handler=fleet_command)


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
    evaluate.set_defaults(handler=evaluate_command)


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
