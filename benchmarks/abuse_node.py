"""
The real node under abuse: the 300-blob cloud during parameter calls; starts with a bad cache.

The 300-blob cloud while its parameter services are called, and its start with a torn kernel
cache and from a read-only install.

Run from the repository root::

    PYTHONPATH=. .venv/bin/python benchmarks/abuse_node.py                # everything
    PYTHONPATH=. .venv/bin/python benchmarks/abuse_node.py --only blobs   # the frame only
    PYTHONPATH=. .venv/bin/python benchmarks/abuse_node.py --only starts  # the starts only

Each run starts the node (``python -m mvbb_ros.ros.decomposer``, what the ``decomposer``
executable runs) as a process of its own, on a random ROS_DOMAIN_ID limited to this machine.

The frame: after one small cloud (so that the first frame's one-off costs are paid), this
process publishes the unsegmented cloud of ``benchmarks/abuse.py`` (300 small blobs, 60k points,
1.7 m across; ``--frames`` times, 1 s apart) and, until the node's grasps for it arrive, calls the
node's GetParameters and ListParameters services in turn, one call 50 ms after the last one
answered, recording each call's latency. It samples the node's resident memory (psutil) every
20 ms and reads its peak (``VmHWM``) at the end; it reports the frame time (publish to the
grasps' arrival), the node's log lines during the frame and the diagnostics' key values after it
(what was capped, the result's notes). Before the frames, the same calls to the idle node are
the peer.

The starts: the package is copied with its warm kernel cache into a temporary install; the time
is from spawning the node to its first answer to GetParameters. Three starts: the copy as it is;
the copy with one cache index file cut to 10 bytes (what a power cut right after the first
compile leaves; the node discards it, warns once and compiles that kernel again); the copy
read-only with a read-only HOME (a read-only container; a bind mount as root, file modes
otherwise, as ``test/support/mounts.py`` does).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import psutil

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path[:0] = [str(HERE), str(ROOT / 'test')]  # the abuse suite's cloud, the tests' mounts

#: Pause between the end of one parameter call and the next, seconds.
CALL_PERIOD_S = 0.05
#: Parameter calls to the idle node before the frames (the peer of the calls during them).
IDLE_CALLS = 60
#: Give up on a start or a frame after this long, seconds.
TIMEOUT_S = 600.0
#: The issue's promise: the parameter services answer within this, seconds, during a frame.
TARGET_S = 0.1
#: The cache index cut short for the torn-cache start (a kernel the node warms up at start).
TORN_INDEX = 'geometry/boxfit/__pycache__/fit.fit_kernel-*.nbi'


class Probe:
    """This process's side of the graph: the node's parameter clients, a publisher, listeners."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray
        from rcl_interfaces.srv import GetParameters, ListParameters
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import PointCloud2

        rclpy.init()
        self.node = rclpy.create_node('abuse_node_probe')
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        reliable = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
        )
        self.publisher = self.node.create_publisher(
            PointCloud2, '/cloud_in', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        )
        self.grasps: list[tuple[float, PoseArray]] = []
        self.diagnostics: list[tuple[float, DiagnosticArray]] = []
        self.node.create_subscription(
            PoseArray,
            '/decomposer/grasps',
            lambda m: self.grasps.append((time.perf_counter(), m)),
            reliable,
        )
        self.node.create_subscription(
            DiagnosticArray,
            '/diagnostics',
            lambda m: self.diagnostics.append((time.perf_counter(), m)),
            reliable,
        )
        self.get = self.node.create_client(GetParameters, '/decomposer/get_parameters')
        self.list = self.node.create_client(ListParameters, '/decomposer/list_parameters')
        self.requests = {
            'get': GetParameters.Request(names=['gain_threshold', 'max_objects']),
            'list': ListParameters.Request(),
        }

    def call(self, kind: str, timeout_s: float) -> float | None:
        """Call GetParameters ('get') or ListParameters ('list'); return its latency or None."""
        client = self.get if kind == 'get' else self.list
        if not client.service_is_ready():
            self.executor.spin_once(timeout_sec=0.05)
            return None
        start = time.perf_counter()
        future = client.call_async(self.requests[kind])
        self.executor.spin_until_future_complete(future, timeout_sec=timeout_s)
        if not future.done():
            future.cancel()
            return None
        return time.perf_counter() - start

    def spin_for(self, seconds: float) -> None:
        """Spin this side for `seconds`."""
        deadline = time.perf_counter() + seconds
        while time.perf_counter() < deadline:
            self.executor.spin_once(timeout_sec=0.01)

    def answered(self, sec: int) -> float | None:
        """Return when the grasps stamped `sec` arrived, or None."""
        return next((t for t, m in self.grasps if m.header.stamp.sec == sec), None)

    def close(self) -> None:
        """Leave the graph."""
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown()


