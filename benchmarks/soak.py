"""
Soak test: stream 300k-point clouds at 30 Hz into the decomposer for a number of minutes.

Starts the installed `decomposer` as its own process (so its memory is its own), publishes
organized depth frames of a synthetic object (or a given .npy cloud), listens to ~/boxes, and
reports clouds sent, answered and dropped, latency percentiles (publish to the boxes received,
matched by stamp), the node's resident memory over time and its CPU time while the clouds
stream, by thread: the executor (the process's main thread), the middleware (Fast DDS's
``dds.*`` threads) and the frames (every other thread: the frame worker and its helpers), as
shares of the streaming time (100 % is one core kept busy). A node whose threads add up to its
cores cannot keep up however fast the transport is.

    .venv/bin/python benchmarks/soak.py --minutes 10
    .venv/bin/python benchmarks/soak.py --cloud ../shared/data/models/bunny_vertices.npy \
        --rate 2 --minutes 0.5        # latency of one cloud at a time

The peer, measured first in the same run (``--no-peer`` skips it): the same stream into an
empty node on the same core, which answers every cloud it takes with one marker and does
nothing else. What it misses is the middleware's and rclpy's cost of moving the clouds (an
organized 300k frame is a 1.1-megapixel image, 13 MB a message), which no pipeline can win back.

``--publisher-profile config/fastdds_large_clouds.xml`` publishes the clouds with the shipped
Fast DDS profile (a shared-memory segment that holds whole frames, as a camera driver on the
robot's computer would load it; the nodes keep the middleware's defaults).

The clouds are published reliable with keep last 1, as camera drivers and bag players do
(``--reliability best_effort`` to compare: the middleware's default transport then loses most
large clouds before the node sees them; the profile above does not). The node runs on one core
(``--node-core``, default 1, set before it starts; this process on the other), as on a robot
that gives the decomposer one core; ``--node-core 0,1`` gives it both (its ``workers`` default
to the CPUs it may use, so 2 then). The last lines compare the decomposer's figures with
issue 17's targets: at least 95 % of the clouds answered, p99 latency under 50 ms, resident
memory growing less than 5 % after the warm-up (the first minute), exit code 0 on SIGINT.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import time

import numpy as np
import psutil

#: The node's resident memory settles in its first minute (buffers, allocator arenas): growth
#: is measured after it (:attr:`Figures.growth`).
WARM_UP_S = 60.0
#: The topic the clouds go to and the one the answers come from (the node's defaults).
CLOUD_TOPIC = 'cloud_in'
BOXES_TOPIC = '/decomposer/boxes'
DIAGNOSTICS_TOPIC = '/diagnostics'
#: The variable ROS 2 Jazzy's Fast DDS (2.x) reads its XML profile from.
PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'


@dataclass
class Figures:
    """What one stream into one node measured."""

    elapsed_s: float  # streaming, without the drain after the last cloud
    sent: int
    latencies_ms: np.ndarray
    memory: list[tuple[float, int]]
    exit_code: int | None
    #: The node's ``frame_budget_level`` in each of its diagnostics (once a second; empty
    #: without a ``frame_time_budget``): the level the next cloud runs at.
    budget_levels: tuple[int, ...] = ()
    #: The node's CPU time while streaming by role (:func:`thread_cpu_s`), as shares of the
    #: streaming time.
    cpu: dict[str, float] | None = None

    @property
    def answered(self) -> int:
        """Clouds whose boxes came back."""
        return len(self.latencies_ms)

    @property
    def share(self) -> float:
        """Answered over sent."""
        return self.answered / max(self.sent, 1)

    def percentile_ms(self, q: float) -> float:
        """Latency percentile, ms (inf when nothing was answered)."""
        return float(np.percentile(self.latencies_ms, q)) if self.answered else float('inf')

    @property
    def growth(self) -> float:
        """
        Return the resident memory's growth after the warm-up (:func:`warm_up_s`), as a share.

        The peak of the last quarter of the time after the warm-up over the peak of its first
        quarter (a steady leak shows three quarters of its growth). Peaks, not single samples:
        glibc gives freed buffers back from time to time, so one sample can fall 5-10 % below
        the node's steady size; a leak raises the peaks.
        """
        if not self.memory:
            return 0.0
        warm = warm_up_s(self.memory[-1][0])
        kept = [(seconds, rss) for seconds, rss in self.memory if seconds >= warm]
        if len(kept) < 2:
            return 0.0
        quarter = 0.25 * (kept[-1][0] - kept[0][0])
        first = max(rss for seconds, rss in kept if seconds <= kept[0][0] + quarter)
        last = max(rss for seconds, rss in kept if seconds >= kept[-1][0] - quarter)
        return (last - first) / first


def warm_up_s(duration_s: float) -> float:
    """Return the warm-up of a run: its first minute, or its first third when shorter."""
    return min(WARM_UP_S, duration_s / 3.0)


#: The roles of the node's threads in :func:`thread_cpu_s`.
THREAD_ROLES = ('frames', 'middleware', 'executor')


def thread_cpu_s(process: psutil.Process) -> dict[str, float]:
    """
    Return the CPU seconds (user and system) the process's threads used so far, by role.

    ``executor`` is the main thread (rclpy spins there), ``middleware`` the threads Linux names
    ``dds.*`` (Fast DDS's receive and event threads), ``frames`` every other thread.
    """
    seconds = dict.fromkeys(THREAD_ROLES, 0.0)
    for thread in process.threads():
        if thread.id == process.pid:
            role = 'executor'
        else:
            try:
                name = Path(f'/proc/{process.pid}/task/{thread.id}/comm').read_text()
            except OSError:  # the thread ended meanwhile
                name = ''
            role = 'middleware' if name.startswith('dds.') else 'frames'
        seconds[role] += thread.user_time + thread.system_time
    return seconds


def empty_node(reliability: str) -> int:
    """Run the peer: a node named like the decomposer that answers each cloud and does nothing."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import Marker, MarkerArray

    rclpy.init()
    node = rclpy.create_node('decomposer')
    publisher = node.create_publisher(MarkerArray, '~/boxes', 10)

    def answer(cloud: PointCloud2) -> None:
        marker = Marker(header=cloud.header, action=Marker.DELETEALL)
        publisher.publish(MarkerArray(markers=[marker]))

    # The stream's reliability (the decomposer's input matches its publishers by itself).
    policy = (
        ReliabilityPolicy.RELIABLE if reliability == 'reliable' else ReliabilityPolicy.BEST_EFFORT
    )
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=policy)
    node.create_subscription(PointCloud2, CLOUD_TOPIC, answer, qos)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def stream(
    command: list[str],
    frames: list,
    args: argparse.Namespace,
    client,
    environment: dict[str, str],
) -> Figures:
    """Start `command` on the node's core, stream `frames` into it, and measure the answers."""
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import PointCloud2
    from visualization_msgs.msg import MarkerArray

    cores = set(args.node_core)
    # Pinned before it starts: the node's default workers are the cores it may use then.
    node = subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=environment,
        preexec_fn=lambda: os.sched_setaffinity(0, cores),
    )
    process = psutil.Process(node.pid)
    sent: dict[tuple[int, int], float] = {}
    latencies: list[float] = []

    def on_boxes(message: MarkerArray) -> None:
        header = message.markers[0].header
        key = (header.stamp.sec, header.stamp.nanosec)
        if key in sent:
            latencies.append(time.perf_counter() - sent.pop(key))

    levels: list[int] = []

    def on_diagnostics(message: DiagnosticArray) -> None:
        for status in message.status:
            values = {item.key: item.value for item in status.values}
            if status.name.startswith('decomposer') and 'frame_budget_level' in values:
                levels.append(int(values['frame_budget_level']))

    reliable = QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
    )
    subscription = client.create_subscription(MarkerArray, BOXES_TOPIC, on_boxes, reliable)
    diagnostics = client.create_subscription(
        DiagnosticArray, DIAGNOSTICS_TOPIC, on_diagnostics, reliable
    )
    publisher = client.create_publisher(
        PointCloud2,
        CLOUD_TOPIC,
        QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE
            if args.reliability == 'reliable'
            else ReliabilityPolicy.BEST_EFFORT,
        ),
    )
    count = 0
    memory: list[tuple[float, int]] = []
    cpu: dict[str, float] | None = None
    elapsed = 0.0
    exit_code = None
    try:
        deadline = time.monotonic() + 60.0
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            rclpy.spin_once(client, timeout_sec=0.1)
        if publisher.get_subscription_count() == 0:
            code = node.poll()
            why = 'is not subscribed' if code is None else f'exited with code {code}'
            raise RuntimeError(f'{" ".join(command)}: {why} after 60 s')
        memory.append((0.0, process.memory_info().rss))
        cpu_before = thread_cpu_s(process)
        period = 1.0 / args.rate
        start = time.monotonic()
        end = start + args.minutes * 60.0
        next_send = start
        next_memory = start + args.memory_every
        while time.monotonic() < end:
            now = time.monotonic()
            if now >= next_send:
                cloud = frames[count % len(frames)]
                cloud.header.stamp.sec, cloud.header.stamp.nanosec = count // 1000, count % 1000
                sent[(cloud.header.stamp.sec, cloud.header.stamp.nanosec)] = time.perf_counter()
                publisher.publish(cloud)
                count += 1
                next_send += period
                if next_send < now:  # publishing itself fell behind: do not burst
                    next_send = now + period
            if now >= next_memory:
                memory.append((now - start, process.memory_info().rss))
                next_memory += args.memory_every
            rclpy.spin_once(client, timeout_sec=max(0.0, min(next_send, end) - time.monotonic()))
        elapsed = time.monotonic() - start
        cpu_after = thread_cpu_s(process)
        cpu = {
            role: (cpu_after[role] - cpu_before[role]) / max(elapsed, 1e-9)
            for role in THREAD_ROLES
        }
        drain = time.monotonic() + 3.0
        while time.monotonic() < drain:
            rclpy.spin_once(client, timeout_sec=0.05)
        memory.append((time.monotonic() - start, process.memory_info().rss))
    finally:
        node.send_signal(signal.SIGINT)
        exit_code = node.wait(timeout=30)
        client.destroy_subscription(subscription)
        client.destroy_subscription(diagnostics)
        client.destroy_publisher(publisher)
    return Figures(
        elapsed, count, np.array(latencies) * 1e3, memory, exit_code, tuple(levels), cpu
    )


