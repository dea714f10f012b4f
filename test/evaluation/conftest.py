"""Fixtures the evaluation's tests share: the unit cube as a grasp target."""

from __future__ import annotations

from mvbb_ros.evaluation.mesh import GraspTarget
import pytest
from support.grasp_targets import cube_mesh


@pytest.fixture(scope='module')
def cube() -> GraspTarget:
    return GraspTarget.from_mesh(cube_mesh())
