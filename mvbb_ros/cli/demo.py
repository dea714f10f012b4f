"""
`mvbb demo`: the decomposer node on a replayed stream, end to end, on the project's own data.

1. Write a small bag: a synthetic table-top scene
   (:func:`~mvbb_ros.evaluation.synthetic.make_scene`) seen by a depth camera moving on an arc
   around it, with sensor noise (:func:`~mvbb_ros.evaluation.synthetic.scene_views`); each frame is
   the camera's raw view (table, objects, the wall behind the table and the floor; nothing
   segmented) as one PointCloud2 at 5 Hz. The node finds the table, and up from it, itself
   (``support_plane: auto``).
2. Start the node (the ``decomposer`` executable, ``-r cloud_in:=/demo/camera/points``,
   ``input_depth:=50`` so that no frame is skipped: the input is reliable, as the player)
   as a subprocess.
3. Play the bag through it with ``mvbb bag play`` (a subprocess) while a listener subscribed to
   ``/decomposer/boxes`` and ``/decomposer/grasps`` prints what the node published per frame.
4. Process the same bag offline (the code of ``mvbb bag process``), print its table, and check
   that every live message equals the offline one.
5. Draw the last frame with its boxes and grasps (:func:`~mvbb_ros.cli.render.render_boxes`).

What needs rclpy (the listener, the bag writer, the live/offline comparison) is in
:mod:`mvbb_ros.ros.demo_graph` and :mod:`mvbb_ros.ros.bag`, imported when the demo runs.

The demo talks on its own graph: a random ``ROS_DOMAIN_ID`` and
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the user set them. It ends by itself, and
stops its subprocesses on any exit (error, SIGINT, SIGTERM).
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping, Sequence
import contextlib
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import time
from typing import Any, TYPE_CHECKING

from mvbb_ros.arrays import Float32Array
from mvbb_ros.cli.render import Panel, render_panels
from mvbb_ros.evaluation.synthetic import make_room_meshes, make_scene, Scene, scene_views
from mvbb_ros.pipeline.decode import read_xyz
from mvbb_ros.pipeline.settings import PipelineSettings, settings_from_mapping
from mvbb_ros.pipeline.settings_text import parse_assignments
import numpy as np

if TYPE_CHECKING:  # the ROS side is imported when the demo runs (see run_demo)
    from mvbb_ros.ros.demo_graph import DemoListener, OfflineFrame

#: The demo bag's cloud topic and frame.
DEMO_TOPIC = '/demo/camera/points'
DEMO_FRAME = 'demo_camera_optical_frame'
#: Objects of the demo scene, and the seed of their placement.
DEMO_KINDS = ('mug', 'can', 'box')
DEMO_SEED = 3
#: Views of the demo picture (the cloud is in the camera's optical frame): the camera's own,
#: and from above the camera looking down its y axis.
DRAW_VIEWS = ('camera', 'front')
#: Distance of the demo camera from the middle of the table, metres.
DEMO_DISTANCE = 0.9
#: Time between frames in the demo bag, seconds (5 Hz), and the first stamp.
FRAME_PERIOD_NS = 200_000_000
FIRST_STAMP_NS = 1_700_000_000 * 1_000_000_000
#: Seconds to wait for the node to start, and for its last answers after the playback.
NODE_START_TIMEOUT_S = 40.0
ANSWER_TIMEOUT_S = 30.0


class DemoError(Exception):
    """The demo could not complete; the message says which step failed."""


#: While a child process is being started and registered, an interrupt is held back (and
#: raised right after): otherwise it could land after the fork but before the child is known,
#: and that child would outlive the demo.
_deferred_interrupt: dict[str, Any] = {'inside': False, 'signal': None}


def _interrupt(signum: int, frame: Any) -> None:
    if _deferred_interrupt['inside']:
        _deferred_interrupt['signal'] = signum
        return
    raise KeyboardInterrupt(f'signal {signum}')


@contextlib.contextmanager
def _interrupts_deferred() -> Iterator[None]:
    """Hold back SIGINT/SIGTERM/SIGHUP for the block; raise KeyboardInterrupt after it."""
    _deferred_interrupt['inside'] = True
    try:
        yield
    finally:
        _deferred_interrupt['inside'] = False
        pending, _deferred_interrupt['signal'] = _deferred_interrupt['signal'], None
        if pending is not None:
            raise KeyboardInterrupt(f'signal {pending}')


def demo_environment(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """
    Give the demo its own graph: a random ROS_DOMAIN_ID and localhost-only discovery.

    Values the user set are kept. `environ` (default ``os.environ``) is updated in place.

    :return: the two values in force.
    """
    target = os.environ if environ is None else environ
    target.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
    target.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return {name: target[name] for name in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')}


def demo_scene(seed: int = DEMO_SEED) -> Scene:
    """Return the demo's scene: its objects on the table, a wall behind it and the floor."""
    scene = make_scene(seed, DEMO_KINDS)
    return Scene(scene.objects, scene.table, tuple(make_room_meshes()))