def report(name: str, figures: Figures) -> None:
    """Print one node's figures."""
    elapsed = max(figures.elapsed_s, 1e-9)
    print(
        f'{name}: {elapsed:.0f} s, sent {figures.sent} clouds ({figures.sent / elapsed:.1f} Hz), '
        f'answered {figures.answered} ({figures.answered / elapsed:.1f} Hz, '
        f'{100.0 * figures.share:.1f} %), dropped {figures.sent - figures.answered}'
    )
    if figures.answered:
        print(
            f'  latency publish -> boxes: p50 {figures.percentile_ms(50):.1f} ms, '
            f'p99 {figures.percentile_ms(99):.1f} ms, max {figures.latencies_ms.max():.1f} ms'
        )
    print(
        '  resident memory (MiB) over time: '
        + ', '.join(f'{seconds:.0f} s {rss / 2**20:.1f}' for seconds, rss in figures.memory)
    )
    print(f'  memory growth after the warm-up (peaks): {100.0 * figures.growth:+.1f}%')
    if figures.cpu is not None:
        parts = ', '.join(f'{role} {100.0 * figures.cpu[role]:.0f} %' for role in THREAD_ROLES)
        print(
            f'  CPU while streaming: {100.0 * sum(figures.cpu.values()):.0f} % of one core '
            f'({parts})'
        )
    if figures.budget_levels:
        seconds = np.bincount(figures.budget_levels)
        spread = ', '.join(f'{level}: {int(n)}' for level, n in enumerate(seconds) if n)
        print(f'  frame_time_budget level, seconds at each (from /diagnostics): {spread}')
    print(f'  exit code on SIGINT: {figures.exit_code}')


