"""The physics benchmark's harness: its views, the contenders' world poses, its JSON and tables."""

from __future__ import annotations

from dataclasses import dataclass
import json

from hypothesis import given, settings
from hypothesis import strategies as st
from mvbb_ros.evaluation.camera import orbit_pose
from mvbb_ros.evaluation.physics.hand import FRANKA
from mvbb_ros.evaluation.physics.primitive import primitive_grasps
from mvbb_ros.evaluation.physics.views import (
    grasp_matrix,
    physics_views,
    PhysicsView,
    PlacedObject,
    transform_points,
    wilson_interval,
)
import numpy as np
import pytest
from support.data import load_benchmark

#: A box 5 x 6 x 10 cm, its own frame at its centre.
BOX_SIZE = np.array([0.05, 0.06, 0.10])


@dataclass
class MeshObject:
    """A plain mesh with a name: what the views need of a physics object."""

    name: str
    vertices: np.ndarray
    triangles: np.ndarray


def box_object(name: str = 'box', size: np.ndarray = BOX_SIZE) -> MeshObject:
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_box(*size)
    mesh.translate(-size / 2.0)
    return MeshObject(name, np.asarray(mesh.vertices), np.asarray(mesh.triangles))


def standing_pose(yaw_deg: float = 30.0, size: np.ndarray = BOX_SIZE) -> np.ndarray:
    """Return the pose of the box standing on the table, turned about z, off the origin."""
    yaw = np.radians(yaw_deg)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0, 0, 1]]
    pose[:3, 3] = [0.1, -0.05, size[2] / 2.0]
    return pose


@pytest.fixture(scope='module')
def placed():
    return PlacedObject.place(box_object(), standing_pose())


@pytest.fixture(scope='module')
def views(placed):
    return list(physics_views(placed, 2, seed=3))


@pytest.fixture(scope='module')
def bench():
    return load_benchmark('physics')


def test_views_are_deterministic_for_a_seed_and_differ_between_seeds(placed, views):
    again = list(physics_views(placed, 2, seed=3))
    other = next(physics_views(placed, 1, seed=4))
    assert [v.index for v in views] == [0, 1]
    for first, second in zip(views, again, strict=True):
        np.testing.assert_array_equal(first.points, second.points)
        np.testing.assert_array_equal(first.scene_points, second.scene_points)
        np.testing.assert_array_equal(first.camera_pose, second.camera_pose)
    assert not np.allclose(other.camera_pose, views[0].camera_pose)


