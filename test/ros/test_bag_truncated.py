"""
Bags whose storage breaks partway: `mvbb bag process` keeps what it processed before the break.

The bags are written here with rosbags (rosbag2 sqlite3 and MCAP), then cut short at a byte in
the middle of their storage file, the way a recorder killed mid-write or a full disk leaves them;
a third bag is whole but its index (metadata.yaml) promises more messages than it holds. Each
run must write a complete output bag holding exactly what a run over an intact bag of the clouds
before the break writes, print one line naming where the storage failed, and exit 1.
"""

from __future__ import annotations

from pathlib import Path

from mvbb_ros.cli.main import main
from mvbb_ros.ros.bag import BagStorageError, canonical_cdr, CloudBag
import pytest
from rosbags.highlevel import AnyReader
from support.bags import (
    bag_stamp,
    CLOUD,
    cut_in_the_middle,
    promise_more,
    TOPIC,
    write_cloud_bag,
)

#: Enough clouds (12 KB each) that a cut in the middle of the file falls between them.
MESSAGES = 12


def write_bag(path: Path, storage: str, count: int = MESSAGES) -> Path:
    """Write the first `count` clouds of the test bag; return the bag's path."""
    return write_cloud_bag(path, storage, count)


def _storage_file(bag: Path) -> Path:
    return next(path for path in bag.iterdir() if path.suffix in ('.db3', '.mcap'))


def _files(folder: Path) -> dict[str, bytes]:
    return {
        str(path.relative_to(folder)): path.read_bytes()
        for path in sorted(folder.rglob('*'))
        if path.is_file()
    }


def _stamps(bag: Path) -> dict[str, list[int]]:
    found: dict[str, list[int]] = {}
    with AnyReader([bag]) as reader:
        for connection, stamp, _ in reader.messages():
            found.setdefault(connection.topic, []).append(stamp)
    return found


def _process(source: Path, folder: Path, capsys) -> tuple[int, str, str, Path]:
    folder.mkdir()
    out = folder / 'out'  # the same name for every run: the outputs compare byte for byte
    code = main(['bag', 'process', str(source), str(out), '--no-progress', '-p', 'voxel_size:=0'])
    captured = capsys.readouterr()
    return code, captured.out, captured.err, out


BROKEN = {
    'sqlite3 cut in the middle': ('sqlite3', cut_in_the_middle),
    'mcap cut in the middle': ('mcap', cut_in_the_middle),
    'index promising more': ('mcap', lambda bag: promise_more(bag, MESSAGES)),
}


@pytest.mark.parametrize('case', BROKEN)
def test_process_keeps_the_clouds_before_the_break(tmp_path, case, capsys):
    storage, spoil = BROKEN[case]
    source = spoil(write_bag(tmp_path / 'input', storage))
    code, out, err, output = _process(source, tmp_path / 'broken', capsys)
    assert code == 1, err
    assert 'Traceback' not in err
    lines = [line for line in err.splitlines() if line.startswith('mvbb bag process: ')]
    assert len(lines) == 1, err
    kept = int(lines[0].split('; kept the ')[1].split()[0])
    assert lines[0].endswith(f'kept the {kept} clouds before it in {output}')
    if case == 'index promising more':
        assert kept == MESSAGES and f'its index lists {MESSAGES + 2} messages' in lines[0]
    else:
        assert 0 < kept < MESSAGES, 'the cut falls between clouds, not before the first'
        where = 'ends at byte' if storage == 'mcap' else 'bytes its header counts'
        assert _storage_file(source).name in lines[0] and where in lines[0], lines[0]
    assert f'total: {kept} clouds' in out
    stamps = _stamps(output)
    assert stamps and all(
        found == [bag_stamp(p) for p in range(kept)] for found in stamps.values()
    )
    intact = write_bag(tmp_path / 'prefix', storage, count=kept)
    code, _, err, reference = _process(intact, tmp_path / 'reference', capsys)
    assert code == 0, err
    assert _files(output) == _files(reference), 'the output is that of the intact prefix'


def test_reader_of_a_cut_bag_yields_whole_clouds_then_says_where(tmp_path):
    source = cut_in_the_middle(write_bag(tmp_path / 'input', 'mcap'))
    read: list[bytes] = []
    with CloudBag(source) as bag:
        assert bag.count([TOPIC]) == MESSAGES, 'the index (metadata.yaml) lists them all'
        with pytest.raises(BagStorageError, match='truncated or corrupt') as caught:
            for cloud in bag.clouds([TOPIC]):
                read.append(canonical_cdr(cloud.cdr, CLOUD))
    assert 0 < len(read) < MESSAGES and caught.value.read == len(read)
    with CloudBag(write_bag(tmp_path / 'whole', 'mcap', count=len(read))) as bag:
        whole = [canonical_cdr(cloud.cdr, CLOUD) for cloud in bag.clouds([TOPIC])]
    assert whole == read, 'the same messages (padding bytes zeroed on both sides)'