def decomposer_command(executable: Path, parameters: list[str]) -> list[str]:
    """Return the decomposer's command line with `parameters` (``NAME:=VALUE``) as ROS args."""
    for item in parameters:
        name, separator, value = item.partition(':=')
        if not (name and separator and value):
            raise ValueError(f'a parameter is NAME:=VALUE, got {item!r}')
    if not parameters:
        return [str(executable)]
    return [str(executable), '--ros-args', *(part for item in parameters for part in ('-p', item))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--minutes', type=float, default=1.0, help='duration (default 1)')
    parser.add_argument('--rate', type=float, default=30.0, help='clouds per second (30)')
    parser.add_argument('--points', type=int, default=300_000, help='points per cloud (300k)')
    parser.add_argument('--memory-every', type=float, default=30.0, help='RSS sample period, s')
    parser.add_argument(
        '--node-core',
        type=lambda text: [int(word) for word in text.split(',')],
        default=[1],
        help='CPU of the node (default 1), or CPUs: 0,1 (its default workers: one per CPU)',
    )
    parser.add_argument(
        '--reliability',
        choices=('reliable', 'best_effort'),
        default='reliable',
        help="the clouds' QoS (default reliable, as camera drivers and bag players publish; "
        "best effort loses most large clouds in the middleware's default transport before the "
        'node sees them)',
    )
    parser.add_argument(
        '--cloud',
        type=Path,
        help='a .npy (N, 3) cloud in metres instead of the synthetic 300k-point frame',
    )
    parser.add_argument(
        '--unorganized',
        action='store_true',
        help="send the synthetic frame's object points only, as an unorganized cloud "
        '(3.6 MB a message instead of the organized 13 MB)',
    )
    parser.add_argument(
        '--no-peer',
        action='store_true',
        help='skip the empty node streamed first (the transport alone, for comparison)',
    )
    parser.add_argument(
        '--publisher-profile',
        type=Path,
        help='a Fast DDS XML profile loaded by this process, which publishes the clouds, as a '
        'camera driver would (config/fastdds_large_clouds.xml); the nodes keep the defaults',
    )
    parser.add_argument(
        '-p',
        '--param',
        action='append',
        default=[],
        metavar='NAME:=VALUE',
        help='a parameter of the decomposer, as `ros2 run ... --ros-args -p` takes it '
        '(repeatable; e.g. frame_time_budget:=0.03)',
    )
    parser.add_argument('--empty-node', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    try:
        decomposer = decomposer_command(Path(sys.executable).parent / 'decomposer', args.param)
    except ValueError as error:
        parser.error(str(error))
    if args.empty_node:
        return empty_node(args.reliability)

    os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    node_environment = dict(os.environ)
    if args.publisher_profile is not None:
        if not args.publisher_profile.is_file():
            parser.error(f'no such profile: {args.publisher_profile}')
        # Read when this process creates its first participant (rclpy.init, below).
        os.environ[PROFILE_VARIABLE] = str(args.publisher_profile.resolve())
        node_environment.pop(PROFILE_VARIABLE, None)

    from mvbb_ros.evaluation.synthetic import organized_frame
    from mvbb_ros.ros.encode import create_cloud_xyz
    import rclpy

    frames = []
    if args.cloud is not None:
        points = np.load(args.cloud)
        frames.append(create_cloud_xyz(points, frame_id='camera_optical_frame'))
        print(f'{args.cloud.name}: {len(points)} points', flush=True)
    else:
        for seed in range(4):
            grid = organized_frame(args.points, seed=seed)
            if args.unorganized:
                points = grid.reshape(-1, 3)
                cloud = create_cloud_xyz(
                    points[np.isfinite(points).all(axis=1)], frame_id='camera_optical_frame'
                )
            else:
                cloud = create_cloud_xyz(
                    grid.reshape(-1, 3),
                    organized_shape=grid.shape[:2],
                    frame_id='camera_optical_frame',
                )
            frames.append(cloud)
        finite = int(np.isfinite(grid).all(axis=2).sum())
        shape = 'unorganized' if args.unorganized else f'organized {grid.shape[1]}x{grid.shape[0]}'
        print(
            f'{len(frames)} frames, {shape} ({finite} object points each, '
            f'{len(frames[0].data) / 1e6:.1f} MB a message)',
            flush=True,
        )
    others = sorted(set(os.sched_getaffinity(0)) - set(args.node_core))
    if others:
        os.sched_setaffinity(0, others)
    print(
        f'node on CPU {",".join(map(str, args.node_core))}, this process on '
        f'{others or "every CPU"}; load average '
        + ' '.join(f'{value:.2f}' for value in os.getloadavg()),
        flush=True,
    )
    profile = os.environ.get(PROFILE_VARIABLE)
    print(f'publisher transport: {profile or "Fast DDS defaults"}', flush=True)
    if args.param:
        print(f'decomposer parameters: {" ".join(args.param)}', flush=True)
    nodes = [('decomposer', decomposer)]
    if not args.no_peer:
        empty = [
            sys.executable,
            str(Path(__file__).resolve()),
            '--empty-node',
            '--reliability',
            args.reliability,
        ]
        nodes.insert(0, ('empty node (peer)', empty))
    rclpy.init()
    client = rclpy.create_node('soak')
    measured = {}
    try:
        for name, command in nodes:
            measured[name] = stream(command, frames, args, client, node_environment)
            report(name, measured[name])
    except RuntimeError as error:
        print(error, file=sys.stderr)
        return 1
    finally:
        client.destroy_node()
        rclpy.shutdown()

    figures = measured['decomposer']
    if 'empty node (peer)' in measured:
        peer = measured['empty node (peer)']
        print(
            f'decomposer over the empty node: answered {figures.share / max(peer.share, 1e-9):.2f}'
            f' x, p99 latency {figures.percentile_ms(99) / peer.percentile_ms(99):.2f} x'
        )
    p99 = figures.percentile_ms(99)
    targets = [
        (f'answered {100.0 * figures.share:.1f} % >= 95 %', figures.share >= 0.95),
        (f'p99 latency {p99:.1f} ms < 50 ms', p99 < 50.0),
        (f'memory growth {100.0 * figures.growth:+.1f} % < 5 %', figures.growth < 0.05),
        (f'exit code {figures.exit_code} == 0', figures.exit_code == 0),
    ]
    print('targets: ' + '; '.join(f'{what}: {"met" if ok else "MISSED"}' for what, ok in targets))
    return 0 if all(f.exit_code == 0 for f in measured.values()) else 1


if __name__ == '__main__':
    sys.exit(main())
