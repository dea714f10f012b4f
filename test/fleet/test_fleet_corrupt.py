"""
`mvbb fleet` skips the messages that do not deserialize as `mvbb bag process` does.

Two bags with spoiled messages (bytes cut short, random bytes): one long enough to be cut into
time ranges (its ranges rebuild the grasp memory, and a spoiled message falls in a warm-up),
one processed whole. Each output must hold the bytes a serial `bag process` writes, and the
summary must name every skipped message once. One embedded Ray run, one worker.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

from mvbb_ros.cli.main import main
import pyarrow.parquet as pq
import pytest
from support.bags import bag_stamp, TOPIC, write_cloud_bag
from support.trees import same_tree

#: name -> (messages, {position: how it is spoiled}, storage).
BAGS = {
    'ranged': (7, {2: 'cut short', 5: 'random bytes'}, 'mcap'),
    'whole': (3, {1: 'random bytes'}, 'sqlite3'),
}
#: Clouds per time range: the 7-message bag is cut into 3 ranges, the 3-message one is not.
RANGE_CLOUDS = 3


def _write_bag(path: Path, messages: int, spoiled: dict[int, str], storage: str) -> Path:
    return write_cloud_bag(path, storage, messages, points=400, spoiled=spoiled)


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    """Write the bags, run `bag process` on each, then one fleet run over both."""
    folder = tmp_path_factory.mktemp('corrupt_fleet')
    bags = {name: _write_bag(folder / name, *spec) for name, spec in BAGS.items()}
    serial: dict[str, Path] = {}
    for name, bag in bags.items():
        serial[name] = folder / 'serial' / name
        assert main(['bag', 'process', str(bag), str(serial[name]), '--quiet']) == 0
    output = folder / 'fleet'
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(
            ['fleet', *(str(bag) for bag in bags.values()), '--output', str(output)]
            + ['--workers', '1', '--clouds-per-range', str(RANGE_CLOUDS), '--no-picture']
        )
    return serial, output, code, printed.getvalue()


def test_fleet_skips_corrupt_messages_with_the_bytes_of_bag_process(runs):
    serial, output, code, out = runs
    assert code == 0, out
    for name, reference in serial.items():
        assert same_tree(output / name, reference), f'{name} differs from serial bag process'
    rows = pq.read_table(output / 'summary.parquet').to_pylist()
    assert {row['ranges'] for row in rows if row['bag'] == 'ranged'} == {3}
    assert {row['ranges'] for row in rows if row['bag'] == 'whole'} == {1}
    for name, (messages, spoiled, _) in BAGS.items():
        clouds = [row for row in rows if row['bag'] == name and row['status'] == 'processed']
        assert [row['timestamp_ns'] for row in clouds] == [
            bag_stamp(p) for p in range(messages) if p not in spoiled
        ]
        assert [row['index'] for row in clouds] == list(range(messages - len(spoiled)))
        skipped = [row for row in rows if row['bag'] == name and row['status'] == 'skipped']
        assert [(row['topic'], row['timestamp_ns']) for row in skipped] == [
            (TOPIC, bag_stamp(p)) for p in sorted(spoiled)
        ], 'each skipped message named once, by bag time, also when it falls in a warm-up'
        assert all(row['note'].startswith('skipped: does not deserialize') for row in skipped)
    total = sum(len(spec[1]) for spec in BAGS.values())
    assert f'skipped {total} messages that do not deserialize' in out
