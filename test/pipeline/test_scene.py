"""
The scene stage: the table under the objects, what stands on it, and clouds without a table.

Synthetic table-top frames (``cli/synthetic.py``: objects on a table, a wall behind it and the
floor, seen by the project's depth camera) must give one object per object placed, no box
below the table and the table's normal within 2 degrees; a segmented object must give the
same boxes and grasps with ``support_plane: auto`` as with ``none``, bit for bit, on every
real scan of the shared data.
"""

from __future__ import annotations

from pathlib import Path

from hypothesis import example, given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st
from mvbb_ros.arrays import perpendicular_axes
from mvbb_ros.evaluation.synthetic import segmented_object_cloud, table_top_frame
from mvbb_ros.pipeline.outline import inside_outline
from mvbb_ros.pipeline.plane import MAX_TILT_DEG
from mvbb_ros.pipeline.process import process_points, RESTING_GAP
from mvbb_ros.pipeline.scene import find_scene, roi_mask, SceneSettings, standing_mask
from mvbb_ros.pipeline.settings import PipelineSettings
import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from support.data import load_benchmark, require_shared_data, SHARED_DATA

SCANS = SHARED_DATA / 'scans'


def _finite(points: np.ndarray) -> np.ndarray:
    flat = points.reshape(-1, 3)
    return flat[np.all(np.isfinite(flat), axis=1)]


def _share_above(box, plane: np.ndarray) -> float:
    """Return the share of `box`'s volume above `plane` (a, b, c, d), sampled."""
    local = np.random.default_rng(0).uniform(-0.5, 0.5, (4000, 3)) * box.extents
    return float(np.mean(box.to_world(local) @ plane[:3] + plane[3] > 0.0))


@pytest.mark.parametrize('seed', range(5))
def test_table_top_frames_give_one_object_per_object_placed(seed):
    frame = table_top_frame(seed, 1 + seed)
    result = process_points(_finite(frame.points), PipelineSettings())

    assert result.warning is None
    assert len(result.objects) == frame.objects
    support = result.support
    assert support is not None and not support.fixed
    truth = frame.table_plane
    angle = np.degrees(np.arccos(min(1.0, float(support.normal @ truth[:3]))))
    assert angle < 2.0, 'the normal points up, within 2 degrees'
    assert abs(support.offset - truth[3]) < 0.01
    assert result.up_source == 'support plane'
    np.testing.assert_allclose(result.up, support.normal)
    for box in result.leaves:
        assert _share_above(box, truth) >= 0.8, 'no box below the table'
    # A resting object's hidden side ends at the table: filled down to it, never below it. An
    # object whose base is hidden (behind another) is not known to rest there: not filled.
    for item in result.objects:
        heights = item.shape.points @ truth[:3] + truth[3]
        assert heights.min() > -0.005
        observed = heights[slice(item.shape.observed)]
        seen_base = observed.min() <= RESTING_GAP
        if item.shape.plane is not None and seen_base:
            assert heights.min() < 0.01
    # No grasp approaches through the table: every pre-grasp position is above it.
    for grasp in result.grasps:
        assert grasp.position @ truth[:3] + truth[3] > 0.0


def test_a_fixed_plane_is_used_as_given():
    frame = table_top_frame(2, 3)
    coefficients = [float(v) for v in 2.0 * frame.table_plane]  # any scale
    settings = PipelineSettings().updated(
        {'support_plane': 'fixed', 'support_coefficients': coefficients}
    )
    result = process_points(_finite(frame.points), settings)
    assert result.support is not None and result.support.fixed
    np.testing.assert_allclose(result.support.coefficients, frame.table_plane, atol=1e-12)
    assert len(result.objects) == 3


def test_a_fixed_plane_needs_its_coefficients():
    with pytest.raises(ValueError, match='support_coefficients'):
        PipelineSettings().updated({'support_plane': 'fixed'})