def start_node(
    tree: Path, log: Path, *, home: Path | None = None, prefix: list[str] | None = None
) -> subprocess.Popen:
    """Start the node from the package in `tree`; its output goes to `log`."""
    env = {k: v for k, v in os.environ.items() if k != 'NUMBA_CACHE_DIR'}
    env.update(PYTHONPATH=str(tree), PYTHONUNBUFFERED='1')
    if home is not None:
        env.update(HOME=str(home), XDG_CACHE_HOME=str(home / '.cache'))
    with open(log, 'w') as handle:
        return subprocess.Popen(
            [*(prefix or []), sys.executable, '-m', 'mvbb_ros.ros.decomposer'],
            cwd=tree,
            env=env,
            stdout=handle,
            stderr=subprocess.STDOUT,
        )


def stop_node(process: subprocess.Popen) -> int:
    """Stop the node with SIGINT; return its exit code."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            return process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
    return process.wait()


def time_to_answer(probe: Probe, process: subprocess.Popen, start: float) -> float:
    """Return the seconds from `start` to the node's first answer to GetParameters."""
    while time.perf_counter() - start < TIMEOUT_S and process.poll() is None:
        if probe.call('get', timeout_s=1.0) is not None:
            return time.perf_counter() - start
    return float('nan')


def _cloud(points: np.ndarray, sec: int):
    from mvbb_ros.ros.encode import create_cloud_xyz

    cloud = create_cloud_xyz(points, frame_id='camera')
    cloud.header.stamp.sec = sec
    return cloud


def _peak_rss(pid: int) -> int:
    """Return the process's peak resident memory (VmHWM), bytes."""
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmHWM:'):
            return int(line.split()[1]) * 1024
    return 0


def _percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float('nan')


def blobs_frame(probe: Probe, folder: Path, frames: int) -> bool:
    """Run the 300-blob cloud `frames` times through the node, calling its parameter services."""
    from abuse import blobs_cloud
    from support.shapes import l_shape_points

    log = folder / 'node_blobs.log'
    start = time.perf_counter()
    process = start_node(ROOT, log)
    ok = True
    try:
        started = time_to_answer(probe, process, start)
        print(f'node started (warm cache) and answered GetParameters after {started:.2f} s')
        warm = _cloud(l_shape_points(count=2000), 1)
        deadline = time.perf_counter() + 60.0
        while probe.answered(1) is None and time.perf_counter() < deadline:
            probe.publisher.publish(warm)
            probe.spin_for(0.5)
        assert probe.answered(1) is not None, 'the node did not answer the first cloud'
        probe.spin_for(1.0)
        node = psutil.Process(process.pid)
        before = node.memory_info().rss
        samples: list[int] = []
        done = threading.Event()

        def sample() -> None:
            while not done.is_set():
                try:
                    samples.append(node.memory_info().rss)
                except psutil.Error:
                    return
                time.sleep(0.02)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        log_start = log.stat().st_size
        latencies: dict[str, list[float]] = {'get': [], 'list': []}
        unanswered = 0
        idle: list[float] = []  # the peer: the same calls to the idle node, same load
        for number in range(IDLE_CALLS):
            latency = probe.call(('get', 'list')[number % 2], timeout_s=TIMEOUT_S)
            if latency is not None:
                idle.append(latency)
            probe.spin_for(CALL_PERIOD_S)
        blobs = blobs_cloud()
        frame_times: list[float] = []
        answered: float | None = None
        calls = 0
        for sec in range(2, 2 + frames):  # a new stamp each time: one answer per frame
            published = time.perf_counter()
            probe.publisher.publish(_cloud(blobs, sec))
            while probe.answered(sec) is None and time.perf_counter() - published < TIMEOUT_S:
                kind = ('get', 'list')[calls % 2]
                latency = probe.call(kind, timeout_s=TIMEOUT_S)
                calls += 1
                if latency is None:
                    unanswered += 1
                else:
                    latencies[kind].append(latency)
                probe.spin_for(CALL_PERIOD_S)
            answered = probe.answered(sec)
            if answered is None:
                break
            frame_times.append(answered - published)
            probe.spin_for(1.0)  # the node idles between frames
        probe.spin_for(2.5)  # the diagnostics come once a second
        done.set()
        sampler.join()
        peak = _peak_rss(process.pid)
        with open(log) as handle:
            handle.seek(log_start)
            node_lines = [line.rstrip() for line in handle if line.strip()]
        after = [m for t, m in probe.diagnostics if answered is not None and t > answered]
    finally:
        code = stop_node(process)
    both = latencies['get'] + latencies['list']
    print()
    print('300 small blobs, 60k points, 1.7 m across, node defaults, through the running node')
    print('| figure | value |\n| --- | --- |')
    print(
        f'| frame time (publish to grasps received): median, max of {len(frame_times)} | '
        f'{_percentile(frame_times, 50):.2f}, {max(frame_times, default=float("nan")):.2f} s |'
    )
    print(
        f'| node RSS before the frame / sampled max / peak (VmHWM) | {before / 2**20:.0f} / '
        f'{max(samples, default=0) / 2**20:.0f} / {peak / 2**20:.0f} MiB |'
    )
    for kind, name in (('get', 'GetParameters'), ('list', 'ListParameters')):
        values = latencies[kind]
        print(
            f'| {name} during the frame: calls, median, p95, max | {len(values)}, '
            f'{1e3 * _percentile(values, 50):.1f}, {1e3 * _percentile(values, 95):.1f}, '
            f'{1e3 * max(values, default=float("nan")):.1f} ms |'
        )
    print(
        f'| both, the idle node (peer, before the frames): calls, median, p95, max | {len(idle)}, '
        f'{1e3 * _percentile(idle, 50):.1f}, {1e3 * _percentile(idle, 95):.1f}, '
        f'{1e3 * max(idle, default=float("nan")):.1f} ms |'
    )
    slow_idle = sum(1 for value in idle if value > TARGET_S)
    print(f'| idle calls over {TARGET_S * 1e3:.0f} ms | {slow_idle} |')
    over = sum(1 for value in both if value > TARGET_S)
    print(f'| calls over {TARGET_S * 1e3:.0f} ms / unanswered | {over} / {unanswered} |')
    print(f'| node exit code on SIGINT | {code} |')
    print()
    print(f"the node's log lines during the frame: {len(node_lines)}")
    for line in node_lines:
        print(f'  {line[:400]}')
    if after:
        status = after[0].status[0]
        values = {item.key: item.value for item in status.values}
        keys = (
            'input_points',
            'filtered_points',
            'boxes',
            'grasps',
            'processing_ms',
            'capped',
            'completion_skipped',
            'no_grasps_because',
            'clouds_received',
            'clouds_processed',
            'clouds_skipped_busy',
            'frame_budget',
        )
        level = int.from_bytes(status.level, 'little')
        print(f'diagnostics after the frame: level {level} ({status.message})')
        for key in keys:
            if key in values:
                text = values[key]
            if len(text) > 300:  # one note per object
                text = f'{text[:300]}... ({len(text)} characters)'
            print(f'  {key}: {text}')
    else:
        print('no diagnostics after the frame')
        ok = False
    return ok and code == 0 and len(frame_times) == frames


