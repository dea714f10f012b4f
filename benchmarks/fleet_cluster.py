"""
Benchmark `mvbb fleet` with 1 and 2 workers on a two-node Ray cluster on this machine.

Each node is a `ray start --block` with one CPU in its own session, as two machines would be
(the kernel shares CPU time between sessions first, so an embedded Ray's workers, all in the
command's session, cannot show what a second machine adds on a machine busy with other work).
It reuses the bags and the serial outputs of ``benchmarks/fleet.py`` (run that first), runs
``--workers 1`` and ``--workers 2`` in turn twice, and prints one table row per run. The nodes
are stopped by their process ids (not `ray stop`, which stops every Ray of the machine).

Usage::

    .venv/bin/python benchmarks/fleet_cluster.py [--out out/fleet_bench] [--port 6398]
"""

from __future__ import annotations

import argparse
import filecmp
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import psutil
import pyarrow.parquet as pq

REPO = Path(__file__).resolve().parents[1]
RAY = Path(sys.executable).with_name('ray')
TOPICS = ('/segmented_object', '/luminar_pointcloud', '/demo/segmented_objects')


def load() -> str:
    """Return the load averages."""
    return ' '.join(Path('/proc/loadavg').read_text().split()[:3])


def same(left: Path, right: Path) -> bool:
    """Return whether two folders hold the same files with the same bytes."""
    names = sorted(x.name for x in left.iterdir())
    if names != sorted(x.name for x in right.iterdir()):
        return False
    return all(filecmp.cmp(left / name, right / name, shallow=False) for name in names)


def main() -> int:
    """Start the two nodes, run the fleet four times, stop the nodes."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[1])
    parser.add_argument('--out', type=Path, default=REPO / 'out' / 'fleet_bench')
    parser.add_argument('--port', type=int, default=6398)
    args = parser.parse_args()
    bench, port = args.out, args.port
    temp = Path(tempfile.mkdtemp(prefix='rt', dir='/tmp'))  # short: Ray's socket paths
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED='0', RAY_AUTH_MODE='disabled')
    env['PYTHONPATH'] = str(REPO)
    common = ['--node-ip-address=127.0.0.1', '--num-cpus=1', f'--temp-dir={temp}']
    common += ['--object-store-memory=200000000', '--block']
    nodes: list[subprocess.Popen] = []
    starts = (
        ('head', ['--head', f'--port={port}', '--include-dashboard=false']),
        ('worker', [f'--address=127.0.0.1:{port}']),
    )
    try:
        for name, first in starts:
            log = temp / f'{name}.log'
            with open(log, 'w') as handle:
                nodes.append(
                    subprocess.Popen(
                        [str(RAY), 'start', *first, *common],
                        env=env,
                        stdout=handle,
                        stderr=subprocess.STDOUT,
                        start_new_session=True,
                    )
                )
            while 'Ray runtime started' not in (log.read_text() if log.exists() else ''):
                time.sleep(0.5)
        print(
            '| workers | wall s | clouds/s (whole run) | clouds/s (first to last cloud) '
            "| load before | load after | identical | workers' CPU share |",
            flush=True,
        )
        for repeat in range(2):
            for workers in (1, 2):
                out = bench / f'cluster{repeat}_w{workers}'
                shutil.rmtree(out, ignore_errors=True)
                before, start = load(), time.perf_counter()
                cmd = [sys.executable, '-m', 'mvbb_ros.cli.main', 'fleet', str(bench / 'bags.txt')]
                cmd += ['--output', str(out), '--cluster', f'127.0.0.1:{port}']
                cmd += ['--workers', str(workers)]
                for topic in TOPICS:
                    cmd += ['--topic', topic]
                run = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True)
                wall = time.perf_counter() - start
                rows = pq.read_table(out / 'summary.parquet').to_pylist()
                done = sorted(row['done_s'] for row in rows)
                lines = run.stdout.splitlines()
                busy = next((line for line in lines if line.startswith('workers: ')), '')
                share = busy.split('(')[1].split(':')[0] if '(' in busy else '?'
                names = sorted({row['bag'] for row in rows})
                identical = sum(same(out / name, bench / 'serial' / name) for name in names)
                rate = (len(done) - 1) / (done[-1] - done[0])
                print(
                    f'| {workers} | {wall:.1f} | {len(done) / wall:.2f} | {rate:.2f} | {before} '
                    f'| {load()} | {identical}/{len(names)} | {share} |',
                    flush=True,
                )
    finally:
        for node in reversed(nodes):
            node.send_signal(signal.SIGTERM)
        for node in reversed(nodes):
            node.wait(timeout=60)
        for process in psutil.process_iter(['pid', 'cmdline']):
            try:
                if any(str(temp) in part for part in process.info['cmdline'] or ()):
                    os.kill(process.pid, signal.SIGKILL)
            except (psutil.Error, ProcessLookupError):
                pass
        shutil.rmtree(temp, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
