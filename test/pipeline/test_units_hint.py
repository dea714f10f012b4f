"""The units hint: a cloud in millimetres read as metres gets one note, and the same answer."""

from __future__ import annotations

from mvbb_ros.pipeline import process
from mvbb_ros.pipeline.process import (
    implausible_extent,
    millimetre_hint,
    MM_SPACING_M,
    MM_SPAN_M,
    process_points,
)
from mvbb_ros.pipeline.settings import settings_from_mapping
import numpy as np
import pytest
from support.data import require_shared_data

#: The node's pipeline without its region of interest (3 m around the sensor, which drops a
#: whole cloud in millimetres) and without the shape completion (a quick test).
SETTINGS = settings_from_mapping(
    {'shape_completion': 'none', 'roi_max_distance': 0.0, 'support_plane': 'none'}
)


def test_the_rule_is_a_wide_cloud_with_sparse_points():
    assert millimetre_hint((MM_SPAN_M * 1.1, 1.0, 1.0), MM_SPACING_M * 1.1) is not None
    assert millimetre_hint((1.0, 1.0, MM_SPAN_M * 1.1), MM_SPACING_M * 1.1) is not None
    assert millimetre_hint((MM_SPAN_M * 0.9, 1.0, 1.0), MM_SPACING_M * 4) is None, 'narrow'
    assert millimetre_hint((MM_SPAN_M * 30, 1.0, 1.0), MM_SPACING_M * 0.9) is None, 'dense'
    note = millimetre_hint((160.0, 240.0, 156.0), 1.2)
    assert note is not None and note.startswith('looks like millimetres: ')
    assert '0.16 x 0.24 x 0.156 m' in note


def test_a_real_scan_in_millimetres_gets_the_note_and_the_same_boxes(monkeypatch):
    metres = np.load(require_shared_data('scans', 'mosd_learn0_obj1.npy'))
    millimetres = metres.astype(np.float64) * 1000.0
    assert process_points(metres, SETTINGS).units_note is None
    hinted = process_points(millimetres, SETTINGS)
    assert hinted.units_note is not None and 'looks like millimetres' in hinted.units_note
    assert hinted.notes[0] == hinted.units_note
    monkeypatch.setattr(process, 'millimetre_hint', lambda span, spacing: None)
    plain = process_points(millimetres, SETTINGS)
    assert plain.units_note is None and hinted.leaves, 'the hint only adds a note'
    assert [box.extents.tolist() for box in hinted.leaves] == [
        box.extents.tolist() for box in plain.leaves
    ]
    assert [g.score for g in hinted.grasps] == [g.score for g in plain.grasps]


def test_with_the_node_defaults_a_cloud_in_millimetres_is_emptied_and_says_why():
    millimetres = np.load(require_shared_data('scans', 'mosd_learn0_obj1.npy')) * 1000.0
    result = process_points(millimetres)
    assert result.warning is not None and 'left after filtering' in result.warning
    assert result.units_note is not None and result.notes == [result.units_note]


@pytest.mark.parametrize(
    'name', ['models/graspit_mug_surface5k.npy', 'scans/pcl_kinect_laptop.npy']
)
def test_millimetre_and_metre_clouds_of_the_shared_data(name):
    points = np.load(require_shared_data(*name.split('/')))
    in_mm = name.startswith('models/graspit')  # the GraspIt! models are in millimetres
    assert (process_points(points, SETTINGS).units_note is not None) == in_mm


def test_a_lidar_scene_in_metres_gets_no_note():
    from mvbb_ros.pipeline.decode import read_xyz
    from mvbb_ros.ros.bag import CloudBag

    with CloudBag(require_shared_data('bags', 'embag_luminar_lidar_ros2')) as bag:
        cloud = next(bag.clouds(['/luminar_pointcloud'])).message()
    points = read_xyz(cloud)
    points = points[np.isfinite(points).all(axis=1)]
    span = points.max(axis=0) - points.min(axis=0)
    assert span.max() > MM_SPAN_M, 'a scene hundreds of metres wide'
    assert millimetre_hint(span, process.point_spacing(points, 0.0)) is None


def test_a_workspace_in_millimetres_is_refused_with_the_hint():
    workspace = np.array([[0.0, 0.0, 0.0], [1500.0, 800.0, 600.0]])
    reason = implausible_extent(workspace)
    assert (
        reason is not None and 'looks like millimetres' in reason and '1.5 x 0.8 x 0.6 m' in reason
    )
    garbage = np.array([[0.0, 0.0, 0.0], [3e30, 1.0, 1.0]])
    assert 'millimetres' not in implausible_extent(garbage)