def _same_result(first, second) -> None:
    assert first.warning == second.warning
    assert first.counts == second.counts
    assert len(first.leaves) == len(second.leaves)
    for mine, other in zip(first.leaves, second.leaves, strict=True):
        np.testing.assert_array_equal(mine.center, other.center)
        np.testing.assert_array_equal(mine.rotation, other.rotation)
        np.testing.assert_array_equal(mine.extents, other.extents)
    assert len(first.grasps) == len(second.grasps)
    for mine, other in zip(first.grasps, second.grasps, strict=True):
        np.testing.assert_array_equal(mine.position, other.position)
        np.testing.assert_array_equal(mine.quaternion, other.quaternion)
        assert (mine.width, mine.score) == (other.width, other.score)


def _auto_and_none(points: np.ndarray) -> None:
    auto = process_points(points, PipelineSettings())
    none = process_points(
        points, PipelineSettings().updated({'support_plane': 'none', 'roi_max_distance': 0.0})
    )
    assert auto.support is None, auto.support_note
    assert auto.support_note is not None
    _same_result(auto, none)


def test_a_segmented_object_is_processed_as_without_the_scene_stage():
    _auto_and_none(segmented_object_cloud('mug', seed=0).astype(np.float64))


@pytest.mark.skipif(not SCANS.is_dir(), reason=f'shared data absent: {SCANS}')
@pytest.mark.parametrize(
    'name', sorted(path.name for path in SCANS.glob('*.npy')) if SCANS.is_dir() else []
)
def test_every_real_scan_is_processed_as_without_the_scene_stage(name):
    _auto_and_none(np.load(Path(SCANS, name)))


def test_the_region_of_interest_drops_far_points():
    points = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 5.0], [3.0, 0.0, 0.0]])
    np.testing.assert_array_equal(roi_mask(points, (0, 0, 0), 3.0), [True, False, True])
    assert roi_mask(points, (0, 0, 0), 0.0) is None
    assert roi_mask(points, (0, 0, 0), 10.0) is None
    single = points.astype(np.float32)
    np.testing.assert_array_equal(roi_mask(single, (0, 0, 0), 3.0), [True, False, True])
    # Bounds well within reach spare the pass over the points; bounds beyond it do not.
    assert roi_mask(points, (0, 0, 0), 6.0, bounds=[[0, 0, 0], [3, 0, 5]]) is None
    np.testing.assert_array_equal(
        roi_mask(points, (0, 0, 0), 4.0, bounds=[[0, 0, 0], [3, 0, 5]]), [True, False, True]
    )


def _table_with_a_box(rotation: np.ndarray, height: float, seed: int) -> np.ndarray:
    """Return a 0.8 x 0.6 m table (local z = 0) with a 10 cm box on it, in a turned frame."""
    rng = np.random.default_rng(seed)
    table = np.column_stack(
        [rng.uniform(-0.4, 0.4, 6000), rng.uniform(-0.3, 0.3, 6000), rng.normal(0, 0.002, 6000)]
    )
    box = rng.uniform([-0.05, -0.05, 0.0], [0.05, 0.05, 0.1], (1500, 3))
    return np.concatenate([table, box]) @ rotation.T + rotation @ [0.0, 0.0, height]


@hypothesis_settings(max_examples=25, deadline=None)
@given(
    quaternion=st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(
        lambda q: np.linalg.norm(q) > 0.1
    ),
    height=st.floats(-2.0, 2.0),
    eye_xy=st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0)),
    seed=st.integers(0, 1000),
)
def test_the_plane_faces_the_sensor_and_its_outline_holds_its_points(
    quaternion, height, eye_xy, seed
):
    rotation = Rotation.from_quat(quaternion).as_matrix()
    points = _table_with_a_box(rotation, height, seed)
    up = rotation[:, 2]
    eye = rotation @ [eye_xy[0], eye_xy[1], height + 1.0]
    scene = find_scene(
        points, SceneSettings(support_plane='auto'), viewpoint=eye, spacing=0.01, min_points=25
    )
    support = scene.support
    assert support is not None, scene.reason
    assert support.heights(eye[None])[0] > 0.0, 'the normal points to the sensor'
    assert abs(support.normal @ up - 1.0) < 1e-3
    assert np.all(np.abs(support.heights(support.outline)) < 1e-9), 'the outline is in the plane'
    # Seen from above (the module's frame: first, second, normal), the outline is
    # counter-clockwise and holds every table point's projection.
    axes = np.stack(perpendicular_axes(support.normal))
    table = points[np.abs(support.heights(points)) <= 0.01]
    assert np.all(inside_outline(table @ axes.T, support.outline @ axes.T, -1e-9))
    # The box stands on the table (its lowest centimetre is counted as table), the table goes.
    assert scene.kept is not None and len(scene.kept) >= 1275  # the lowest 1 cm goes
    assert np.all(support.heights(points[scene.kept]) > 0.01)


