"""
Read what a truncated rosbag2 still holds: its messages up to the first byte that is missing.

``rosbags`` opens a rosbag2 through its index (the MCAP summary at the end of the file, a count
over the whole sqlite3 ``messages`` table), so a storage file cut short (a recorder killed, a
disk full, a copy interrupted) cannot be opened at all, although most of its messages are
intact. :class:`SalvageReader` reads such a bag without its index, in the order the messages
were recorded: an MCAP file record by record from its start, a sqlite3 file row by row through
a read-only SQLite file layer that refuses every page not wholly in the file (so a message is
either read whole or not at all, never padded). The first message that cannot be read ends the
reading with :class:`StorageCutError`, which names the file and where it ends.

It has the few members of ``rosbags.highlevel.AnyReader`` that
:class:`mvbb_ros.ros.bag.CloudBag` uses, so the bag tools read a salvaged bag as any other.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
import itertools
import mmap
import os
from pathlib import Path
import struct
from typing import Any, Final

import apsw
import yaml

#: The first (and last) bytes of an MCAP file.
MCAP_MAGIC: Final = b'\x89MCAP0\r\n'
#: The first bytes of a SQLite 3 database file.
SQLITE_MAGIC: Final = b'SQLite format 3\x00'
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _FOOTER = 0x03, 0x04, 0x05, 0x06, 0x02
_RECORD_HEAD = struct.Struct('<BQ')
_vfs_count = itertools.count()


class StorageCutError(Exception):
    """The storage ends (or breaks) here: nothing after this point can be read."""


@dataclass(frozen=True)
class SalvagedTopic:
    """A topic of a salvaged bag, as ``AnyReader.topics`` describes it."""

    msgtype: str
    msgcount: int


@dataclass(frozen=True)
class SalvagedConnection:
    """A connection (topic and type) of a salvaged bag."""

    number: int
    topic: str
    msgtype: str


#: One raw message: ``(topic, message type, bag time ns, serialized bytes)``.
RawMessage = tuple[str, str, int, bytes]


def storage_kind(path: Path) -> str:
    """Return ``'mcap'``, ``'sqlite3'`` or '' from a storage file's first bytes."""
    try:
        with open(path, 'rb') as handle:
            head = handle.read(len(SQLITE_MAGIC))
    except OSError:
        return ''
    if head.startswith(MCAP_MAGIC):
        return 'mcap'
    return 'sqlite3' if head == SQLITE_MAGIC else ''


def _string(data: bytes | memoryview, offset: int) -> tuple[str, int]:
    (length,) = struct.unpack_from('<I', data, offset)
    start = offset + 4
    end = start + length
    return bytes(data[start:end]).decode(), end


def _decompress(data: bytes, compression: str) -> bytes:
    if not compression:
        return data
    if compression == 'zstd':
        try:
            from compression import zstd  # type: ignore[import-not-found]
        except ImportError:
            from backports import zstd
        return bytes(zstd.decompress(data))
    if compression == 'lz4':
        from lz4.frame import decompress  # type: ignore[import-untyped]

        return bytes(decompress(data))
    raise StorageCutError(f'unknown MCAP chunk compression {compression!r}')


