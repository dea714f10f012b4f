"""
`mvbb fleet` keeps a truncated bag's readable clouds, as `mvbb bag process` keeps them.

Three bags whose storage fails partway: a sqlite3 and an MCAP file cut in the middle (a recorder
killed mid-write; the MCAP one long enough to be cut into time ranges, were its storage whole),
and a whole MCAP bag whose index (metadata.yaml) lists two more messages than it holds, which is
cut into time ranges and must be run again as one task. Each output must hold the bytes a serial
`bag process` writes (which keeps the clouds before the break and exits 1), the summary must say
where the storage failed, and the run must exit 1 with one `truncated:` line per bag, also when
a second run resumes the outputs. One embedded Ray run, one worker. The driver's choice for a
bag cut into ranges (assemble the ranges, or run the bag again as one task) is also checked on
range outcomes made here, as a range meeting a break mid-storage gives them.
"""

from __future__ import annotations

from collections import deque
import contextlib
import io
from pathlib import Path

from mvbb_ros.cli.main import main
from mvbb_ros.common.progress import ProgressBar
from mvbb_ros.fleet.run import _Driver, BagReport
from mvbb_ros.fleet.tasks import BagJob, Outcome, TimeRange
from mvbb_ros.pipeline.settings import PipelineSettings
import pyarrow.parquet as pq
import pytest
from support.bags import bag_stamp, cut_in_the_middle, promise_more, write_cloud_bag
from support.trees import same_tree

#: name -> (messages, storage, how the storage is spoiled).
BAGS = {
    'cut_sqlite': (6, 'sqlite3', 'cut'),
    'cut_long_mcap': (7, 'mcap', 'cut'),
    'index_promising_more': (7, 'mcap', 'promise'),
}
#: Clouds per time range: a whole 7-message bag is cut into 3 ranges.
RANGE_CLOUDS = 3


def _write_bag(path: Path, messages: int, storage: str, spoil: str) -> Path:
    # 1000 points (12 KB a message): a cut in the middle falls between clouds.
    bag = write_cloud_bag(path, storage, messages)
    return cut_in_the_middle(bag) if spoil == 'cut' else promise_more(bag, messages)


def _fleet(bags: dict[str, Path], output: Path) -> tuple[int, str, str]:
    printed, errors = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(errors):
        code = main(
            ['fleet', *(str(bag) for bag in bags.values()), '--output', str(output)]
            + ['--workers', '1', '--clouds-per-range', str(RANGE_CLOUDS), '--no-picture']
        )
    return code, printed.getvalue(), errors.getvalue()


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    """Write the bags, run `bag process` on each, then one fleet run over all of them."""
    folder = tmp_path_factory.mktemp('truncated_fleet')
    bags = {name: _write_bag(folder / name, *spec) for name, spec in BAGS.items()}
    serial: dict[str, tuple[Path, str]] = {}
    for name, bag in bags.items():
        target = folder / 'serial' / name
        errors = io.StringIO()
        with contextlib.redirect_stderr(errors):
            code = main(['bag', 'process', str(bag), str(target), '--quiet'])
        assert code == 1, f'{name}: serial bag process should stop at the break'
        serial[name] = (target, errors.getvalue())
    output = folder / 'fleet'
    return bags, serial, output, _fleet(bags, output)


