"""The single-view grasp judge: pads closing on a whole mesh, friction cones, steadiness."""

from __future__ import annotations

from types import SimpleNamespace

from mvbb_ros.evaluation.grasp_judge import (
    FINGER_DEPTHS,
    grasp_angle_deg,
    judge_grasps,
    PadGripper,
    same_grasp,
    simulated_epsilon,
    steady_pairs,
)
from mvbb_ros.evaluation.mesh import GraspTarget
from mvbb_ros.evaluation.wrench import line_in_friction_cones
import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

GRIPPER = PadGripper(max_width=0.08)
TABLE = (np.array([0.0, 0.0, 1.0]), 0.0)


def cube(size=0.04):
    """Return a cube of the given side standing on z = 0, centred on the z axis."""
    mesh = o3d.geometry.TriangleMesh.create_box(size, size, size)
    mesh.translate([-size / 2.0, -size / 2.0, 0.0])
    return GraspTarget.from_mesh(mesh)


def grasp(position, approach, closing):
    return SimpleNamespace(
        position=np.asarray(position, dtype=float),
        approach=np.asarray(approach, dtype=float) / np.linalg.norm(approach),
        closing=np.asarray(closing, dtype=float) / np.linalg.norm(closing),
    )


def verdict(target, one, gripper=GRIPPER, support=TABLE):
    result = judge_grasps(target, [one], gripper, support=support)
    return result, next(name for name, n in result.status_counts().items() if n)


TOP_DOWN = grasp([0.0, 0.0, 0.1], [0, 0, -1], [1, 0, 0])


def test_an_antipodal_grasp_across_a_box_holds_with_contacts_on_the_two_faces():
    result, status = verdict(cube(), TOP_DOWN)
    assert status == 'holds' and result.holds[0]
    assert result.depth[0] == FINGER_DEPTHS[0]
    contacts, normals = result.contacts[0], result.normals[0]
    # Pad 0 starts at +x and closes along -x: its contact is on the +x face, pushing inwards.
    np.testing.assert_allclose(contacts[:, 0], [0.02, -0.02], atol=1e-6)
    np.testing.assert_allclose(contacts[:, 1], 0.0, atol=1e-6)  # the patch centre
    np.testing.assert_allclose(normals, [[-1, 0, 0], [1, 0, 0]], atol=1e-9)
    # The fingertips reach 5 mm past the top (z = 0.04); the pad is the finger's last 2 cm.
    assert 0.035 - 0.01 < contacts[0, 2] < 0.04


def test_the_pre_grasp_distance_does_not_matter_only_the_line():
    near = grasp([0.0, 0.0, 0.05], [0, 0, -1], [1, 0, 0])
    inside = grasp([0.0, 0.0, 0.02], [0, 0, -1], [1, 0, 0])  # a box put it inside the object
    for other in (near, inside):
        result, status = verdict(cube(), other)
        assert status == 'holds'


def test_a_grasp_that_misses_the_object_is_refused():
    result, status = verdict(cube(), grasp([0.2, 0.0, 0.1], [0, 0, -1], [1, 0, 0]))
    assert status == 'missed' and not result.holds[0]
    assert np.all(np.isnan(result.contacts[0]))


def test_an_object_wider_than_the_opening_is_refused():
    _, status = verdict(cube(0.04), TOP_DOWN, PadGripper(max_width=0.035))
    assert status == 'collision'  # the fingertips land on the top face
    _, status = verdict(cube(0.04), TOP_DOWN, PadGripper(max_width=0.045))
    assert status == 'holds'


def test_closing_diagonally_across_a_cube_corner_slips_out_of_the_friction_cones():
    diagonal = grasp([0.015, 0.015, 0.1], [0, 0, -1], [1, -1, 0])
    result, status = verdict(cube(), diagonal)
    assert status == 'slips' and not result.holds[0]
    contacts = result.contacts[0]
    assert np.all(np.isfinite(contacts))  # both pads touched: only friction fails
    line = contacts[1] - contacts[0]
    inward = result.normals[0, 0]
    angle = np.degrees(np.arccos(inward @ line / np.linalg.norm(line)))
    assert angle == pytest.approx(45.0, abs=1.0)
    # With friction enough for 45 degrees (mu > 1) the same grasp holds.
    _, status = verdict(cube(), diagonal, PadGripper(max_width=0.08, friction=1.1))
    assert status == 'holds'


def test_the_table_refuses_approaches_from_below_and_pads_under_its_top():
    from_below = grasp([0.0, 0.0, -0.05], [0, 0, 1], [1, 0, 0])
    assert verdict(cube(), from_below)[1] == 'support'
    assert verdict(cube(), from_below, support=None)[1] == 'holds'  # floating in the air
    # From the side, closing vertically at 2 cm height: the lower pad would be in the table.
    vertical = grasp([0.1, 0.0, 0.02], [-1, 0, 0], [0, 0, 1])
    assert verdict(cube(), vertical)[1] == 'support'
    # From the side, closing horizontally at 2 cm: the 2 x 2 cm pads clear the table.
    horizontal = grasp([0.1, 0.0, 0.02], [-1, 0, 0], [0, 1, 0])
    assert verdict(cube(), horizontal)[1] == 'holds'


