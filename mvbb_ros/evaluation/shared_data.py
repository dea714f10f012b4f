"""
Where the shared real data lives (models, scans, scenes, bags): one rule for every tool.

The data is not part of the repository (``../shared/data/MANIFEST.md`` beside a checkout). The
benchmarks and the tests find it by :func:`shared_data_folder`: the folder named by the
environment variable :data:`ENVIRONMENT`, else the first ``shared/data`` beside the checkout or
beside one of its parent folders (a git worktree kept under ``<project>/wt/<name>`` finds the
project's data too).
"""

from __future__ import annotations

import os
from pathlib import Path

#: The environment variable that names the shared data folder.
ENVIRONMENT = 'MVBB_SHARED_DATA'
#: The checkout this module was imported from (its package folder's parent).
CHECKOUT = Path(__file__).resolve().parents[2]


def shared_data_folder(checkout: Path = CHECKOUT) -> Path:
    """
    Return the shared data folder (it may not exist: check what you need, :func:`missing`).

    :param checkout: the repository whose neighbourhood is searched.
    """
    named = os.environ.get(ENVIRONMENT)
    if named:
        return Path(named)
    for folder in checkout.parents:
        candidate = folder / 'shared' / 'data'
        if candidate.is_dir():
            return candidate
    return checkout.parent / 'shared' / 'data'


def missing(path: Path) -> str | None:
    """Return why `path` (shared data) cannot be read, with how to point at it, or None."""
    if path.exists():
        return None
    return f'shared data not found: {path} (set {ENVIRONMENT} to the shared data folder)'