def demo_clouds(frames: int, *, seed: int = DEMO_SEED) -> list[tuple[int, Float32Array]]:
    """
    Return the demo's frames: ``(stamp_ns, points)``, every point the moving camera saw.

    :param frames: number of camera frames.
    :param seed: seed of the scene and of the sensor noise.
    """
    clouds = []
    for view in scene_views(demo_scene(seed), frames, distance=DEMO_DISTANCE, seed=seed):
        points = view.points.reshape(-1, 3)
        clouds.append(
            (FIRST_STAMP_NS + view.index * FRAME_PERIOD_NS, points[np.isfinite(points).all(1)])
        )
    return clouds


class _Children:
    """Subprocesses of the demo, stopped (SIGINT, then SIGKILL) on any exit."""

    def __init__(self) -> None:
        self.processes: list[subprocess.Popen] = []

    def start(self, command: Sequence[str], **kwargs: Any) -> subprocess.Popen:
        with _interrupts_deferred():
            process = subprocess.Popen(list(command), **kwargs)
            self.processes.append(process)
        return process

    @staticmethod
    def stop(process: subprocess.Popen, timeout_s: float = 10.0) -> int:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        return int(process.returncode)

    def stop_all(self) -> None:
        for process in reversed(self.processes):
            self.stop(process, timeout_s=5.0)


def _executable(name: str, module: str) -> list[str]:
    """Return the console script `name` beside this Python, or ``python -m module``."""
    script = Path(sys.executable).with_name(name)
    return [str(script)] if script.exists() else [sys.executable, '-m', module]


def _log_tail(path: Path, lines: int = 15) -> str:
    try:
        text = path.read_text(errors='replace').splitlines()
    except OSError:
        return ''
    return '\n'.join('    ' + line for line in text[-lines:])


