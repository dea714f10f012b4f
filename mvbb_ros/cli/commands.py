"""
What each `mvbb` subcommand runs on its parsed arguments, and the exit codes they return.

:mod:`mvbb_ros.cli.main` parses the command line and calls one of these (``args.handler``).
Each imports the heavy layers it needs (the pipeline and its compiled kernels, Open3D,
matplotlib, rclpy, Ray) when it runs, so `mvbb --help` stays fast and only the ROS commands
load ROS.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import signal
import sys
import threading
import time
from typing import Any

from mvbb_ros.cli.options import settings_from_args
from mvbb_ros.cli.report import print_report, result_document
from mvbb_ros.cli.stop import exit_code, STOP_SIGNALS, Stopped, StopSignals
from mvbb_ros.common.atomic import atomic_open
from mvbb_ros.common.progress import ProgressBar
from mvbb_ros.evaluation.gripper import ParallelJawGripper
from mvbb_ros.pipeline.settings import defaults, PipelineSettings
from mvbb_ros.pipeline.settings_text import format_assignment
import numpy as np
from numpy.typing import ArrayLike

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
#: The reader of stdout closed it: the shell's code for a process killed by SIGPIPE.
EXIT_BROKEN_PIPE = 128 + signal.SIGPIPE


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


def decompose_command(args: argparse.Namespace) -> int:
    """Run `mvbb decompose`: the node's pipeline on a cloud file; return the exit code."""
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


def demo_command(args: argparse.Namespace) -> int:
    """Run `mvbb demo` (with ``--offline``: one synthetic object); return the exit code."""
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


def bag_play_command(args: argparse.Namespace) -> int:
    """Run `mvbb bag play`: publish the clouds of a bag; return the exit code."""
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


def bag_process_command(args: argparse.Namespace) -> int:
    """Run `mvbb bag process`: a bag of results from a bag; return the exit code."""
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


def fleet_command(args: argparse.Namespace) -> int:
    """Run `mvbb fleet`: `bag process` over many bags on Ray; return the exit code."""
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


def evaluate_command(args: argparse.Namespace) -> int:
    """Run `mvbb evaluate`: grasp quality on a mesh; return the exit code."""
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
