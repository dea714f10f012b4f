"""Tests for the wrench-space grasp quality evaluator (mvbb_ros.evaluation)."""

from __future__ import annotations

from dataclasses import dataclass
import json
import math

from mvbb_ros.cli.main import main
from mvbb_ros.evaluation.experiment import compare_grasp_sets
from mvbb_ros.evaluation.gripper import ParallelJawGripper
from mvbb_ros.evaluation.mesh import center_of_mass, GraspTarget, is_closed
from mvbb_ros.evaluation.report import format_comparison, plot_quality_space
from mvbb_ros.evaluation.simulation import evaluate_grasps, grasp_quality
from mvbb_ros.evaluation.spherical import expected_best_of, spherical_grasps
from mvbb_ros.evaluation.wrench import contact_quality, wrench_space_quality
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.grasping.hypotheses import grasp_hypotheses
import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

# A unit cube centred on the origin, grasped from above across its +-x faces by a gripper that
# opens 1.5 and reaches 0.6 deep: the palm stops on the top face (z = 0.5) and the fingers
# close at half a finger depth below it, z = 0.5 - 0.3 + retreat ... on the face centres' line.
CUBE_GRIPPER = ParallelJawGripper(max_width=1.5, finger_depth=0.6, finger_width=0.1, retreat=0.01)


@dataclass
class Pose:
    position: np.ndarray
    approach: np.ndarray
    closing: np.ndarray


def cube_mesh(side: float = 1.0) -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh.create_box(side, side, side)
    return mesh.translate((-side / 2, -side / 2, -side / 2))


def top_grasp(x: float = 0.0, y: float = 0.0, closing=(1.0, 0.0, 0.0)) -> Pose:
    return Pose(
        position=np.array([x, y, 1.5]),
        approach=np.array([0.0, 0.0, -1.0]),
        closing=np.asarray(closing, dtype=float),
    )


@pytest.fixture(scope='module')
def cube() -> GraspTarget:
    return GraspTarget.from_mesh(cube_mesh())


# Mesh properties ------------------------------------------------------------------------------


def test_cube_target_mass_properties(cube):
    assert cube.closed
    assert cube.com_method == 'solid'
    np.testing.assert_allclose(cube.center_of_mass, 0.0, atol=1e-12)
    assert cube.radius == pytest.approx(math.sqrt(3) / 2)
    assert cube.diameter == pytest.approx(math.sqrt(3))


def test_center_of_mass_is_the_solid_centroid_not_the_vertex_mean():
    # A square pyramid (apex up) has its centroid at a quarter of its height, whatever the
    # triangulation; its vertex mean (what Open3D's get_center returns) is higher.
    base = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
    apex = np.array([[0.0, 0.0, 2.0]])
    verts = np.vstack([base, apex])
    tris = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    centre, method = center_of_mass(verts, tris)
    assert method == 'solid'
    np.testing.assert_allclose(centre, [0.0, 0.0, 0.5], atol=1e-12)
    assert verts.mean(axis=0)[2] == pytest.approx(0.4)
    # The winding (inward or outward) does not matter.
    centre_flipped, _ = center_of_mass(verts, tris[:, ::-1])
    np.testing.assert_allclose(centre_flipped, centre, atol=1e-12)


def test_open_mesh_uses_the_surface_centroid():
    # The cube without its top face: the area-weighted centroid of five unit squares.
    mesh = cube_mesh()
    tris = np.asarray(mesh.triangles)
    verts = np.asarray(mesh.vertices)
    centroids = verts[tris].mean(axis=1)
    open_tris = tris[centroids[:, 2] < 0.5 - 1e-9]
    assert not is_closed(open_tris)
    centre, method = center_of_mass(verts, open_tris)
    assert method == 'surface'
    np.testing.assert_allclose(centre, [0.0, 0.0, -0.1], atol=1e-12)


# Known answers --------------------------------------------------------------------------------


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


# Invariances ----------------------------------------------------------------------------------


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


# Batches, spherical grasps, box grasps ----------------------------------------------------------


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