def run_demo(
    out: Path,
    *,
    assignments: Sequence[str] = (),
    frames: int = 6,
    rate: float = 1.0,
) -> int:
    """
    Run the demo (see the module docstring); return the exit code (0 when all went well).

    :param out: the output folder (bags, picture, node log).
    :param assignments: node parameters as ``name:=value``; the offline run uses the same.
    :param frames: frames in the demo bag.
    :param rate: playback rate.
    """
    if hasattr(sys.stdout, 'reconfigure'):  # keep our lines in order with the subprocesses'
        sys.stdout.reconfigure(line_buffering=True)
    previous = {
        number: signal.signal(number, _interrupt)
        for number in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    }
    children = _Children()
    listeners: list[DemoListener] = []
    start = time.monotonic()
    try:
        return _run(out, assignments, frames, rate, children, listeners, start)
    except DemoError as error:
        print(f'mvbb demo: error: {error}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('mvbb demo: interrupted; stopping', file=sys.stderr)
        return 130
    finally:
        children.stop_all()
        for listener in listeners:
            listener.close()
        for number, handler in previous.items():
            signal.signal(number, handler)


def _run(
    out: Path,
    assignments: Sequence[str],
    frames: int,
    rate: float,
    children: _Children,
    listeners: list[DemoListener],
    start: float,
) -> int:
    # The ROS side (rclpy, messages, bags) is imported only when the demo runs: importing the
    # command-line tools must not load ROS (test/test_layers.py).
    from mvbb_ros.ros.bag import write_cloud_bag
    from mvbb_ros.ros.demo_graph import compare_offline, DemoListener, describe_frame
    from mvbb_ros.ros.offline import format_row, format_totals, TABLE_HEADER

    if frames < 1:
        raise DemoError(f'--frames must be >= 1, got {frames}')
    try:
        settings = settings_from_mapping(parse_assignments(assignments))
    except ValueError as error:
        raise DemoError(str(error)) from error
    out.mkdir(parents=True, exist_ok=True)
    env = demo_environment()
    print(
        f'demo graph: ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]}, '
        f'ROS_AUTOMATIC_DISCOVERY_RANGE={env["ROS_AUTOMATIC_DISCOVERY_RANGE"]}'
    )

    # The node starts first: importing Open3D takes a few seconds, while the bag is written.
    node_log = out / 'demo_node.log'
    node_args = ['--ros-args', '-r', f'cloud_in:={DEMO_TOPIC}', '-p', 'input_depth:=50']
    for assignment in assignments:
        node_args += ['-p', assignment]
    print(f'[1/5] starting the node: decomposer {" ".join(node_args)}  (log: {node_log})')
    with open(node_log, 'w') as log:
        node = children.start(
            _executable('decomposer', 'mvbb_ros.ros.decomposer') + node_args,
            stdout=log,
            stderr=subprocess.STDOUT,
        )

    bag_path = out / 'demo_input'
    clouds = demo_clouds(frames)
    write_cloud_bag(bag_path, DEMO_TOPIC, DEMO_FRAME, clouds)
    counts = [len(points) for _, points in clouds]
    print(
        f'[2/5] wrote {bag_path}: {frames} frames of a {", ".join(DEMO_KINDS)} scene seen by a '
        f'moving depth camera with noise, {min(counts)}-{max(counts)} points each, on {DEMO_TOPIC}'
    )

    listener = DemoListener()
    listeners.append(listener)
    deadline = time.monotonic() + NODE_START_TIMEOUT_S
    while not listener.node_is_up():
        if node.poll() is not None:
            raise DemoError(f'the node exited with code {node.returncode}:\n{_log_tail(node_log)}')
        if time.monotonic() > deadline:
            raise DemoError(
                f'the node did not come up in {NODE_START_TIMEOUT_S:.0f} s:\n{_log_tail(node_log)}'
            )
        listener.spin(0.1)

    play_args = ['bag', 'play', str(bag_path), '--rate', f'{rate:g}']
    play_args += ['--wait-for-subscribers', '20', '--no-progress']
    print(f'[3/5] playing it through the node: mvbb {" ".join(play_args)}')
    player = children.start(_executable('mvbb', 'mvbb_ros.cli.main') + play_args)
    printed = 0
    stamps = [FIRST_STAMP_NS + i * FRAME_PERIOD_NS for i in range(frames)]
    answer_deadline = None
    while True:
        listener.spin(0.05)
        for stamp in listener.complete():
            frame = listener.frames[stamp]
            if not frame.printed:
                frame.printed = True
                index = stamps.index(stamp) if stamp in stamps else -1
                seconds = (stamp - FIRST_STAMP_NS) / 1e9
                print('      ' + describe_frame(frame, index, seconds))
                printed += 1
        if printed >= frames:
            break
        if node.poll() is not None:
            raise DemoError(f'the node exited with code {node.returncode}:\n{_log_tail(node_log)}')
        if player.poll() is not None:
            if player.returncode != 0:
                raise DemoError(f'mvbb bag play failed with exit code {player.returncode}')
            if answer_deadline is None:
                answer_deadline = time.monotonic() + ANSWER_TIMEOUT_S
            elif time.monotonic() > answer_deadline:
                raise DemoError(f'the node answered {printed} of {frames} frames')
    if player.wait() != 0:
        raise DemoError(f'mvbb bag play failed with exit code {player.returncode}')
    node_code = children.stop(node)
    if node_code != 0:
        raise DemoError(f'the node exited with code {node_code} on SIGINT:\n{_log_tail(node_log)}')
    print(f'      the node answered all {frames} frames and exited cleanly on SIGINT')

    processed_path = out / 'demo_processed'
    options = ''.join(f' -p {assignment}' for assignment in assignments)
    print(f'[4/5] mvbb bag process {bag_path} {processed_path} --with-input --force{options}')
    print(TABLE_HEADER)
    summary, differing, last = compare_offline(
        bag_path,
        processed_path,
        settings,
        listener,
        on_row=lambda row: print(format_row(row, FIRST_STAMP_NS)),
    )
    for line in format_totals(summary):
        print(line)
    if differing or last is None:
        raise DemoError(f'live and offline outputs differ on frames {differing}')
    print(
        f'      live == offline: the node and mvbb bag process gave identical messages '
        f'on all {summary.clouds} frames'
    )
    picture = out / 'demo.png'
    _draw(picture, last, settings)
    print(f'[5/5] wrote {picture}')
    print(
        f'demo done in {time.monotonic() - start:.1f} s: {bag_path} (input), {processed_path} '
        f'(input, boxes, tree, grasps: play it with ros2 bag play or open it in Foxglove), '
        f'{picture}'
    )
    return 0


def _draw(picture: Path, last: OfflineFrame, settings: PipelineSettings) -> None:
    """Draw the last frame: one row per object, its points, boxes and best grasps."""
    result = last.result
    points = read_xyz(last.cloud)
    threshold = settings.decomposition.gain_threshold
    if result is None or not result.objects:
        title = f'demo frame {last.index}: {len(points)} points, no boxes (t = {threshold:g})'
        render_panels(picture, [Panel(points, [], title=title)], views=DRAW_VIEWS, frame='data')
        return
    panels = []
    for item in result.objects:
        leaves = item.decomposition.leaves
        grasps = [grasp for grasp in result.grasps if grasp.object_index == item.index]
        observed = item.shape.points[: item.shape.observed]
        title = f'object {item.index}: {len(leaves)} boxes, {len(grasps)} grasps'
        panels.append(Panel(observed, leaves, grasps=grasps, title=title))
    title = (
        f'demo frame {last.index}: {len(points)} points -> {len(result.objects)} objects, '
        f'{len(result.leaves)} boxes, {len(result.grasps)} grasps (t = {threshold:g})'
    )
    render_panels(picture, panels, views=DRAW_VIEWS, frame='data', title=title, max_grasps=3)
