"""Shared fixtures: where the shared real data lives, and how to skip clearly without it."""

from __future__ import annotations

import os
from pathlib import Path
import random

from mvbb_ros.kernels import warm_up
import pytest

# Every test run talks on its own DDS domain, on this machine only, so parallel runs and other
# ROS graphs never see each other. Set before any rclpy context exists (and inherited by the
# subprocesses that tests start).
os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

REPO_ROOT = Path(__file__).resolve().parents[1]


def pytest_sessionstart(session: pytest.Session) -> None:
    """Warm the numba kernels' cache, so the nodes that tests start do not compile on a cloud."""
    warm_up()


#: The shared real data (models, scans, bags); override with MVBB_SHARED_DATA.
SHARED_DATA = Path(os.environ.get('MVBB_SHARED_DATA', REPO_ROOT.parent / 'shared' / 'data'))


def require_shared_data(*relative: str) -> Path:
    """Return SHARED_DATA / relative, or skip the test with a message saying what is missing."""
    path = SHARED_DATA.joinpath(*relative)
    if not path.exists():
        pytest.skip(f'shared data not found: {path} (set MVBB_SHARED_DATA to its folder)')
    return path


@pytest.fixture
def shared_data() -> Path:
    """Return the shared data folder; skip the test when it is absent."""
    return require_shared_data()
