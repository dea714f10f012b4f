"""
The grasp simulation (evaluation.simulation): known answers, invariances, batches, bad input.

A unit cube grasped from above across its +-x faces is the known answer; the invariances move,
turn and scale an asymmetric mesh with its grasp.
"""

from __future__ import annotations

from mvbb_ros.evaluation.gripper import ParallelJawGripper
from mvbb_ros.evaluation.mesh import GraspTarget
from mvbb_ros.evaluation.simulation import evaluate_grasps, grasp_quality
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.grasping.hypotheses import grasp_hypotheses
import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation
from support.grasp_targets import CUBE_GRIPPER, Pose, top_grasp


def test_cube_grasped_across_opposite_faces_is_force_closure(cube):
    quality = grasp_quality(cube, top_grasp(), gripper=CUBE_GRIPPER)
    assert quality.status == 'grasped'
    assert quality.force_closure
    assert quality.epsilon > 0.0
    assert quality.volume > 0.0
    # Contacts on the face centres' line, half a finger depth (minus the retreat) below the top.
    depth = 0.5 - (0.6 / 2 - 0.01)
    np.testing.assert_allclose(quality.contacts, [[0.5, 0, depth], [-0.5, 0, depth]], atol=1e-6)
    np.testing.assert_allclose(quality.normals, [[-1, 0, 0], [1, 0, 0]], atol=1e-9)
    assert quality.travel == pytest.approx(1.6 - 0.01, abs=1e-6)


def test_grasp_that_misses_the_object_is_not_force_closure(cube):
    quality = grasp_quality(cube, top_grasp(x=3.0), gripper=CUBE_GRIPPER)
    assert quality.status == 'missed'
    assert not quality.force_closure
    assert quality.epsilon == 0.0 and quality.volume == 0.0
    assert np.all(np.isnan(quality.contacts))


def test_fingers_hitting_the_object_while_approaching_is_a_failure(cube):
    narrow = ParallelJawGripper(max_width=0.8, finger_depth=0.6, finger_width=0.1)
    quality = grasp_quality(cube, top_grasp(), gripper=narrow)
    assert quality.status == 'collision'
    assert quality.epsilon == 0.0 and not quality.force_closure


def test_closing_line_off_the_object_has_no_contact():
    # A post just beside the closing line: the palm (0.1 wide, y in [-0.05, 0.05]) lands on it,
    # but the fingers close along x on the line y = 0, which passes next to it (y >= 0.02).
    post = o3d.geometry.TriangleMesh.create_box(0.2, 0.2, 1.0).translate((-0.6, 0.02, -0.5))
    gripper = ParallelJawGripper(max_width=1.5, finger_depth=0.4, finger_width=0.1)
    quality = grasp_quality(post, top_grasp(), gripper=gripper)
    assert quality.status == 'no_contact'
    assert quality.epsilon == 0.0


def transformed(mesh, grasp: Pose, rotation: np.ndarray, translation: np.ndarray, scale=1.0):
    moved = o3d.geometry.TriangleMesh(mesh)
    moved.scale(scale, center=(0.0, 0.0, 0.0))
    moved.rotate(rotation, center=(0.0, 0.0, 0.0))
    moved.translate(translation)
    pose = Pose(
        position=rotation @ (scale * grasp.position) + translation,
        approach=rotation @ grasp.approach,
        closing=rotation @ grasp.closing,
    )
    return moved, pose


def asymmetric_mesh() -> o3d.geometry.TriangleMesh:
    # A box with a smaller box on top, off-centre: nothing symmetric to hide errors.
    body = o3d.geometry.TriangleMesh.create_box(1.0, 0.6, 0.5).translate((-0.5, -0.3, -0.25))
    bump = o3d.geometry.TriangleMesh.create_box(0.3, 0.3, 0.4).translate((0.1, -0.2, 0.25))
    return body + bump


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_epsilon_is_invariant_under_rigid_motion(seed):
    rng = np.random.default_rng(seed)
    mesh = asymmetric_mesh()
    grasp = Pose(
        position=np.array([0.25, -0.05, 1.2]),
        approach=np.array([0.0, 0.0, -1.0]),
        closing=Rotation.from_euler('z', 20, degrees=True).apply([1.0, 0.0, 0.0]),
    )
    # Grasps the bump, 20 degrees off its faces' normals (inside the 26.6-degree cone).
    gripper = ParallelJawGripper(max_width=0.5, finger_depth=0.3, finger_width=0.05, retreat=0.01)
    base = grasp_quality(mesh, grasp, gripper=gripper)
    assert base.force_closure
    rotation = Rotation.random(random_state=rng).as_matrix()
    moved_mesh, moved_grasp = transformed(mesh, grasp, rotation, rng.uniform(-5, 5, 3))
    moved = grasp_quality(moved_mesh, moved_grasp, gripper=gripper)
    assert moved.status == base.status
    assert moved.epsilon == pytest.approx(base.epsilon, rel=1e-4)
    assert moved.volume == pytest.approx(base.volume, rel=1e-4)


