"""Objects cut by the view's edge: the frame's outline, the gaps, their grasps last."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from mvbb_ros.evaluation.synthetic import cut_table_top_frame, table_top_frame
from mvbb_ros.pipeline.process import process_points
from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.pipeline.view_edge import edge_gaps, view_outline
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.data import load_benchmark, require_shared_data
from support.shapes import l_shape_points

OFF = PipelineSettings().updated({'view_edge_margin_deg': 0.0})
SCENES = load_benchmark('scenes')


def _camera_frame(seed: int, half_width_deg: float, half_height_deg: float) -> tuple:
    """
    Return a pinhole frame (H, W, 3) at random depths, seen from a random pose, and its eye.

    The image spans +-`half_width_deg` and +-`half_height_deg` about its optical axis.
    """
    rng = np.random.default_rng(seed)
    columns, rows = 48, 36
    u = np.linspace(-1.0, 1.0, columns) * math.tan(math.radians(half_width_deg))
    v = np.linspace(-1.0, 1.0, rows) * math.tan(math.radians(half_height_deg))
    grid_u, grid_v = np.meshgrid(u, v)
    rays = np.stack([grid_u, grid_v, np.ones_like(grid_u)], axis=-1)
    depths = rng.uniform(0.5, 3.0, (rows, columns, 1))
    rotation = Rotation.random(random_state=seed).as_matrix()
    eye = rng.uniform(-2.0, 2.0, 3)
    return (rays * depths) @ rotation.T + eye, eye


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(5.0, 55.0), st.floats(5.0, 45.0))
def test_the_outline_of_a_camera_frame_is_its_image_border(seed, half_width, half_height):
    """Seen from its eye, a pinhole frame's border pixels lie on its outline, the rest inside."""
    frame, eye = _camera_frame(seed, half_width, half_height)
    outline = view_outline(frame.reshape(-1, 3), eye)
    assert outline is not None
    gaps = edge_gaps(outline, frame.reshape(-1, 3)).reshape(frame.shape[:2])
    border = np.zeros(gaps.shape, dtype=bool)
    border[0], border[-1], border[:, 0], border[:, -1] = True, True, True, True
    assert np.abs(gaps[border]).max() < 1e-9
    inner = gaps[2:-2, 2:-2]
    assert inner.min() > 0.0
    # Along its line of sight a point keeps its gap: the outline is of directions.
    farther = (
        eye + (frame - eye) * np.random.default_rng(seed).uniform(0.2, 5.0, gaps.shape)[..., None]
    )
    np.testing.assert_allclose(
        edge_gaps(outline, farther.reshape(-1, 3)), gaps.ravel(), rtol=1e-9, atol=1e-12
    )


def test_clouds_that_are_not_one_view_have_no_outline():
    angles = np.linspace(0.0, 2.0 * np.pi, 360, endpoint=False)
    sweep = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)]) * 10.0
    assert view_outline(sweep, (0.0, 0.0, 0.0)) is None, 'a LiDAR sweep around the sensor'
    assert view_outline(sweep[:2], (0.0, 0.0, 0.0)) is None
    at_the_eye = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.0, 0.0]])
    assert view_outline(at_the_eye, (0.0, 0.0, 0.0)) is None, 'two points with a direction'


def test_points_at_the_viewpoint_are_left_out_of_the_outline():
    """Some depth drivers write a pixel without depth as (0, 0, 0): it has no direction."""
    frame, eye = _camera_frame(5, 30.0, 20.0)
    flat = frame.reshape(-1, 3)
    outline = view_outline(flat, eye)
    holes = np.concatenate([flat, np.tile(eye, (50, 1))])
    with_holes = view_outline(np.random.default_rng(0).permutation(holes), eye)
    assert outline is not None and with_holes is not None
    np.testing.assert_allclose(edge_gaps(with_holes, flat), edge_gaps(outline, flat), atol=1e-9)


@pytest.mark.parametrize(('seed', 'count'), [(2, 3), (9, 5)])
def test_the_object_the_image_edge_cuts_is_found_and_its_grasps_come_last(seed, count):
    points, labels, cut = cut_table_top_frame(seed, count)
    result = process_points(points, PipelineSettings())
    assert result.support is not None
    owners = SCENES.object_owners(result, points, labels)
    assert cut in owners
    for item, owner in zip(result.objects, owners, strict=True):
        assert item.view_edge is not None
        assert item.cut_by_view == (owner == cut), (owner, item.view_edge)
    assert result.cut_objects == [owners.index(cut)]
    ranks = [grasp.object_index in result.cut_objects for grasp in result.grasps]
    assert ranks == sorted(ranks) and not ranks[0], 'the whole objects first'
    # Without the rule the cut object's grasps are ranked by score among the others'.
    plain = process_points(points, OFF)
    assert all(item.view_edge is None for item in plain.objects)
    whole = [g for g in result.grasps if g.object_index not in result.cut_objects]
    by_score = [g for g in plain.grasps if g.object_index not in result.cut_objects]
    assert [g.score for g in by_score] == [g.score for g in whole][: len(by_score)]
    if seed == 9:
        assert plain.grasps[0].object_index in result.cut_objects, 'the rule changed the top'


