"""Wrench-space quality (evaluation.wrench): epsilon and volume of known contact sets."""

from __future__ import annotations

import math

from mvbb_ros.evaluation.simulation import grasp_quality
from mvbb_ros.evaluation.wrench import contact_quality, wrench_space_quality
import numpy as np
import pytest
from support.grasp_targets import CUBE_GRIPPER, top_grasp


def test_two_hard_contacts_are_never_force_closure(cube):
    # Point contacts with friction cannot resist a torque about the line through them.
    quality = grasp_quality(cube, top_grasp(), gripper=CUBE_GRIPPER, contact_radius=0)
    assert quality.status == 'grasped'
    assert quality.epsilon == 0.0 and quality.volume == 0.0


def test_single_contact_has_zero_epsilon():
    epsilon, volume = contact_quality(
        [[0.5, 0.0, 0.0]], [[-1.0, 0.0, 0.0]], center=np.zeros(3), scale=1.0, torsion=0.1
    )
    assert epsilon == 0.0 and volume == 0.0


def test_no_contact_has_zero_epsilon():
    epsilon, volume = contact_quality(
        np.zeros((0, 3)), np.zeros((0, 3)), center=np.zeros(3), scale=1.0
    )
    assert (epsilon, volume) == (0.0, 0.0)


def test_cross_polytope_epsilon_and_volume():
    # The hull of +-e_i in 6D: every facet is at 1 / sqrt(6), the volume is 2^6 / 6!.
    wrenches = np.vstack([np.eye(6), -np.eye(6)])
    epsilon, volume = wrench_space_quality(wrenches)
    assert epsilon == pytest.approx(1 / math.sqrt(6))
    assert volume == pytest.approx(2**6 / math.factorial(6))


def test_origin_outside_the_hull_gives_zero_epsilon_but_a_volume():
    wrenches = np.vstack([np.eye(6), -np.eye(6)]) + np.array([2.0, 0, 0, 0, 0, 0])
    epsilon, volume = wrench_space_quality(wrenches)
    assert epsilon == 0.0
    assert volume == pytest.approx(2**6 / math.factorial(6))


def test_six_frictionless_face_contacts_of_a_cube_are_not_force_closure_but_with_friction_are():
    # Contacts at the six face centres: frictionless they cannot resist torques (every normal
    # passes through the centre); with friction they hold anything.
    normals = np.vstack([np.eye(3), -np.eye(3)])
    points = -0.5 * normals  # face centres; the inward normal points back to the centre
    frictionless, _ = contact_quality(points, normals, center=np.zeros(3), scale=1.0, friction=0.0)
    assert frictionless == 0.0
    with_friction, _ = contact_quality(
        points, normals, center=np.zeros(3), scale=1.0, friction=0.5
    )
    assert with_friction > 0.0