def test_quality_does_not_depend_on_units():
    # The same object and grasp in metres and in millimetres, the gripper scaled with them.
    mesh = asymmetric_mesh()
    grasp = Pose(np.array([-0.1, 0.0, 1.2]), np.array([0.0, 0.0, -1.0]), np.array([1.0, 0, 0]))
    in_m = GraspTarget.from_mesh(mesh)
    mm_mesh, mm_grasp = transformed(mesh, grasp, np.eye(3), np.zeros(3), scale=1000.0)
    in_mm = GraspTarget.from_mesh(mm_mesh)
    metres = grasp_quality(in_m, grasp, gripper=ParallelJawGripper.for_object(in_m.diameter))
    millimetres = grasp_quality(
        in_mm, mm_grasp, gripper=ParallelJawGripper.for_object(in_mm.diameter)
    )
    assert metres.force_closure
    assert millimetres.epsilon == pytest.approx(metres.epsilon, rel=1e-4)
    assert millimetres.volume == pytest.approx(metres.volume, rel=1e-4)


def test_more_friction_never_lowers_epsilon(cube):
    values = [
        grasp_quality(cube, top_grasp(), gripper=CUBE_GRIPPER, friction=mu).epsilon
        for mu in (0.2, 0.5, 1.0)
    ]
    assert values == sorted(values)
    assert values[0] > 0.0


def test_off_centre_grasp_is_worse_than_centred(cube):
    centred = grasp_quality(cube, top_grasp(), gripper=CUBE_GRIPPER)
    off = grasp_quality(cube, top_grasp(y=0.3), gripper=CUBE_GRIPPER)
    assert off.force_closure
    assert off.epsilon < centred.epsilon


def test_batch_matches_single_and_prefilter_keeps_epsilon(cube):
    grasps = [top_grasp(), top_grasp(x=3.0), top_grasp(y=0.3), top_grasp(closing=(1, 1, 0))]
    batch = evaluate_grasps(cube, grasps, gripper=CUBE_GRIPPER)
    for index, grasp in enumerate(grasps):
        single = grasp_quality(cube, grasp, gripper=CUBE_GRIPPER)
        assert batch.item(index).epsilon == single.epsilon
        assert batch.item(index).status == single.status
    fast = evaluate_grasps(cube, grasps, gripper=CUBE_GRIPPER, closure_prefilter=True)
    np.testing.assert_array_equal(fast.epsilon, batch.epsilon)
    closure = batch.force_closure
    np.testing.assert_array_equal(fast.volume[closure], batch.volume[closure])
    assert batch.status_counts()['missed'] == 1


def test_an_empty_grasp_set_is_evaluated_as_empty(cube):
    """A refined set can come out empty (nothing holds); its evaluation has no rows."""
    empty = evaluate_grasps(cube, [], gripper=CUBE_GRIPPER)
    assert empty.epsilon.shape == (0,) and empty.contacts.shape == (0, 2, 3)
    assert not empty.force_closure.any() and sum(empty.status_counts().values()) == 0


def test_root_box_grasps_on_a_cube_are_all_force_closure(cube):
    box = Box(center=np.zeros(3), rotation=np.eye(3), extents=np.ones(3))
    gripper = ParallelJawGripper.for_object(cube.diameter)
    grasps = grasp_hypotheses([box], gripper_max_width=gripper.max_width, standoff=0.1)
    assert len(grasps) == 24
    result = evaluate_grasps(cube, grasps, gripper=gripper)
    assert np.all(result.force_closure)
    # The cube's symmetry: every face grasp scores the same.
    np.testing.assert_allclose(result.epsilon, result.epsilon[0], rtol=1e-5)


def test_bad_arguments_are_refused(cube):
    with pytest.raises(ValueError):
        ParallelJawGripper(max_width=0.0, finger_depth=1.0)
    with pytest.raises(ValueError):
        grasp_quality(cube, Pose(np.zeros(3), np.array([0, 0, -1.0]), np.array([0, 0, 1.0])))
    with pytest.raises(ValueError):
        grasp_quality(cube, top_grasp(), gripper=CUBE_GRIPPER, max_width=1.0)
    with pytest.raises(TypeError):
        GraspTarget.from_mesh(42)
