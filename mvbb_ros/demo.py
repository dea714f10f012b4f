"""
`mvbb demo`: the decomposer node on a replayed stream, end to end, on the project's own data.

1. Write a small bag: a synthetic table-top scene (:func:`mvbb_ros.synthetic.make_scene`) seen by
   a depth camera moving on an arc around it, with sensor noise
   (:func:`mvbb_ros.synthetic.scene_views`); each frame keeps the points of the objects (the
   table removed, as a table-top segmentation would) as one PointCloud2 at 5 Hz.
2. Start the node (the ``decomposer`` executable, ``-r cloud_in:=/demo/segmented_objects``,
   reliable input so that no frame is skipped) as a subprocess.
3. Play the bag through it with ``mvbb bag play`` (a subprocess) while a listener subscribed to
   ``/decomposer/boxes`` and ``/decomposer/grasps`` prints what the node published per frame.
4. Process the same bag offline (the code of ``mvbb bag process``), print its table, and check
   that every live message equals the offline one.
5. Draw the last frame with its boxes and grasps (:func:`mvbb_ros.render.render_boxes`).

The demo talks on its own graph: a random ``ROS_DOMAIN_ID`` and
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless the user set them. It ends by itself, and
stops its subprocesses on any exit (error, SIGINT, SIGTERM).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
import contextlib
from dataclasses import dataclass, field
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import time
from typing import Any

import numpy as np

#: The demo bag's cloud topic and frame.
DEMO_TOPIC = '/demo/segmented_objects'
DEMO_FRAME = 'demo_camera_optical_frame'
#: Objects of the demo scene, and the seed of their placement.
DEMO_KINDS = ('mug', 'can', 'box')
DEMO_SEED = 3
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


def demo_environment(environ: dict[str, str] | None = None) -> dict[str, str]:
    """
    Give the demo its own graph: a random ROS_DOMAIN_ID and localhost-only discovery.

    Values the user set are kept. `environ` (default ``os.environ``) is updated in place.

    :return: the two values in force.
    """
    environ = os.environ if environ is None else environ
    environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
    environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return {name: environ[name] for name in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')}


def write_demo_bag(
    path: Path, frames: int, *, seed: int = DEMO_SEED, storage: str = 'mcap'
) -> list[int]:
    """
    Write the demo bag (replacing an old one) and return the point count of each frame.

    :param path: the rosbag2 directory to write (atomically).
    :param frames: number of camera frames.
    :param seed: seed of the scene and of the sensor noise.
    :param storage: ``'mcap'`` or ``'sqlite3'``.
    """
    from mvbb_ros.atomic import atomic_path
    from mvbb_ros.bag import BagWriter, CLOUD_TYPE
    from mvbb_ros.pointcloud2 import create_cloud_xyz
    from mvbb_ros.synthetic import BACKGROUND, make_scene, scene_views
    from rclpy.serialization import serialize_message

    scene = make_scene(seed, DEMO_KINDS)
    counts = []
    with atomic_path(path) as tmp, BagWriter(tmp, storage=storage) as writer:
        writer.add_topic(DEMO_TOPIC, CLOUD_TYPE)
        for view in scene_views(scene, frames, distance=0.9, seed=seed):
            points = view.points[view.labels != BACKGROUND]
            stamp_ns = FIRST_STAMP_NS + view.index * FRAME_PERIOD_NS
            sec, nanosec = divmod(stamp_ns, 1_000_000_000)
            cloud = create_cloud_xyz(points, frame_id=DEMO_FRAME)
            cloud.header.stamp.sec, cloud.header.stamp.nanosec = sec, nanosec
            writer.write(DEMO_TOPIC, stamp_ns, serialize_message(cloud))
            counts.append(len(points))
        if path.exists():
            import shutil

            shutil.rmtree(path)
    return counts


@dataclass
class _Frame:
    boxes: Any = None
    grasps: Any = None
    printed: bool = False


@dataclass
class _Listener:
    """A node that records /decomposer/boxes and /decomposer/grasps, by header stamp."""

    frames: dict[int, _Frame] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from geometry_msgs.msg import PoseArray
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from visualization_msgs.msg import MarkerArray

        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('mvbb_demo_listener', context=self.context)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.RELIABLE
        )
        self.node.create_subscription(MarkerArray, '/decomposer/boxes', self._on_boxes, qos)
        self.node.create_subscription(PoseArray, '/decomposer/grasps', self._on_grasps, qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _frame(self, header: Any) -> _Frame:
        stamp = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        return self.frames.setdefault(stamp, _Frame())

    def _on_boxes(self, message: Any) -> None:
        if message.markers:  # the first marker (DELETEALL) carries the cloud's header
            self._frame(message.markers[0].header).boxes = message

    def _on_grasps(self, message: Any) -> None:
        self._frame(message.header).grasps = message

    def node_is_up(self) -> bool:
        return all(
            self.node.count_publishers(topic) > 0
            for topic in ('/decomposer/boxes', '/decomposer/grasps')
        )

    def complete(self) -> list[int]:
        return sorted(s for s, f in self.frames.items() if f.boxes and f.grasps)

    def spin(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=max(0.0, min(0.05, deadline - time.monotonic())))

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def describe_frame(index: int, stamp_ns: int, boxes: Any, grasps: Any) -> str:
    """Return one line about what the node published for a frame."""
    from visualization_msgs.msg import Marker

    cubes = [m for m in boxes.markers if m.type == Marker.CUBE and m.action == Marker.ADD]
    sizes = sorted(
        (m.scale.x * m.scale.y * m.scale.z, (m.scale.x, m.scale.y, m.scale.z)) for m in cubes
    )
    line = (
        f'frame {index}: stamp {(stamp_ns - FIRST_STAMP_NS) / 1e9:5.2f} s, {len(cubes):2d} boxes'
    )
    if sizes:
        largest = ' x '.join(f'{v * 100:.1f}' for v in sizes[-1][1])
        line += f' (largest {largest} cm)'
    line += f', {len(grasps.poses):3d} grasps'
    if grasps.poses:
        p = grasps.poses[0].position
        line += f', best at ({p.x:+.3f}, {p.y:+.3f}, {p.z:+.3f}) m'
    return line


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
    listeners: list[_Listener] = []
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
    listeners: list[_Listener],
    start: float,
) -> int:
    from mvbb_ros.settings import parse_assignments, settings_from_mapping

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
    node_args = ['--ros-args', '-r', f'cloud_in:={DEMO_TOPIC}', '-p', 'reliable_input:=true']
    for assignment in assignments:
        node_args += ['-p', assignment]
    print(f'[1/5] starting the node: decomposer {" ".join(node_args)}  (log: {node_log})')
    with open(node_log, 'w') as log:
        node = children.start(
            _executable('decomposer', 'mvbb_ros.node') + node_args,
            stdout=log,
            stderr=subprocess.STDOUT,
        )

    bag_path = out / 'demo_input'
    counts = write_demo_bag(bag_path, frames)
    print(
        f'[2/5] wrote {bag_path}: {frames} frames of a {", ".join(DEMO_KINDS)} scene seen by a '
        f'moving depth camera with noise, {min(counts)}-{max(counts)} points each, on {DEMO_TOPIC}'
    )

    listener = _Listener()
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
    player = children.start(_executable('mvbb', 'mvbb_ros.cli') + play_args)
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
                print('      ' + describe_frame(index, stamp, frame.boxes, frame.grasps))
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
    last = _process_offline(bag_path, processed_path, settings, listener, assignments)
    picture = out / 'demo.png'
    _draw(picture, last, settings)
    print(f'[5/5] wrote {picture}')
    print(
        f'demo done in {time.monotonic() - start:.1f} s: {bag_path} (input), {processed_path} '
        f'(input, boxes, tree, grasps: play it with ros2 bag play or open it in Foxglove), '
        f'{picture}'
    )
    return 0


def _process_offline(
    bag_path: Path, processed_path: Path, settings: Any, listener: _Listener, assignments: Any
) -> dict[str, Any]:
    """Run `mvbb bag process` on the demo bag, compare with the live outputs; return the last."""
    from mvbb_ros.bag import format_row, format_totals, process_bag, TABLE_HEADER
    from mvbb_ros.messages import output_messages
    from rclpy.serialization import deserialize_message, serialize_message

    options = ''.join(f' -p {assignment}' for assignment in assignments)
    print(f'[4/5] mvbb bag process {bag_path} {processed_path} --with-input --force{options}')
    print(TABLE_HEADER)
    last: dict[str, Any] = {}
    differing: list[int] = []

    def compare(row: Any, cloud: Any, result: Any) -> None:
        print(format_row(row, FIRST_STAMP_NS))
        # Compare as received: float32 fields (colours) are rounded by serialization.
        offline = {
            suffix: deserialize_message(serialize_message(message), type(message))
            for suffix, message in output_messages(result, cloud.header, settings).items()
        }
        live = listener.frames.get(row.stamp_ns)
        if live is None or live.boxes != offline['boxes'] or live.grasps != offline['grasps']:
            differing.append(row.index)
        last.update(cloud=cloud, result=result, index=row.index)

    summary = process_bag(
        bag_path, processed_path, settings=settings, with_input=True, force=True, on_cloud=compare
    )
    for line in format_totals(summary):
        print(line)
    if differing:
        raise DemoError(f'live and offline outputs differ on frames {differing}')
    print(
        f'      live == offline: the node and mvbb bag process gave identical messages '
        f'on all {summary.clouds} frames'
    )
    return last


def _draw(picture: Path, last: dict[str, Any], settings: Any) -> None:
    from mvbb_ros.pointcloud2 import read_xyz
    from mvbb_ros.render import render_boxes

    result = last['result']
    boxes = [] if result is None else result.leaves
    grasps = [] if result is None else result.grasps
    points = np.asarray(read_xyz(last['cloud']))
    title = (
        f'demo frame {last["index"]}: {len(points)} points -> {len(boxes)} boxes, '
        f'{len(grasps)} grasps (t = {settings.gain_threshold:g})'
    )
    render_boxes(picture, points, boxes, grasps=grasps, title=title)