def _install_copy(folder: Path) -> Path:
    """Copy the package with its kernel cache (times kept, so the cache stays valid)."""
    root = folder / 'install'
    shutil.copytree(ROOT / 'mvbb_ros', root / 'mvbb_ros', symlinks=True)
    (root / 'home').mkdir()
    return root


def starts(probe: Probe, folder: Path) -> bool:
    """Time the node's start from a copied install: as is, with a torn cache, read-only."""
    from support.mounts import read_only_command

    root = _install_copy(folder)
    home = folder / 'home'
    home.mkdir()
    rows = []
    ok = True

    def one(name: str, **kwargs) -> None:
        nonlocal ok
        log = folder / f'node_{len(rows)}.log'
        start = time.perf_counter()
        process = start_node(root, log, **kwargs)
        seconds = time_to_answer(probe, process, start)
        code = stop_node(process)
        text = log.read_text()
        said = [
            line.strip()
            for line in text.splitlines()
            if any(word in line for word in ('KernelCacheWarning', 'compiling', 'cannot write'))
            or 'Traceback' in line
        ]
        warning = 'KernelCacheWarning'
        said = [warning + line.split(warning, 1)[1] if warning in line else line for line in said]
        rows.append((name, seconds, code, said))
        ok = ok and seconds == seconds and code == 0 and 'Traceback' not in text

    one('warm copy of the install')
    one('warm copy again')
    (torn,) = (root / 'mvbb_ros').glob(TORN_INDEX)
    torn.write_bytes(torn.read_bytes()[:10])
    one(f'{torn.name} cut to 10 bytes')
    one('the start after (healed)')
    prefix = read_only_command(root)
    one('read-only install, read-only HOME', home=root / 'home', prefix=prefix)
    print()
    print('start to the first GetParameters answer (python -m mvbb_ros.ros.decomposer)')
    print('| start | seconds | exit code on SIGINT | what it said |\n| --- | --- | --- | --- |')
    for name, seconds, code, said in rows:
        print(f'| {name} | {seconds:.2f} | {code} | {" / ".join(said)[:300] or "-"} |')
    return ok


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--only', choices=('blobs', 'starts'), help='one part only')
    parser.add_argument(
        '--frames', type=int, default=5, help='times the blob cloud is sent (default 5)'
    )
    args = parser.parse_args()
    os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(1, 101))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    print(
        f'load average {" ".join(f"{v:.2f}" for v in os.getloadavg())}, '
        f'{os.cpu_count()} CPUs, ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}'
    )
    probe = Probe()
    ok = True
    try:
        with tempfile.TemporaryDirectory(prefix='abuse_node_') as name:
            folder = Path(name)
            if args.only in (None, 'blobs'):
                ok = blobs_frame(probe, folder, args.frames) and ok
            if args.only in (None, 'starts'):
                ok = starts(probe, folder) and ok
    finally:
        probe.close()
    print(f'load average at the end {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