def test_fleet_keeps_the_clouds_before_the_break_with_the_bytes_of_bag_process(runs):
    _, serial, output, (code, out, err) = runs
    assert code == 1, out + err
    assert 'Traceback' not in err
    rows = pq.read_table(output / 'summary.parquet').to_pylist()
    assert not [row for row in rows if row['status'] == 'failed'], rows
    for name, (reference, serial_err) in serial.items():
        assert same_tree(output / name, reference), f'{name} differs from serial bag process'
        clouds = [row for row in rows if row['bag'] == name and row['status'] == 'processed']
        kept = len(clouds)
        assert serial_err.rstrip().endswith(f'kept the {kept} clouds before it in {reference}')
        if BAGS[name][2] == 'cut':
            assert 0 < kept < BAGS[name][0], 'the cut falls between clouds, not before the first'
        else:
            assert kept == BAGS[name][0]
        assert [row['timestamp_ns'] for row in clouds] == [bag_stamp(p) for p in range(kept)]
        assert [row['index'] for row in clouds] == list(range(kept))
        truncated = [row for row in rows if row['bag'] == name and row['status'] == 'truncated']
        assert len(truncated) == 1 and rows.index(truncated[0]) > rows.index(clouds[-1])
        # The serial line names the same place: 'error: <where the storage failed>; kept ...'.
        where = truncated[0]['note'].rstrip('.')
        assert f'mvbb bag process: error: {where}; kept the {kept} clouds' in serial_err
        line = f'truncated: {name}: {where}; kept the {kept} clouds before it in {output / name}'
        assert line in err.splitlines(), err
    ranges = {row['bag']: row['ranges'] for row in rows}
    assert ranges['index_promising_more'] == 3, 'a whole storage is cut into time ranges'
    assert ranges['cut_long_mcap'] == 1, 'a storage file cut short is read from its start'
    assert not [path for path in output.iterdir() if path.name.startswith('.')]


def test_a_rerun_resumes_and_still_reports_the_truncation(runs):
    bags, serial, output, _ = runs
    stamps = {name: (output / name / 'metadata.yaml').stat().st_mtime_ns for name in BAGS}
    code, out, err = _fleet(bags, output)
    assert code == 1, out + err
    assert f'{len(BAGS)} bag outputs complete with the same settings: skipped' in out
    assert {name: (output / name / 'metadata.yaml').stat().st_mtime_ns for name in BAGS} == stamps
    assert sum(1 for line in err.splitlines() if line.startswith('truncated: ')) == len(BAGS)
    rows = pq.read_table(output / 'summary.parquet').to_pylist()
    assert {row['status'] for row in rows} == {'resumed', 'truncated'}
    assert sum(1 for row in rows if row['status'] == 'truncated') == len(BAGS)


def _ranged_driver(count: int) -> tuple[_Driver, BagReport, list[TimeRange]]:
    """Return a driver without Ray (only its dispatch state) with one bag in three ranges."""
    driver = object.__new__(_Driver)
    driver.queue, driver.ranges, driver.done = deque(), {}, 0
    driver.bar = ProgressBar(1, enabled=False)
    job = BagJob(Path('bag'), 'bag', '', Path('out/bag'), PipelineSettings(), {}, 'digest')
    report = BagReport(job, ranges=3)
    spans = [TimeRange(k, 10 * k, 10 * k + 10, max(0, 10 * k - 3)) for k in range(3)]
    driver.ranges[id(report)] = {
        'spans': spans,
        'outcomes': {},
        'verified': -1,
        'failed': False,
        'count': count,
    }
    return driver, report, spans


def _range_outcome(rows: int, memory: bytes = b'm', storage_error: str = '') -> Outcome:
    return Outcome(
        rows=[{'index': i} for i in range(rows)],
        start_memory=memory,
        end_memory=memory,
        storage_error=storage_error,
    )


def test_a_range_meeting_the_break_makes_the_bag_run_again_as_one_task():
    driver, report, spans = _ranged_driver(count=9)
    driver.handle(('range', report, spans[0]), _range_outcome(3))
    assert not driver.queue
    driver.handle(('range', report, spans[1]), _range_outcome(0, storage_error='cut at byte 9'))
    assert list(driver.queue) == [('bag', report)]
    driver.handle(('range', report, spans[2]), _range_outcome(3))  # read on past the break
    assert list(driver.queue) == [('bag', report)], 'no assembly from ranges after a break'
    assert report.status == 'processed' and not report.rows


def test_ranges_reading_fewer_clouds_than_the_index_lists_run_again_as_one_task():
    for count, queued in ((9, 'assemble'), (11, 'bag')):
        driver, report, spans = _ranged_driver(count=count)
        for span in spans:
            driver.handle(('range', report, span), _range_outcome(3))
        assert [task[0] for task in driver.queue] == [queued], count