def test_a_previous_grasp_on_a_cut_object_does_not_stay_above_a_whole_objects():
    points, _, _ = cut_table_top_frame(9, 5)
    plain = process_points(points, OFF)
    result = process_points(points, PipelineSettings())
    on_cut = plain.grasps[0]
    assert on_cut.object_index in result.cut_objects
    again = process_points(points, PipelineSettings(), previous=on_cut)
    assert not again.refinement.kept_previous
    assert again.grasps[0].object_index not in result.cut_objects
    # With the rule off the same previous grasp stays on top (it is the best there).
    assert process_points(points, OFF, previous=on_cut).refinement.kept_previous


@pytest.mark.parametrize('seed', range(3))
def test_whole_rendered_frames_have_no_cut_object(seed):
    """The rendered frames place every object well inside the image."""
    frame = table_top_frame(seed, 1 + seed)
    flat = frame.points.reshape(-1, 3)
    result = process_points(flat[np.all(np.isfinite(flat), axis=1)], PipelineSettings())
    assert result.objects and all(item.view_edge is not None for item in result.objects)
    assert result.cut_objects == []
    assert min(item.view_edge.gap_deg for item in result.objects) > 1.0


def test_without_a_support_plane_nothing_is_measured():
    result = process_points(l_shape_points(), PipelineSettings())
    assert result.support is None and result.objects
    assert all(item.view_edge is None for item in result.objects)


def test_in_the_laptop_frame_the_panels_at_the_edge_are_cut_and_the_laptop_grasped_first():
    """The frame the rule was made on: background panels at the edge of its valid depth."""
    require_shared_data('scenes', 'pcl_kinect_laptop_box_frame.pcd')
    points, labels = SCENES.scene_truth('pcl_kinect_laptop_box_frame')
    result = process_points(points, PipelineSettings())
    owners = SCENES.object_owners(result, points, labels)
    laptop, box = owners.index(0), owners.index(1)
    assert not result.objects[laptop].cut_by_view and not result.objects[box].cut_by_view
    assert result.cut_objects, 'the panels at the right edge of the view'
    assert all(owners[index] not in (0, 1) for index in result.cut_objects)
    assert result.grasps[0].object_index == laptop


def test_without_the_refinement_the_hypotheses_of_cut_objects_come_last_too():
    points, _, _ = cut_table_top_frame(9, 5)
    paper_grasps = PipelineSettings().updated({'grasp_refinement': False, 'max_grasps': 0})
    plain = process_points(points, paper_grasps.updated({'view_edge_margin_deg': 0.0}))
    result = process_points(points, paper_grasps)
    assert result.cut_objects and plain.grasps
    # The paper's ranking within each group, the whole objects' group first.
    expected = sorted(plain.grasps, key=lambda g: g.object_index in result.cut_objects)
    assert expected != plain.grasps, 'the rule moved some hypotheses'
    assert [g.to_dict() for g in result.grasps] == [g.to_dict() for g in expected]
    bounded = process_points(points, paper_grasps.updated({'max_grasps': 5}))
    assert [g.to_dict() for g in bounded.grasps] == [g.to_dict() for g in expected[:5]]


def test_in_another_frame_the_same_objects_are_cut_with_the_viewpoint_set_and_none_without():
    """The outline is of directions from `viewpoint`: any frame, as long as it is the sensor's."""
    points, _, _ = cut_table_top_frame(9, 5)
    camera = process_points(points, PipelineSettings())
    rotation = Rotation.from_euler('xyz', [100.0, -20.0, 35.0], degrees=True).as_matrix()
    shift = np.array([0.4, -1.2, 0.9])
    moved = (points.astype(np.float64) @ rotation.T + shift).astype(np.float32)
    seen = process_points(moved, PipelineSettings().updated({'viewpoint': shift.tolist()}))
    assert seen.cut_objects == camera.cut_objects
    assert [item.view_edge.cut for item in seen.objects] == [
        item.view_edge.cut for item in camera.objects
    ]
    # Seen from above the scene (not the sensor), an object's completion finds the cloud is not
    # one view from there: nothing is measured.
    above = points.astype(np.float64).mean(axis=0) - [0.0, 1.0, 0.0]  # the camera's y is down
    lost = process_points(points, PipelineSettings().updated({'viewpoint': above.tolist()}))
    assert lost.support is not None
    assert any(item.shape.skipped is not None for item in lost.objects)
    assert lost.cut_objects == [] and all(item.view_edge is None for item in lost.objects)
