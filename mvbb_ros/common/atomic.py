"""Atomic file writes: a reader never sees a half-written file, a failure leaves nothing behind."""

from __future__ import annotations

from collections.abc import Iterator
import contextlib
import os
from pathlib import Path
import shutil
import tempfile
from typing import IO


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """
    Yield a temporary path beside `path`; on success it is renamed onto `path`.

    Use it for writers that want a file name (Open3D, matplotlib, rosbags). If the block raises,
    the temporary file (or directory) is removed and `path` is untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f'.{target.name}.', dir=target.parent)) / target.name
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        with contextlib.suppress(FileNotFoundError):
            if tmp.is_dir():
                shutil.rmtree(tmp)
            else:
                tmp.unlink()
        with contextlib.suppress(OSError):
            tmp.parent.rmdir()


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = 'w') -> Iterator[IO]:
    """Open a temporary file beside `path` for writing; it replaces `path` when the block ends."""
    if not any(flag in mode for flag in 'wx'):
        raise ValueError(f'atomic_open is for writing, got mode {mode!r}')
    with atomic_path(path) as tmp, open(tmp, mode) as handle:
        yield handle
        handle.flush()
        os.fsync(handle.fileno())