def test_a_view_holds_the_object_and_the_table_in_the_camera_frame(placed, views):
    for view in views:
        assert view.points.dtype == np.float32 and view.scene_points.dtype == np.float32
        assert 30.0 <= view.elevation_deg <= 70.0 and 0.5 <= view.distance <= 1.0
        world = view.to_world(view.points)
        # Every object point lies on the box (sensor noise of a few mm), none under the table.
        assert placed.contains(world, 0.01).all()
        assert world[:, 2].min() > -0.005
        scene = view.to_world(view.scene_points)
        table = scene[np.abs(scene[:, 2]) < 0.005]
        assert len(scene) > len(view.points) and len(table) > 100
        # The up direction is the world's +z seen from the camera.
        np.testing.assert_allclose(view.camera_pose[:3, :3] @ view.up, [0.0, 0.0, 1.0], atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(
    azimuth=st.floats(0.0, 360.0),
    elevation=st.floats(5.0, 85.0),
    distance=st.floats(0.2, 3.0),
    points=st.lists(st.tuples(*[st.floats(-1.0, 1.0)] * 3), min_size=1, max_size=8),
    turn=st.floats(0.0, 2.0 * np.pi),
)
def test_camera_to_world_round_trips_points_and_grasp_poses(
    placed, azimuth, elevation, distance, points, turn
):
    pose = orbit_pose([0.1, 0.0, 0.05], distance, azimuth, elevation)
    empty = np.zeros((0, 3), dtype=np.float32)
    view = PhysicsView(placed, 0, empty, empty, pose, elevation, azimuth, distance, 0)
    camera = np.array(points)
    np.testing.assert_allclose(view.to_camera(view.to_world(camera)), camera, atol=1e-9)
    closing = [np.cos(turn), np.sin(turn), 0.3]
    grasp = grasp_matrix(camera[0], [0.2, -0.1, 1.0], closing)
    world = view.poses_to_world(grasp)
    # The pose's origin and axes move as points and directions do.
    np.testing.assert_allclose(world[:3, 3], view.to_world(camera[0]), atol=1e-9)
    np.testing.assert_allclose(world[:3, :3], pose[:3, :3] @ grasp[:3, :3], atol=1e-12)
    # Still a grasp pose of the convention: right-handed, x = y cross z.
    np.testing.assert_allclose(world[:3, :3].T @ world[:3, :3], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(np.cross(world[:3, 1], world[:3, 2]), world[:3, 0], atol=1e-9)


def test_grasp_matrix_follows_the_convention():
    pose = grasp_matrix([1.0, 2.0, 3.0], [0.0, 0.0, -2.0], [1.0, 0.0, 0.5])
    np.testing.assert_allclose(pose[:3, 2], [0.0, 0.0, -1.0])
    np.testing.assert_allclose(pose[:3, 1], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(pose[:3, 0], [0.0, 1.0, 0.0])  # y x z
    np.testing.assert_allclose(pose[:3, 3], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match='parallel'):
        grasp_matrix([0, 0, 0], [0, 0, 1], [0, 0, 2])


@pytest.mark.parametrize('contender', ['node', 'node_scene', 'node_lighter', 'paper', 'primitive'])
def test_the_contenders_world_poses_land_on_the_object(bench, placed, views, contender):
    propose = bench.PROPOSERS[contender]
    for view in views:
        poses = propose(view, FRANKA)
        assert poses, f'{contender} proposed nothing on {view.name}'
        for pose in poses:
            assert pose.shape == (4, 4)
            np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-6)
            assert placed.contains(pose[:3, 3], 0.03).all(), (contender, view.name, pose[:3, 3])


def test_the_primitive_closes_across_the_narrowest_side_from_above(placed):
    world = transform_points(placed.pose, box_object().vertices)
    surface = np.concatenate([world, (world[:, None] + world[None]).reshape(-1, 3) / 2.0])
    poses = primitive_grasps(surface, 0.08)
    # Sides 5 and 6 cm fit the 8 cm hand: two grasps, the 5 cm side first.
    assert len(poses) == 2
    x_axis = placed.pose[:3, 0]
    np.testing.assert_allclose(abs(poses[0][:3, 1] @ x_axis), 1.0, atol=1e-6)
    np.testing.assert_allclose(poses[0][:3, 2], [0.0, 0.0, -1.0])
    np.testing.assert_allclose(poses[0][:3, 3], [0.1, -0.05, BOX_SIZE[2] - 0.03], atol=1e-6)
    assert len(primitive_grasps(surface, 0.055)) == 1
    assert primitive_grasps(surface, 0.04) == []


@pytest.mark.parametrize(
    ('successes', 'trials', 'low', 'high'),
    [
        (5, 10, 0.2366, 0.7634),
        (0, 10, 0.0, 0.2775),
        (10, 10, 0.7225, 1.0),
        (81, 263, 0.2553, 0.3662),
    ],
)
def test_wilson_interval_on_known_values(successes, trials, low, high):
    interval = wilson_interval(successes, trials)
    np.testing.assert_allclose(interval, (low, high), atol=5e-5)
    assert (interval[0] == 0.0) == (successes == 0) and (interval[1] == 1.0) == (
        successes == trials
    )


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 2000).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))))
def test_wilson_interval_matches_scipy(counts):
    from scipy.stats import binomtest

    successes, trials = counts
    expected = binomtest(successes, trials).proportion_ci(method='wilson')
    np.testing.assert_allclose(
        wilson_interval(successes, trials), (expected.low, expected.high), atol=1e-9
    )
    with pytest.raises(ValueError):
        wilson_interval(trials + 1, trials)


def test_the_run_writes_the_promised_json_and_tables(bench, tmp_path, capsys):
    out = tmp_path / 'physics.json'
    code = bench.main(
        [
            '--set',
            'development',
            '--objects',
            '1',
            '--views',
            '2',
            '--contenders',
            'node,paper,primitive,cgn',
            '--cgn-python',
            str(tmp_path / 'no-venv' / 'python'),
            '--json',
            str(out),
            '--pictures',
            str(tmp_path / 'pictures'),
        ]
    )
    assert code == 0
    data = json.loads(out.read_text())
    printed = capsys.readouterr().out
    assert set(data['contenders']) == {'node', 'paper', 'primitive'}
    for name, summary in data['contenders'].items():
        assert summary['views'] == 2
        for key in ('top1', 'top5'):
            assert 0.0 <= summary[key] <= 1.0
            low, high = summary[f'{key}_ci']
            assert low <= summary[key] <= high
        assert summary['top1'] <= summary['top5']
        assert summary['seconds_per_view'] >= 0.0
        assert f'| development | {name} | 2 |' in printed
    assert data['sets']['development'].keys() == data['contenders'].keys()
    # Without its environment the CGN contender is skipped with the reason, and the run goes on.
    assert 'no-venv' in data['skipped']['cgn'] and 'contender cgn skipped' in printed
    records = data['records']
    assert records and {r['contender'] for r in records} <= {'node', 'paper', 'primitive'}
    for record in records:
        assert {
            'object',
            'view',
            'contender',
            'rank',
            'stage',
            'detail',
            'success',
            'judge',
        } <= set(record)
        assert 0 <= record['rank'] < bench.TOP_K
        # The paper's grasps go until contact (they close off their face-centre pose, unless
        # the trial stopped before: None); the others close where they were sent.
        if record['contender'] != 'paper':
            assert record['advance'] in (0.0, None), record
    # A paper grasp's advance is unknown exactly when its trial stopped before the approach ended
    # (the guarded approach itself is tested in test/evaluation/physics/test_trial.py).
    for record in records:
        if record['contender'] == 'paper':
            stopped = record['detail'].endswith(('pre-grasp pose', 'on the approach'))
            assert (record['advance'] is None) == stopped, record
    views = [v for v in data['views'] if v['contender'] == 'node']
    assert sum(v['top1'] for v in views) == round(data['contenders']['node']['top1'] * 2)
    judge = data['judge']['all']
    assert judge['grasps'] == len(records)
    assert sum(judge['confusion'].values()) == len(records)
    failures = [v for v in views if not v['top1']]
    assert (tmp_path / 'pictures' / 'node_failures_franka.png').exists() == bool(failures)
    paper_failures = [v for v in data['views'] if v['contender'] == 'paper' and not v['top1']]
    assert (tmp_path / 'pictures' / 'paper_failures_franka.png').exists() == bool(paper_failures)