@hypothesis_settings(max_examples=15, deadline=None)
@given(tilt=st.floats(0.0, 40.0), turn=st.floats(0.0, 360.0), seed=st.integers(0, 1000))
# A RANSAC plane slicing the table at 13 degrees across the box, refitted once, passed here.
@example(tilt=26.0, turn=0.0, seed=0)
@example(tilt=23.0, turn=45.0, seed=6)
def test_with_up_given_only_a_level_plane_is_a_support(tilt, turn, seed):
    """
    A plane tilted past MAX_TILT_DEG from the given up is no support, whatever else it passes.

    A large flat face of a segmented object with a part standing on it looks like a table
    with an object; a table is level, the face of an object lying on one usually is not.
    """
    rotation = Rotation.from_euler('z', turn, degrees=True).as_matrix()
    points = _table_with_a_box(rotation, -0.8, seed)
    tipped = Rotation.from_euler('zx', [turn, tilt], degrees=True).as_matrix()
    scene = find_scene(
        points,
        SceneSettings(support_plane='auto'),
        viewpoint=(0.0, 0.0, 0.0),
        up=tipped[:, 2],
        spacing=0.01,
        min_points=25,
    )
    if tilt <= MAX_TILT_DEG - 0.5:
        assert scene.support is not None, scene.reason
    elif tilt >= MAX_TILT_DEG + 0.5:
        assert scene.support is None and scene.kept is None


def test_the_laptop_and_the_box_on_the_floor_are_two_objects():
    """They stand 3 cm apart and touch in the view: two footprints on the floor, two objects."""
    require_shared_data('scenes', 'pcl_kinect_laptop_box_frame.pcd')
    require_shared_data('scans', 'pcl_kinect_laptop.npy')
    scenes = load_benchmark('scenes')
    points, labels = scenes.scene_truth('pcl_kinect_laptop_box_frame')
    result = process_points(points, PipelineSettings())
    assert result.support is not None
    tree = cKDTree(points)
    found = [
        labels[tree.query(item.shape.points[: item.shape.observed])[1]] for item in result.objects
    ]
    owners = []
    for label in (0, 1):  # the laptop, the box
        shares = [np.count_nonzero(mine == label) / len(mine) for mine in found]
        owners.append(int(np.argmax(shares)))
        assert max(shares) > 0.9, 'an object of its own, nearly all of it'
    assert owners[0] != owners[1]


@pytest.mark.parametrize('seed', range(3))
def test_the_whole_cloud_cut_agrees_with_the_scene_stage(seed):
    """`standing_mask` (one pass over a whole frame) keeps what `find_scene` keeps."""
    rotation = Rotation.random(random_state=seed).as_matrix()
    points = _table_with_a_box(rotation, 0.3, seed)
    eye = rotation @ [0.1, 0.2, 1.3]
    settings = SceneSettings(support_plane='auto')
    scene = find_scene(points, settings, viewpoint=eye, spacing=0.01, min_points=25)
    assert scene.support is not None and scene.kept is not None
    np.testing.assert_array_equal(
        np.flatnonzero(standing_mask(points, scene.support, settings)), scene.kept
    )
    # float32 points (as decoded) give the same cut but for points on its edges.
    single = standing_mask(points.astype(np.float32), scene.support, settings)
    assert np.count_nonzero(single != standing_mask(points, scene.support, settings)) <= 3