def test_a_thin_wall_between_the_pads_is_not_mistaken_for_a_grasp_when_a_finger_hits_it():
    # Two cubes side by side along x, 2 cm apart: the opening straddles both, a finger lands.
    left = o3d.geometry.TriangleMesh.create_box(0.04, 0.04, 0.04)
    left.translate([-0.07, -0.02, 0.0])
    right = o3d.geometry.TriangleMesh.create_box(0.04, 0.04, 0.04)
    right.translate([0.03, -0.02, 0.0])
    target = GraspTarget.from_mesh(left + right)
    assert verdict(target, TOP_DOWN)[1] in ('collision', 'no_contact')


def test_many_grasps_are_judged_as_each_alone_in_input_order():
    target = cube()
    grasps = [
        TOP_DOWN,
        grasp([0.2, 0.0, 0.1], [0, 0, -1], [1, 0, 0]),
        grasp([0.015, 0.015, 0.1], [0, 0, -1], [1, -1, 0]),
        grasp([0.0, 0.0, -0.05], [0, 0, 1], [1, 0, 0]),
        grasp([0.1, 0.0, 0.02], [-1, 0, 0], [0, 1, 0]),
    ]
    together = judge_grasps(target, grasps, GRIPPER, support=TABLE)
    alone = [judge_grasps(target, [g], GRIPPER, support=TABLE).status[0] for g in grasps]
    np.testing.assert_array_equal(together.status, alone)
    assert list(together.holds) == [True, False, False, False, True]
    empty = judge_grasps(target, [], GRIPPER)
    assert len(empty) == 0 and empty.holds.shape == (0,)


def test_the_judge_agrees_with_the_figure_6_simulator_on_the_clear_cases():
    target = cube()
    good, diagonal = TOP_DOWN, grasp([0.015, 0.015, 0.1], [0, 0, -1], [1, -1, 0])
    epsilon = simulated_epsilon(target, [good, diagonal], 0.08)
    assert epsilon[0] > 0.0
    assert epsilon[1] == 0.0


def test_the_pad_gripper_checks_its_sizes():
    for bad in (
        {'max_width': 0.0},
        {'max_width': 0.08, 'pad_size': 0.0},
        {'max_width': 0.08, 'depths': ()},
        {'max_width': 0.08, 'pad_rays': 1},
    ):
        with pytest.raises(ValueError):
            PadGripper(**bad)


def test_line_in_friction_cones():
    contacts = np.array([[[0.0, 0, 0], [1.0, 0, 0]]])
    along = np.array([[[1.0, 0, 0], [-1.0, 0, 0]]])
    assert line_in_friction_cones(contacts, along)[0]
    tilted = Rotation.from_euler('z', 25.0, degrees=True).apply(along[0])[None]
    assert line_in_friction_cones(contacts, tilted, 0.5)[0]  # 25 < 26.6 degrees
    tilted = Rotation.from_euler('z', 28.0, degrees=True).apply(along[0])[None]
    assert not line_in_friction_cones(contacts, tilted, 0.5)[0]
    assert not line_in_friction_cones(contacts, -along)[0]  # pushing outwards
    assert not line_in_friction_cones(np.zeros((1, 2, 3)), along)[0]  # one point


# Steadiness --------------------------------------------------------------------------------------


def test_a_half_turn_about_the_approach_is_the_same_grasp():
    first = grasp([0.1, 0.0, 0.2], [0, 0, -1], [1, 0, 0])
    half_turn = grasp([0.1, 0.0, 0.2], [0, 0, -1], [-1, 0, 0])
    quarter_turn = grasp([0.1, 0.0, 0.2], [0, 0, -1], [0, 1, 0])
    assert grasp_angle_deg(first, half_turn) == pytest.approx(0.0, abs=1e-6)
    assert same_grasp(first, half_turn)
    assert grasp_angle_deg(first, quarter_turn) == pytest.approx(90.0)
    assert not same_grasp(first, quarter_turn)


def test_same_grasp_needs_one_centimetre_and_fifteen_degrees():
    first = grasp([0.1, 0.0, 0.2], [0, 0, -1], [1, 0, 0])
    tilt = Rotation.from_euler('y', 10.0, degrees=True)
    tilted = grasp([0.1, 0.0, 0.2], tilt.apply([0, 0, -1]), tilt.apply([1, 0, 0]))
    assert grasp_angle_deg(first, tilted) == pytest.approx(10.0)
    assert same_grasp(first, tilted)
    tilt = Rotation.from_euler('y', 20.0, degrees=True)
    assert not same_grasp(
        first, grasp([0.1, 0.0, 0.2], tilt.apply([0, 0, -1]), tilt.apply([1, 0, 0]))
    )
    assert same_grasp(first, grasp([0.109, 0.0, 0.2], [0, 0, -1], [1, 0, 0]))
    assert not same_grasp(first, grasp([0.112, 0.0, 0.2], [0, 0, -1], [1, 0, 0]))
    assert not same_grasp(first, None) and not same_grasp(None, None)


def test_steady_pairs_count_consecutive_frames():
    a = grasp([0.1, 0.0, 0.2], [0, 0, -1], [1, 0, 0])
    b = grasp([0.1, 0.0, 0.2], [0, 0, -1], [-1, 0, 0])  # a, turned half
    c = grasp([0.3, 0.0, 0.2], [0, 0, -1], [1, 0, 0])
    assert steady_pairs([a, b, c, c]) == (2, 3)
    assert steady_pairs([a, None, a]) == (0, 2)
    assert steady_pairs([a]) == (0, 0)
    assert steady_pairs([]) == (0, 0)
