"""
Tests of `mvbb fleet`: many bags on Ray, the same bytes as serial `mvbb bag process`.

The bags are the demo's scenes (the project's own ray-cast views), written with the project's
bag writer in MCAP and sqlite3, plus a corrupt and a missing one. The quick tests run an embedded
local Ray; the slow ones start a two-node Ray cluster on 127.0.0.1 (`ray start`, each node one
CPU) and kill a worker process in the middle of a bag, or interrupt the run with SIGINT.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

from mvbb_ros.cli.demo import demo_clouds, DEMO_FRAME, DEMO_TOPIC
from mvbb_ros.cli.main import main
from mvbb_ros.fleet.inputs import expand_inputs, InputError, Setting, sweep_settings
from mvbb_ros.fleet.run import check_output_folder, FleetError, make_jobs
from mvbb_ros.fleet.tasks import completed_rows, settings_digest, STAGING
from mvbb_ros.pipeline.settings import PipelineSettings, PRESETS
from mvbb_ros.ros.bag import CloudBag, jazzy_typestore, write_cloud_bag
import pyarrow.parquet as pq
import pytest
from support.data import REPO_ROOT
from support.trees import same_tree

RAY = Path(sys.executable).with_name('ray')
#: Bags of the quick run: name -> (frames, seed, storage).
BAGS = {
    'scene_mcap': (4, 3, 'mcap'),
    'scene_sqlite': (3, 4, 'sqlite3'),
    'scene_long': (8, 5, 'mcap'),  # cut into time ranges of 3 clouds
}
RANGE_CLOUDS = 3


def _write_bag(path: Path, frames: int, seed: int, storage: str) -> Path:
    write_cloud_bag(path, DEMO_TOPIC, DEMO_FRAME, demo_clouds(frames, seed=seed), storage=storage)
    return path


def _serial(bag: Path, folder: Path, *args: str) -> Path:
    """Run `mvbb bag process` on `bag` into ``folder/<name>``: the reference output."""
    target = folder / bag.name
    assert main(['bag', 'process', str(bag), str(target), '--quiet', *args]) == 0
    return target


def _grasp_counts(bag: Path) -> list[int]:
    """Return the number of poses of each /decomposer/grasps message of an output bag."""
    with CloudBag(bag) as reader:
        store = jazzy_typestore()
        return [
            len(store.deserialize_cdr(raw, connection.msgtype).poses)
            for connection, _, raw in reader.reader.messages()
            if connection.topic == '/decomposer/grasps'
        ]


def _summary(folder: Path) -> list[dict]:
    return pq.read_table(folder / 'summary.parquet').to_pylist()


@pytest.fixture(scope='module')
def bags(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp('bags')
    made = {name: _write_bag(folder / name, *spec) for name, spec in BAGS.items()}
    corrupt = folder / 'corrupt'
    shutil.copytree(made['scene_mcap'], corrupt)
    data = next(corrupt.glob('*.mcap'))
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])  # truncated mid-bag
    made['corrupt'] = corrupt
    made['missing'] = folder / 'missing.bag'
    return made


@pytest.fixture(scope='module')
def serial(bags, tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp('serial')
    return {name: _serial(bags[name], folder) for name in BAGS}


@pytest.fixture(scope='module')
def fleet_run(bags, tmp_path_factory):
    """One fleet run over the good, the corrupt and the missing bag, two local workers."""
    output = tmp_path_factory.mktemp('fleet') / 'out'
    manifest = output.parent / 'bags.txt'
    manifest.write_text(f'# the fleet\n{bags["scene_sqlite"]}\n{bags["corrupt"].name}\n')
    shutil.copytree(bags['corrupt'], output.parent / bags['corrupt'].name)
    inputs = [
        str(bags['scene_mcap']),
        str(manifest),
        str(bags['scene_long']),
        str(bags['missing']),
    ]
    start = time.perf_counter()
    code = main(
        ['fleet', *inputs, '--output', str(output), '--workers', '2']
        + ['--clouds-per-range', str(RANGE_CLOUDS)]
    )
    return output, code, time.perf_counter() - start


@pytest.mark.slow
def test_outputs_are_the_bytes_of_serial_bag_process(fleet_run, serial):
    output, _, _ = fleet_run
    for name, reference in serial.items():
        assert same_tree(output / name, reference), f'{name} differs from serial bag process'
    rows = [row for row in _summary(output) if row['bag'] == 'scene_long']
    assert rows[0]['ranges'] == 3, 'the long bag was not cut into time ranges'
    assert [row['index'] for row in rows] == list(range(BAGS['scene_long'][0]))


def test_bad_bags_are_reported_and_the_others_done(fleet_run, bags, serial, tmp_path):
    output, code, _ = fleet_run
    assert code == 1  # a bag failed, another was truncated
    rows = _summary(output)
    failed = {row['bag']: row['note'] for row in rows if row['status'] == 'failed'}
    assert set(failed) == {'missing'}
    assert 'bag not found' in failed['missing'] and 'missing.bag' in failed['missing']
    assert not (output / 'missing').exists()
    # The bag cut short keeps the clouds before the break, as `bag process` keeps them.
    truncated = {row['bag']: row['note'] for row in rows if row['status'] == 'truncated'}
    assert set(truncated) == {'corrupt'} and 'corrupt' in truncated['corrupt']
    reference = tmp_path / 'corrupt'
    assert main(['bag', 'process', str(bags['corrupt']), str(reference), '--quiet']) == 1
    assert same_tree(output / 'corrupt', reference), 'differs from serial bag process'
    kept = sum(1 for row in rows if row['bag'] == 'corrupt' and row['status'] == 'processed')
    done = {row['bag'] for row in rows if row['status'] == 'processed'}
    assert done == set(BAGS) | ({'corrupt'} if kept else set())
    clouds = sum(spec[0] for spec in BAGS.values()) + kept
    assert sum(1 for row in rows if row['status'] == 'processed') == clouds


def test_summary_has_a_row_per_cloud_in_both_formats_and_a_picture(fleet_run, serial):
    output, _, _ = fleet_run
    rows = _summary(output)
    for name, reference in serial.items():
        written = [row['grasps'] for row in rows if row['bag'] == name]
        assert written == _grasp_counts(reference), f'{name}: grasps differ from the bag'
    with open(output / 'summary.csv') as handle:
        csv_rows = list(csv.DictReader(handle))
    assert len(csv_rows) == len(rows)
    assert [row['bag'] for row in csv_rows] == [row['bag'] for row in rows]
    for row in rows:
        if row['status'] == 'processed':
            assert row['points'] > 0 and row['objects'] >= 1 and row['boxes'] >= 1
            assert row['done_s'] > 0 and row['retries'] == 0
            assert (row['grasps'] > 0) == (row['top_score'] == row['top_score'])  # NaN: none
    assert (output / 'summary.png').stat().st_size > 10_000
    assert not (output / STAGING).exists()
    assert not [path for path in output.iterdir() if path.name.startswith('.')]


def test_a_rerun_resumes_skipping_complete_outputs(fleet_run, bags, capsys):
    output, _, _ = fleet_run
    stamps = {name: (output / name / 'metadata.yaml').stat().st_mtime_ns for name in BAGS}
    capsys.readouterr()
    start = time.perf_counter()
    code = main(['fleet', *(str(bags[name]) for name in BAGS), '--output', str(output)])
    seconds = time.perf_counter() - start
    assert code == 0
    assert (
        f'{len(BAGS)} bag outputs complete with the same settings: skipped'
        in capsys.readouterr().out
    )
    assert {name: (output / name / 'metadata.yaml').stat().st_mtime_ns for name in BAGS} == stamps
    rows = _summary(output)
    assert {row['status'] for row in rows} == {'resumed'}
    assert len(rows) == sum(spec[0] for spec in BAGS.values())
    assert seconds < 30, 'a resumed run should not start Ray or process anything'


def test_other_settings_or_a_changed_input_do_not_resume(fleet_run, bags, tmp_path):
    output, _, _ = fleet_run
    options = {'topics': (), 'namespace': '/decomposer', 'storage': 'mcap', 'compress': False}
    grid = [Setting('', PRESETS['node'])]
    job = make_jobs([bags['scene_mcap']], grid, output, options)[0]
    assert completed_rows(job) is not None, 'the same settings must resume'
    other = [Setting('', PRESETS['node'].updated({'gain_threshold': 0.9}))]
    assert completed_rows(make_jobs([bags['scene_mcap']], other, output, options)[0]) is None
    copy = tmp_path / 'scene_mcap'
    shutil.copytree(bags['scene_mcap'], copy)
    data = next(copy.glob('*.mcap'))
    os.utime(data, ns=(data.stat().st_atime_ns, data.stat().st_mtime_ns + 10**9))
    assert completed_rows(make_jobs([copy], grid, output, options)[0]) is None


@pytest.mark.slow
def test_a_sweep_writes_one_output_per_setting_and_one_summary(bags, tmp_path):
    output = tmp_path / 'sweep'
    bag = bags['scene_sqlite']
    code = main(
        ['fleet', str(bag), '--output', str(output), '--workers', '2', '--no-picture']
        + ['--sweep', 'gain_threshold=0.9,0.98']
    )
    assert code == 0
    rows = _summary(output)
    assert {row['setting'] for row in rows} == {'gain_threshold=0.9', 'gain_threshold=0.98'}
    frames = BAGS['scene_sqlite'][0]
    assert len(rows) == 2 * frames
    boxes = {
        label: sum(r['boxes'] for r in rows if r['setting'] == label)
        for label in ('gain_threshold=0.9', 'gain_threshold=0.98')
    }
    assert boxes['gain_threshold=0.9'] <= boxes['gain_threshold=0.98']
    reference = _serial(bag, tmp_path / 'serial', '-p', 'gain_threshold:=0.9')
    assert same_tree(output / 'gain_threshold=0.9' / bag.name, reference)
    assert not (output / 'summary.png').exists()


def test_an_unwritable_output_folder_is_a_clear_error(bags, tmp_path, capsys):
    blocker = tmp_path / 'a_file'
    blocker.write_text('not a folder')
    with pytest.raises(FleetError, match='cannot write to the output folder .*a_file/out'):
        check_output_folder(blocker / 'out')
    code = main(['fleet', str(bags['scene_mcap']), '--output', str(blocker / 'out')])
    assert code == 1
    assert 'mvbb fleet: error: cannot write to the output folder' in capsys.readouterr().err


def test_inputs_from_paths_globs_folders_and_manifests(bags, tmp_path):
    folder = bags['scene_mcap'].parent
    assert expand_inputs([folder]) == sorted(
        [bags[name] for name in ('corrupt', *BAGS)], key=lambda path: path.name
    )
    assert expand_inputs([str(folder / 'scene_*')]) == [
        bags['scene_long'],
        bags['scene_mcap'],
        bags['scene_sqlite'],
    ]
    manifest = tmp_path / 'list.txt'
    manifest.write_text(f'{bags["scene_mcap"]}\n  # a comment\n\n{bags["scene_mcap"]}\nnope.bag\n')
    assert expand_inputs([manifest]) == [bags['scene_mcap'], tmp_path / 'nope.bag']
    with pytest.raises(InputError, match='matches nothing'):
        expand_inputs([str(tmp_path / 'none_*.bag')])
    (tmp_path / 'empty').mkdir()
    with pytest.raises(InputError, match='holds no bag'):
        expand_inputs([tmp_path / 'empty'])
    twin = tmp_path / 'twin'
    shutil.copytree(bags['scene_mcap'], twin / 'scene_mcap')
    with pytest.raises(InputError, match='same name'):
        make_jobs(
            [bags['scene_mcap'], twin / 'scene_mcap'],
            [Setting('', PipelineSettings())],
            tmp_path / 'o',
            {},
        )


def test_sweeps_make_a_grid_and_refuse_bad_values():
    grid = sweep_settings(PipelineSettings(), ['gain_threshold=0.9,0.95', 'min_points=10,20'])
    assert [s.label for s in grid] == [
        'gain_threshold=0.9,min_points=10',
        'gain_threshold=0.9,min_points=20',
        'gain_threshold=0.95,min_points=10',
        'gain_threshold=0.95,min_points=20',
    ]
    assert grid[3].settings.decomposition.gain_threshold == 0.95
    assert grid[3].settings.decomposition.min_points == 20
    with pytest.raises(InputError, match='gain_threshold=7'):
        sweep_settings(PipelineSettings(), ['gain_threshold=7'])
    with pytest.raises(InputError, match='NAME=V1'):
        sweep_settings(PipelineSettings(), ['gain_threshold'])


@pytest.mark.slow
def test_the_node_and_the_demo_do_not_load_ray():
    """Ray is the fleet's alone: the node, the bag tools and the demo never import it."""
    probe = (
        'import sys\n'
        'import mvbb_ros.ros.decomposer, mvbb_ros.ros.node, mvbb_ros.ros.offline\n'
        'import mvbb_ros.ros.bag_play, mvbb_ros.ros.demo_graph, mvbb_ros.cli.demo\n'
        'import mvbb_ros.cli.main\n'
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'ray'))\n"
    )
    result = subprocess.run(
        [sys.executable, '-c', probe], cwd=REPO_ROOT, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == '[]'


# A Ray cluster of two nodes on this machine (slow: starting it takes about 15 s) -------------


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return int(probe.getsockname()[1])


def _wait_for_line(log: Path, text: str, process: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if log.exists() and text in log.read_text(errors='replace'):
            return
        assert process.poll() is None, (
            f'ray start ended: {log.read_text(errors="replace")[-2000:]}'
        )
        time.sleep(0.5)
    raise AssertionError(f'no {text!r} in {log} after {timeout_s} s')


def _processes_of(folder: Path) -> list[int]:
    """Return the processes whose command line names `folder` (this test's Ray session)."""
    import psutil

    found = []
    for process in psutil.process_iter(['pid', 'cmdline']):
        try:
            if any(str(folder) in part for part in process.info['cmdline'] or ()):
                found.append(process.pid)
        except psutil.Error:
            continue
    return found


@pytest.fixture
def ray_cluster():
    """
    Start a head and a worker node (`ray start --block`, one CPU each) on 127.0.0.1.

    Teardown stops exactly these: SIGTERM to the two `ray start --block` processes (which stop
    their own children), then SIGKILL to any process left that names this session's folder.
    `ray stop` is not used: it stops every Ray of the machine, other users' too.
    """
    temp = Path(tempfile.mkdtemp(prefix='rt', dir='/tmp'))  # short: Ray's socket paths
    port = _free_port()
    env = dict(
        os.environ,
        RAY_USAGE_STATS_ENABLED='0',
        RAY_AUTH_MODE='disabled',
        PYTHONPATH=str(REPO_ROOT),
    )
    common = [
        '--node-ip-address=127.0.0.1',
        '--num-cpus=1',
        f'--temp-dir={temp}',
        '--object-store-memory=200000000',
        '--block',
    ]
    nodes: list[subprocess.Popen] = []
    try:
        for name, first in (
            ('head', ['--head', f'--port={port}', '--include-dashboard=false']),
            ('worker', [f'--address=127.0.0.1:{port}']),
        ):
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
            _wait_for_line(log, 'Ray runtime started', nodes[-1], 120)
        yield f'127.0.0.1:{port}', env, temp
    finally:
        for node in reversed(nodes):
            node.send_signal(signal.SIGTERM)
        for node in reversed(nodes):
            try:
                node.wait(timeout=30)
            except subprocess.TimeoutExpired:
                node.kill()
        for pid in _processes_of(temp):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        shutil.rmtree(temp, ignore_errors=True)


def _marker(output: Path, name: str, task: str = 'bag') -> Path:
    return output / STAGING / '_' / name / f'{task}.attempt-1'


def _wait_for(path: Path, process: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert process.poll() is None, f'the fleet ended before {path} appeared'
        assert time.monotonic() < deadline, f'{path} did not appear in {timeout_s} s'
        time.sleep(0.05)


@pytest.mark.slow
def test_a_worker_killed_mid_bag_is_retried_and_its_bag_written_once(ray_cluster, tmp_path):
    address, env, _ = ray_cluster
    long = [_write_bag(tmp_path / f'long_{k}', 30, 10 + k, 'mcap') for k in range(2)]
    output = tmp_path / 'out'
    fleet = subprocess.Popen(
        [sys.executable, '-m', 'mvbb_ros.cli.main', 'fleet', *map(str, long)]
        + ['--output', str(output), '--cluster', address],
        env=env,
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        marker = _marker(output, long[0].name)
        _wait_for(marker, fleet, 240)
        time.sleep(1.0)  # into the bag: 30 clouds take several seconds
        assert not (output / long[0].name).exists(), 'the bag ended before the kill'
        host, pid = marker.read_text().split()
        assert host == socket.gethostname()
        os.kill(int(pid), signal.SIGKILL)
        text, _ = fleet.communicate(timeout=400)
    finally:
        if fleet.poll() is None:
            fleet.kill()
    assert fleet.returncode == 0, text
    assert '1 retries' in text or 'retries' in text
    rows = _summary(output)
    retries = {row['bag']: row['retries'] for row in rows}
    assert retries == {long[0].name: 1, long[1].name: 0}
    assert len(rows) == 60 and {row['status'] for row in rows} == {'processed'}
    serial = tmp_path / 'serial'
    for bag in long:
        assert same_tree(output / bag.name, _serial(bag, serial)), f'{bag.name} differs'
    assert not [path.name for path in output.iterdir() if path.name.startswith('.')]


def _ctrl_c_as_in_a_terminal() -> None:
    """
    Give the child Python's own Ctrl-C (KeyboardInterrupt), whatever the test runner's is.

    A shell runs a command started with ``&`` with SIGINT ignored, and Python keeps an ignored
    SIGINT ignored: a test run launched that way would see the fleet finish through the
    interrupt, with exit code 0.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_ctrl_c_leaves_no_half_written_output_and_a_rerun_completes(bags, tmp_path):
    inputs = [_write_bag(tmp_path / f'bag_{k}', 12, 20 + k, 'mcap') for k in range(4)]
    output = tmp_path / 'out'
    command = [sys.executable, '-m', 'mvbb_ros.cli.main', 'fleet', *map(str, inputs)]
    command += ['--output', str(output), '--workers', '2']
    fleet = subprocess.Popen(
        command,
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        preexec_fn=_ctrl_c_as_in_a_terminal,
    )
    try:
        _wait_for(output / STAGING, fleet, 240)
        time.sleep(1.5)
        os.killpg(fleet.pid, signal.SIGINT)  # as Ctrl-C in a terminal: the whole group
        text, _ = fleet.communicate(timeout=120)
    finally:
        if fleet.poll() is None:
            os.killpg(fleet.pid, signal.SIGKILL)
    assert fleet.returncode == 130, text
    assert 'interrupted' in text
    serial = tmp_path / 'serial'
    finished = [bag for bag in inputs if (output / bag.name).exists()]
    assert len(finished) < len(inputs), 'the run ended before the interrupt'
    for bag in finished:
        assert same_tree(output / bag.name, _serial(bag, serial)), f'{bag.name} is half-written'
    assert not [path.name for path in output.iterdir() if path.name.startswith('.bag_')]
    assert main(['fleet', *map(str, inputs), '--output', str(output), '--workers', '2']) == 0
    for bag in inputs:
        reference = serial / bag.name
        if not reference.exists():
            _serial(bag, serial)
        assert same_tree(output / bag.name, reference)
    statuses = {row['bag']: row['status'] for row in _summary(output)}
    assert {statuses[bag.name] for bag in finished} <= {'resumed'}


def test_the_settings_digest_ignores_the_worker_threads(bags):
    base = PipelineSettings()
    bag = next(iter(bags.values()))
    digest = settings_digest(bag, base.updated({'workers': 1}), {})
    assert settings_digest(bag, base.updated({'workers': 3}), {}) == digest
    assert settings_digest(bag, base.updated({'gain_threshold': 0.9}), {}) != digest