class _McapRecords:
    """The messages of an MCAP file, record by record from its start, until it ends."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, tuple[str, int]] = {}

    def _records(
        self, view: memoryview, base: int, end: int
    ) -> Iterator[tuple[int, memoryview, bool, int]]:
        """
        Yield ``(opcode, body, whole, at)`` per record of `view`, which starts at file byte `base`.

        `at` is the file byte where the body starts.

        A record cut short by the end of the file (`end`) comes last, with what it holds of its
        body and `whole` False; a cut header raises :class:`StorageCutError` at once.
        """
        offset = 0
        while offset < len(view):
            if offset + _RECORD_HEAD.size > len(view):
                raise StorageCutError(
                    f'{self.path.name} ends at byte {end} inside the header of a record at '
                    f'byte {base + offset}'
                )
            opcode, length = _RECORD_HEAD.unpack_from(view, offset)
            start = offset + _RECORD_HEAD.size
            if start + length > len(view):
                yield opcode, view[start:], False, base + start
                raise StorageCutError(
                    f'{self.path.name} ends at byte {end} inside a record of {length} bytes '
                    f'that starts at byte {base + offset}'
                )
            offset = start + length
            yield opcode, view[start:offset], True, base + start

    def _message(self, opcode: int, body: memoryview) -> RawMessage | None:
        if opcode == _SCHEMA:
            (schema_id,) = struct.unpack_from('<H', body, 0)
            self.schemas[schema_id] = _string(body, 2)[0]
        elif opcode == _CHANNEL:
            channel_id, schema_id = struct.unpack_from('<HH', body, 0)
            self.channels[channel_id] = (_string(body, 4)[0], schema_id)
        elif opcode == _MESSAGE:
            channel_id, _sequence, log_time = struct.unpack_from('<HIQ', body, 0)
            topic, schema_id = self.channels[channel_id]
            return topic, self.schemas.get(schema_id, ''), int(log_time), bytes(body[22:])
        return None

    def _chunk(self, body: memoryview, base: int, end: int, whole: bool) -> Iterator[RawMessage]:
        """Yield the messages of a chunk; of a cut one, those wholly in the file (uncompressed)."""
        if len(body) < 32:
            return
        compression, offset = _string(body, 28)
        (length,) = struct.unpack_from('<Q', body, offset)
        offset += 8
        if not whole and compression:
            return  # a compressed stream cut short: its messages cannot be told apart
        end = offset + length
        inner = _decompress(bytes(body[offset:end]), compression)
        try:
            for opcode, inner_body, inner_whole, _ in self._records(
                memoryview(inner), base + offset, end
            ):
                message = self._message(opcode, inner_body) if inner_whole else None
                if message is not None:
                    yield message
        except StorageCutError:
            if whole:
                raise StorageCutError(
                    f'{self.path.name}: a chunk at byte {base} is corrupt'
                ) from None

    def messages(self) -> Iterator[RawMessage]:
        """Yield every message in file order; raise :class:`StorageCutError` where it ends."""
        with open(self.path, 'rb') as handle:  # mapped, not read: bags are larger than memory
            size = os.fstat(handle.fileno()).st_size
            data = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) if size else b''
        if not data[: len(MCAP_MAGIC)] == MCAP_MAGIC:
            raise StorageCutError(f'{self.path.name} does not start as an MCAP file')
        view = memoryview(data)
        base = len(MCAP_MAGIC)
        for opcode, body, whole, at in self._records(view[base:], base, len(data)):
            if opcode == _FOOTER and whole:
                return
            if opcode == _CHUNK:
                yield from self._chunk(body, at, len(data), whole)
            elif whole:
                message = self._message(opcode, body)
                if message is not None:
                    yield message
        raise StorageCutError(f'{self.path.name} ends at byte {len(data)} without its footer')


class _WholePagesFile(apsw.VFSFile):
    """A read-only SQLite file whose missing pages are read errors rather than zeros."""

    def __init__(self, name: Any, flags: list[int], claimed: int, whole: int) -> None:
        super().__init__('', name, flags)
        self.claimed, self.whole = claimed, whole

    def xFileSize(self) -> int:  # noqa: N802 (SQLite's name)
        return max(self.claimed, int(super().xFileSize()))

    def xRead(self, amount: int, offset: int) -> bytes:  # noqa: N802 (SQLite's name)
        if offset + amount > self.whole:
            raise apsw.IOError(f'page at byte {offset} is missing')
        return bytes(super().xRead(amount, offset))


class _WholePagesVFS(apsw.VFS):
    def __init__(self, name: str, claimed: int, whole: int) -> None:
        self.claimed, self.whole = claimed, whole
        super().__init__(name, '')

    def xOpen(self, name: Any, flags: list[int]) -> _WholePagesFile:  # noqa: N802
        return _WholePagesFile(name, flags, self.claimed, self.whole)


def _sqlite_messages(path: Path) -> Iterator[RawMessage]:
    """Yield a sqlite3 bag's rows in recording order; raise :class:`StorageCutError` at a gap."""
    with open(path, 'rb') as handle:
        header = handle.read(100)
    size = path.stat().st_size
    (page_size,) = struct.unpack_from('>H', header, 16)
    page_size = 65536 if page_size == 1 else page_size
    (pages,) = struct.unpack_from('>I', header, 28)
    claimed = page_size * pages
    name = f'mvbb-salvage-{next(_vfs_count)}'
    vfs = _WholePagesVFS(name, claimed, size // page_size * page_size)
    where = f'{path.name} holds {size} of the {claimed} bytes its header counts'
    read = 0
    try:
        connection = apsw.Connection(
            f'file:{path}?immutable=1',
            flags=apsw.SQLITE_OPEN_READONLY | apsw.SQLITE_OPEN_URI,
            vfs=name,
        )
        try:
            topics = {
                int(row[0]): (str(row[1]), str(row[2]))
                for row in connection.execute('SELECT id, name, type FROM topics')
            }
            rows = connection.execute('SELECT topic_id, timestamp, data FROM messages ORDER BY id')
            for topic_id, timestamp, data in rows:
                topic, msgtype = topics[int(topic_id)]
                read += 1
                yield topic, msgtype, int(timestamp), bytes(data)
        finally:
            connection.close()
    except apsw.Error as error:
        raise StorageCutError(
            f'{where}; message {read + 1} is not wholly in it ({error})'
        ) from error
    finally:
        vfs.unregister()
    if size < claimed:
        raise StorageCutError(f'{where}')


class SalvageReader:
    """
    A rosbag2 read without its index, message by message, until its storage ends.

    :param path: a rosbag2 directory or a bare ``.db3`` / ``.mcap`` file.
    :raises StorageCutError: when a file is not MCAP or sqlite3, or is compressed as a whole.
    """

    is2 = True

    def __init__(self, path: Path) -> None:
        self.path = path
        metadata: dict[str, Any] = {}
        if path.is_dir():
            text = (path / 'metadata.yaml').read_text()
            metadata = yaml.safe_load(text)['rosbag2_bagfile_information']
            if str(metadata.get('compression_mode', '')).upper() == 'FILE':
                raise StorageCutError(f'{path} is compressed file by file')
            self.per_message = str(metadata.get('compression_mode', '')).upper() == 'MESSAGE'
            self.files = [path / name for name in metadata['relative_file_paths']]
        else:
            self.files, self.per_message = [path], False
        self.kinds = [storage_kind(file) for file in self.files]
        if not all(self.kinds):
            raise StorageCutError(f'{path} has a storage file that is neither MCAP nor sqlite3')
        counts: dict[str, int] = {}
        types: dict[str, str] = {}
        self.start_time, self.end_time = 2**63 - 1, 0
        self.cut = ''
        try:
            for topic, msgtype, timestamp, _ in self._raw():
                counts[topic] = counts.get(topic, 0) + 1
                types[topic] = msgtype
                self.start_time = min(self.start_time, timestamp)
                self.end_time = max(self.end_time, timestamp + 1)
        except StorageCutError as cut:
            self.cut = str(cut)
        for entry in metadata.get('topics_with_message_count', []):
            topic = entry['topic_metadata']['name']
            types.setdefault(topic, entry['topic_metadata']['type'])
            counts[topic] = int(entry['message_count'])  # what the bag promises
        self.topics = {
            topic: SalvagedTopic(types[topic], counts.get(topic, 0)) for topic in sorted(types)
        }
        self.connections = [
            SalvagedConnection(number, topic, types[topic])
            for number, topic in enumerate(sorted(types))
        ]

    def _raw(self) -> Iterator[RawMessage]:
        for file, kind in zip(self.files, self.kinds, strict=True):
            if kind == 'mcap':
                yield from _McapRecords(file).messages()
            elif self.per_message:
                for topic, msgtype, timestamp, raw in _sqlite_messages(file):
                    yield topic, msgtype, timestamp, _decompress(raw, 'zstd')
            else:
                yield from _sqlite_messages(file)

    def messages(
        self,
        connections: Sequence[SalvagedConnection],
        start: int | None = None,
        stop: int | None = None,
    ) -> Iterator[tuple[SalvagedConnection, int, bytes]]:
        """Yield ``(connection, bag time ns, raw bytes)`` in recording order, as AnyReader."""
        wanted = {connection.topic: connection for connection in connections}
        for topic, _msgtype, timestamp, raw in self._raw():
            if topic not in wanted:
                continue
            if (start is not None and timestamp < start) or (
                stop is not None and timestamp >= stop
            ):
                continue
            yield wanted[topic], timestamp, raw

    def close(self) -> None:
        """Nothing to close: every reading opens and closes its files."""