def _grid(low: tuple[float, float], high: tuple[float, float], step: float) -> np.ndarray:
    first, second = (np.arange(a, b + 1e-9, step) for a, b in zip(low, high, strict=True))
    return np.stack(np.meshgrid(first, second, indexing='ij'), axis=-1).reshape(-1, 2)


def test_a_table_in_front_of_a_larger_wall_is_the_support_not_the_wall():
    """
    Take the table, not the larger wall behind it, as the support (no up direction given).

    The largest plane is the wall and the table stands on it: a plane with another wide plane
    standing on it is a wall, and the table in front of it is the support.
    """
    step = 0.01
    wall = _grid((-0.8, 0.0), (0.8, 1.2), step)  # x, z on y = 0.6: 19,481 points
    table = _grid((-0.5, -0.2), (0.5, 0.55), step)  # x, y on z = 0.4: 7,676 points
    box = _grid((-0.04, 0.16), (0.04, 0.24), step / 2)  # the top of a 10 cm tall box
    side = _grid((-0.04, 0.41), (0.04, 0.5), step / 2)  # its front face, on y = 0.16
    points = np.concatenate(
        [
            np.column_stack([wall[:, 0], np.full(len(wall), 0.6), wall[:, 1]]),
            np.column_stack([table, np.full(len(table), 0.4)]),
            np.column_stack([box, np.full(len(box), 0.5)]),
            np.column_stack([side[:, 0], np.full(len(side), 0.16), side[:, 1]]),
        ]
    )
    points += np.random.default_rng(0).normal(0.0, 0.001, points.shape)
    scene = find_scene(
        points,
        SceneSettings(support_plane='auto'),
        viewpoint=(0.0, -1.2, 0.9),
        spacing=step,
        min_points=25,
    )
    support = scene.support
    assert support is not None, scene.reason
    assert abs(support.normal @ np.array([0.0, 0.0, 1.0])) > np.cos(np.radians(2.0)), scene.reason
    assert scene.kept is not None and np.all(points[scene.kept, 2] > 0.41)


def test_an_objects_face_with_the_object_behind_it_holds_nothing_standing():
    """A segmented box seen from the front: its face is the largest plane, and no support."""
    step = 0.005
    front = _grid((-0.1, -0.1), (0.1, 0.1), step)  # x, z on y = 0.5, facing the sensor
    top = _grid((-0.1, 0.5 + step), (0.1, 0.6), step)  # x, y on z = 0.1, behind the face
    points = np.concatenate(
        [
            np.column_stack([front[:, 0], np.full(len(front), 0.5), front[:, 1]]),
            np.column_stack([top, np.full(len(top), 0.1)]),
        ]
    )
    scene = find_scene(points, SceneSettings(support_plane='auto'), spacing=step, min_points=10)
    assert scene.support is None and scene.kept is None
    assert scene.reason is not None
    assert scene.reason.startswith('no support: plane 0: 0 points stand on it'), scene.reason


def test_no_plane_is_fitted_to_fewer_points_than_a_support_holds(monkeypatch):
    """A plate's face holds nearly every point: the rest cannot hold 15 %, and is not fitted."""
    import mvbb_ros.pipeline.scene as scene_module

    step = 0.005
    face = _grid((-0.1, -0.1), (0.1, 0.1), step)
    points = np.column_stack([face, np.full(len(face), 0.5)])
    points = np.concatenate([points, points[:20] + (0.0, 0.0, 0.02)])  # a few behind it
    fitted = []

    def counted(points, rest, *args):
        fitted.append(int(np.count_nonzero(rest)))
        return next_plane(points, rest, *args)

    next_plane = scene_module._next_plane
    monkeypatch.setattr(scene_module, '_next_plane', counted)
    settings = SceneSettings(support_plane='auto')
    scene = find_scene(points, settings, spacing=step, min_points=10)
    assert scene.support is None and scene.kept is None
    assert fitted == [len(points)], fitted  # the 20 left are under 15 % of 1,701
    assert scene.reason == 'no support: plane 0: 0 points stand on it', scene.reason
