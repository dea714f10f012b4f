"""Shared fixtures: where the shared real data lives, and how to skip clearly without it."""

from __future__ import annotations

import os
from pathlib import Path
import random

from hypothesis import settings
from mvbb_ros.kernels import warm_up
import pytest
from support.data import require_shared_data

# Every test run talks on its own DDS domain, on this machine only, so parallel runs and other
# ROS graphs never see each other. Set before any rclpy context exists (and inherited by the
# subprocesses that tests start).
os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(1, 101)))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

# Property tests draw new examples on every local run (that is how they find bugs: a failing
# example found so is then pinned with @example); in CI (the variable CI set, as .ci/run's
# callers do) they draw the same ones every time, so a clean checkout's verdict is reproducible.
settings.register_profile('ci', derandomize=True, print_blob=True)
if os.environ.get('CI'):
    settings.load_profile('ci')


def pytest_sessionstart(session: pytest.Session) -> None:
    """Warm the numba kernels' cache, so the nodes that tests start do not compile on a cloud."""
    warm_up()


@pytest.fixture
def shared_data() -> Path:
    """Return the shared data folder; skip the test when it is absent."""
    return require_shared_data()