def test_quick_mode_takes_fewer_views_when_contact_graspnet_runs(bench):
    with_cgn = bench.parse_args(['--quick'])
    assert 'cgn' in with_cgn.contenders and with_cgn.views == bench.QUICK_VIEWS_CGN
    without = bench.parse_args(['--quick', '--contenders', 'node,paper,primitive'])
    assert without.views == bench.QUICK_VIEWS > bench.QUICK_VIEWS_CGN
    assert with_cgn.default_objects == without.default_objects == bench.QUICK_OBJECTS
    assert bench.parse_args(['--quick', '--views', '3']).views == 3
    assert bench.parse_args([]).views == bench.FULL_VIEWS


def test_the_node_is_steady_on_a_static_view_and_counts_its_frame_pairs(bench, views):
    """Four frames of one view (fresh noise): three pairs, most of them the same grasp."""
    same, pairs = bench.node_steadiness(views[0], FRANKA, 4, 0.0)
    assert pairs == 3
    assert 2 <= same <= 3


def test_the_frames_of_a_view_differ_only_in_noise_or_in_the_camera_drift(views):
    """Frame 0 is the view's pose; with drift, frame k's camera moved k * drift sideways."""
    from mvbb_ros.evaluation.physics.views import view_frames

    view = views[0]
    frames = list(view_frames(view, 3, drift=0.002))
    np.testing.assert_allclose(frames[0].camera_pose, view.camera_pose)
    moved = frames[2].camera_pose[:3, 3] - view.camera_pose[:3, 3]
    np.testing.assert_allclose(moved, 0.004 * view.camera_pose[:3, 0], atol=1e-12)
    assert not np.array_equal(frames[0].points, frames[1].points)  # fresh noise


def test_pose_errors_are_the_same_for_every_contender_and_move_the_grasp_rigidly(bench, views):
    """One view's errors come from the seed and the view alone; a tried pose stays a pose."""
    first = bench.pose_errors(views[0], bench.TOP_K, (0.002, 3.0), seed=0)
    again = bench.pose_errors(views[0], bench.TOP_K, (0.002, 3.0), seed=0)
    other = bench.pose_errors(views[1], bench.TOP_K, (0.002, 3.0), seed=0)
    assert bench.pose_errors(views[0], bench.TOP_K, None, seed=0) is None
    assert len(first) == bench.TOP_K
    for error, same, different in zip(first, again, other, strict=True):
        np.testing.assert_array_equal(error, same)
        assert not np.allclose(error, different)
        rotation = error[:3, :3]
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) > 0.0
        angle = np.degrees(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))
        assert 0.0 < angle < 6 * 3.0 and 0.0 < np.linalg.norm(error[:3, 3]) < 6 * 0.002 * 3
    pose = grasp_matrix(np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, -1.0]), np.eye(3)[0])
    moved = bench.with_error(pose, first[0])
    np.testing.assert_allclose(moved[:3, 3] - pose[:3, 3], first[0][:3, 3])
    np.testing.assert_allclose(moved[:3, :3], first[0][:3, :3] @ pose[:3, :3])
    # No error: the grasp is tried where it was proposed.
    still = bench.pose_errors(views[0], 2, (0.0, 0.0), seed=0)
    np.testing.assert_array_equal(bench.with_error(pose, still[0]), pose)


def test_a_pose_error_is_parsed_in_millimetres_and_degrees(bench):
    assert bench.parse_args(['--pose-error', '2,3']).pose_error == (0.002, 3.0)
    assert bench.parse_args([]).pose_error is None
    for bad in ('2', 'a,b', '-1,3'):
        with pytest.raises(SystemExit):
            bench.parse_args(['--pose-error', bad])
