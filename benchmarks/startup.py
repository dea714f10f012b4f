"""
Warm start: process start of the `decomposer` to its input subscription matched, and a cold one.

    .venv/bin/python benchmarks/startup.py              # 5 warm starts and 1 cold start
    .venv/bin/python benchmarks/startup.py --starts 10 --no-cold

Each start runs the installed ``decomposer`` executable as its own process (what ``ros2 run``
does) while this process, already up, holds a publisher on ``cloud_in``; the time is from just
before the process is spawned to the moment the publisher sees the node's subscription
(discovery on this machine included). Then SIGINT, and the exit code is checked (0).

Warm: numba's cache as ``tools/bootstrap.sh`` left it. Cold: ``NUMBA_CACHE_DIR`` points to a new
empty folder, so every kernel is compiled (the node says so in one log line, which is shown);
the folder's size afterwards is the cache size. Also printed: how long importing the node's
module takes and whether it loads Open3D (it must not: importing Open3D alone is slow).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time

#: The issue's target, seconds from process start to subscription.
TARGET_S = 3.0


def folder_size(path: Path) -> int:
    """Return the bytes of the files under `path`."""
    return sum(item.stat().st_size for item in path.rglob('*') if item.is_file())


def one_start(publisher, node, environment: dict[str, str]) -> tuple[float, str, int]:
    """Start the decomposer; return seconds to the matched subscription, its log and exit code."""
    import rclpy

    executable = Path(sys.executable).parent / 'decomposer'
    start = time.perf_counter()
    process = subprocess.Popen(
        [str(executable)],
        env=environment,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = start + 300.0
    seconds = float('nan')
    try:
        while time.perf_counter() < deadline and process.poll() is None:
            if publisher.get_subscription_count() > 0:
                seconds = time.perf_counter() - start
                break
            rclpy.spin_once(node, timeout_sec=0.005)
    finally:
        process.send_signal(signal.SIGINT)
        try:
            output, _ = process.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            output, _ = process.communicate()
    # Wait until the subscription has left the graph, so that the next start is measured.
    while publisher.get_subscription_count() > 0 and time.perf_counter() < deadline:
        rclpy.spin_once(node, timeout_sec=0.01)
    return seconds, output, process.returncode


def import_time() -> tuple[float, bool]:
    """Return the seconds of importing the node's module in a new Python, and if Open3D came."""
    probe = (
        'import time, sys; start = time.perf_counter(); import mvbb_ros.ros.node; '
        "print(time.perf_counter() - start, 'open3d' in sys.modules)"
    )
    result = subprocess.run(
        [sys.executable, '-c', probe], capture_output=True, text=True, check=True
    )
    seconds, open3d = result.stdout.split()
    return float(seconds), open3d == 'True'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--starts', type=int, default=5, help='warm starts (default 5)')
    parser.add_argument('--no-cold', action='store_true', help='skip the cold start')
    args = parser.parse_args()

    os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    print(f'load average {" ".join(f"{value:.2f}" for value in os.getloadavg())}')
    imports = [import_time() for _ in range(3)]
    print(
        f'import mvbb_ros.ros.node: median {statistics.median(s for s, _ in imports):.2f} s; '
        f'loads Open3D: {any(open3d for _, open3d in imports)}'
    )
    rclpy.init()
    node = rclpy.create_node('startup_benchmark')
    publisher = node.create_publisher(
        PointCloud2, 'cloud_in', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
    )
    failures = 0
    try:
        warm = []
        for _ in range(args.starts):
            seconds, output, code = one_start(publisher, node, dict(os.environ))
            failures += code != 0 or 'compiling' in output
            warm.append(seconds)
        print(
            f'warm start to subscription: median {statistics.median(warm):.2f} s, max '
            f'{max(warm):.2f} s over {len(warm)} starts (target {TARGET_S:g} s); '
            + ', '.join(f'{value:.2f}' for value in warm)
        )
        if not args.no_cold:
            with tempfile.TemporaryDirectory() as folder:
                environment = {**os.environ, 'NUMBA_CACHE_DIR': folder}
                seconds, output, code = one_start(publisher, node, environment)
                failures += code != 0
                lines = [line for line in output.splitlines() if 'compiling' in line]
                said = lines[0].strip() if lines else '(no line)'
                print(f'cold start to subscription: {seconds:.2f} s; the node said: {said}')
                print(f'cache size: {folder_size(Path(folder)) / 2**20:.1f} MiB')
    finally:
        node.destroy_node()
        rclpy.shutdown()
    print('every start exited with 0 on SIGINT' if not failures else f'{failures} bad starts')
    return 1 if failures else 0


if __name__ == '__main__':
    sys.exit(main())