def test_spherical_grasps_match_the_paper_count_and_geometry():
    centre = np.array([1.0, 2.0, 3.0])
    sphere = spherical_grasps(centre, 2.0, 10)
    assert len(sphere) == 22104  # the paper's count
    offsets = sphere.positions - centre
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=1), 2.0)
    np.testing.assert_allclose(sphere.approaches, -offsets / 2.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(sphere.closings, axis=1), 1.0)
    np.testing.assert_allclose(
        np.einsum('ij,ij->i', sphere.closings, sphere.approaches), 0, atol=1e-12
    )
    poses = np.round(np.hstack([sphere.positions, sphere.closings]), 9)
    assert len(np.unique(poses, axis=0)) == len(sphere)
    assert len(spherical_grasps(centre, 1.0, 20)) == 2 * 18 + 8 * 18 * 18
    with pytest.raises(ValueError, match='divide 180'):
        spherical_grasps(centre, 1.0, 7)


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


# Comparison, report, plot, command ------------------------------------------------------------


def l_shape_mesh() -> o3d.geometry.TriangleMesh:
    mesh = o3d.geometry.TriangleMesh.create_box(1.0, 0.3, 0.3)
    mesh += o3d.geometry.TriangleMesh.create_box(0.3, 0.3, 0.8).translate((0.0, 0.0, 0.3))
    return mesh.subdivide_midpoint(2)  # enough vertices for the decomposition's min_points


def test_compare_grasp_sets_table_and_plot(tmp_path):
    comparison = compare_grasp_sets(l_shape_mesh(), name='L', thresholds=(0.9,), spherical_step=45)
    names = [result.name for result in comparison.sets]
    assert names == ['spherical', 'root box', 't=0.90']
    assert comparison.sets[1].candidates == 24
    rows = comparison.summary()
    assert rows[0]['candidates'] == 2 * 8 + 3 * 8 * 8
    for row in rows[1:]:
        assert 'holds' in row and 'quality_ratio' in row
    table = format_comparison(comparison)
    assert table.count('\n') == 1 + len(rows)
    json.dumps(comparison.to_dict())  # JSON-ready
    path = plot_quality_space(comparison, tmp_path / 'fig.png')
    assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert [p.name for p in tmp_path.iterdir()] == ['fig.png']  # no temporary left behind


def test_evaluate_command(tmp_path, capsys):
    mesh_path = tmp_path / 'l_shape.ply'
    assert o3d.io.write_triangle_mesh(str(mesh_path), l_shape_mesh())
    code = main(
        [
            'evaluate',
            str(mesh_path),
            '--spherical-step',
            '60',
            '-t',
            '0.94',
            '--json',
            str(tmp_path / 'out.json'),
            '--png',
            str(tmp_path / 'out.png'),
        ]
    )
    assert code == 0
    output = capsys.readouterr().out
    assert 'spherical' in output and 'root box' in output and 't=0.94' in output
    document = json.loads((tmp_path / 'out.json').read_text())
    assert [row['set'] for row in document['sets']] == ['spherical', 'root box', 't=0.94']
    assert (tmp_path / 'out.png').stat().st_size > 0


def test_evaluate_command_reports_bad_input(tmp_path, capsys):
    assert main(['evaluate', str(tmp_path / 'missing.ply')]) == 1
    assert 'missing.ply' in capsys.readouterr().err


def test_expected_best_of_matches_simulation():
    rng = np.random.default_rng(0)
    values = rng.random(40)
    simulated = np.mean([rng.choice(values, 5, replace=False).max() for _ in range(20000)])
    assert expected_best_of(values, 5) == pytest.approx(simulated, abs=5e-3)
    assert expected_best_of(values, 1) == pytest.approx(values.mean())
    assert expected_best_of(values, 40) == pytest.approx(values.max())
    assert expected_best_of([], 3) == 0.0


def test_targets_from_every_mesh_form(tmp_path, cube):
    legacy = cube_mesh()
    path = tmp_path / 'cube.ply'
    assert o3d.io.write_triangle_mesh(str(path), legacy)
    forms = [
        legacy,
        o3d.t.geometry.TriangleMesh.from_legacy(legacy),
        (np.asarray(legacy.vertices), np.asarray(legacy.triangles)),
        path,
        str(path),
    ]
    for form in forms:
        target = GraspTarget.from_mesh(form)
        quality = grasp_quality(target, top_grasp(), gripper=CUBE_GRIPPER)
        assert quality.epsilon == pytest.approx(
            grasp_quality(cube, top_grasp(), gripper=CUBE_GRIPPER).epsilon, rel=1e-6
        )
    assert GraspTarget.from_mesh(cube) is cube
    with pytest.raises(FileNotFoundError):
        GraspTarget.from_mesh(tmp_path / 'missing.ply')
