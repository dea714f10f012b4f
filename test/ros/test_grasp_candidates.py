"""
Per-grasp and per-box data as PointCloud2 (issue 18, item 9): ~/grasp_candidates, ~/box_list.

Read back with the project's decoder (:func:`mvbb_ros.pipeline.decode.read_fields`) and with a
reader written here from the PointField rules alone (struct, field by field), as any other
PointCloud2 reader would.
"""

from __future__ import annotations

import struct

from builtin_interfaces.msg import Time
from mvbb_ros import process_points
from mvbb_ros.pipeline.decode import CloudFormatError, read_fields, read_xyz
from mvbb_ros.ros.encode import create_cloud_xyz
from mvbb_ros.ros.messages import (
    BOX_FLOAT_FIELDS,
    BOX_INDEX_FIELDS,
    box_list_cloud,
    grasp_candidates_cloud,
    GRASP_FLOAT_FIELDS,
    GRASP_INDEX_FIELDS,
)
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import PointField
from std_msgs.msg import Header
from support.ros_graph import Graph
from support.shapes import l_shape_points
from visualization_msgs.msg import Marker

GRASP_FIELDS = ('x', 'y', 'z', *GRASP_FLOAT_FIELDS, *GRASP_INDEX_FIELDS)
BOX_FIELDS = ('x', 'y', 'z', *BOX_FLOAT_FIELDS, *BOX_INDEX_FIELDS)
_STRUCT_CODES = {PointField.FLOAT32: 'f', PointField.INT32: 'i'}


def _struct_rows(cloud) -> list[dict[str, float]]:
    """Read every point field by field with struct, from the offsets and datatypes alone."""
    order = '>' if cloud.is_bigendian else '<'
    data = bytes(cloud.data)
    rows = []
    for row in range(cloud.height):
        for column in range(cloud.width):
            start = row * cloud.row_step + column * cloud.point_step
            rows.append(
                {
                    field.name: struct.unpack_from(
                        order + _STRUCT_CODES[field.datatype], data, start + field.offset
                    )[0]
                    for field in cloud.fields
                }
            )
    return rows


@pytest.fixture(scope='module')
def result():
    return process_points(l_shape_points())


def test_grasp_candidates_hold_every_grasp_in_order(result):
    header = Header(frame_id='camera', stamp=Time(sec=3, nanosec=4))
    cloud = grasp_candidates_cloud(result.grasps, header)
    assert [field.name for field in cloud.fields] == list(GRASP_FIELDS)
    floats = 3 + len(GRASP_FLOAT_FIELDS)
    assert [f.datatype for f in cloud.fields] == [PointField.FLOAT32] * floats + [
        PointField.INT32
    ] * len(GRASP_INDEX_FIELDS)
    assert cloud.header == header and cloud.height == 1 and cloud.width == len(result.grasps)
    assert cloud.point_step == 4 * len(GRASP_FIELDS), 'packed: 13 fields of 4 bytes'

    ours = read_fields(cloud)
    theirs = _struct_rows(cloud)
    assert list(ours) == list(GRASP_FIELDS)
    assert len(theirs) == len(result.grasps) > 0
    for index, (grasp, row) in enumerate(zip(result.grasps, theirs, strict=True)):
        for name in GRASP_FIELDS:
            assert ours[name][index] == row[name], f'{name} of grasp {index}'
        np.testing.assert_allclose([row['x'], row['y'], row['z']], grasp.position, atol=1e-6)
        quaternion = [row['qx'], row['qy'], row['qz'], row['qw']]
        np.testing.assert_allclose(quaternion, grasp.quaternion, atol=1e-6)
        assert row['width'] == pytest.approx(grasp.width, rel=1e-6)
        assert row['score'] == pytest.approx(grasp.score, rel=1e-6)
        assert row['depth'] == pytest.approx(grasp.depth, rel=1e-6)
        assert (row['box_index'], row['object_index'], row['face']) == (
            grasp.box_index,
            grasp.object_index,
            grasp.face,
        )
    assert ours['box_index'].dtype == np.int32 and ours['width'].dtype == np.float32
    np.testing.assert_array_equal(read_xyz(cloud), np.stack([ours['x'], ours['y'], ours['z']], 1))


def test_box_list_rows_are_the_leaves_then_the_inner_boxes(result):
    cloud = box_list_cloud(result, Header(frame_id='camera'))
    assert [field.name for field in cloud.fields] == list(BOX_FIELDS)
    rows = read_fields(cloud)
    (item,) = result.objects
    decomposition = item.decomposition
    leaves = decomposition.leaf_nodes
    inner = [node for node in decomposition.nodes if node.children]
    assert cloud.width == len(leaves) + len(inner) == 3, 'the L shape: a root and two leaves'
    np.testing.assert_array_equal(rows['leaf'], [1] * len(leaves) + [0] * len(inner))
    for row, node in enumerate([*leaves, *inner]):
        np.testing.assert_allclose(
            [rows[n][row] for n in ('x', 'y', 'z')], node.box.center, atol=1e-6
        )
        sizes = [rows[n][row] for n in ('size_x', 'size_y', 'size_z')]
        np.testing.assert_allclose(sizes, node.box.extents, rtol=1e-6)
        observed = int(np.count_nonzero(node.point_indices < item.shape.observed))
        assert rows['point_count'][row] == observed
        assert rows['object_index'][row] == 0
    root_row = len(leaves)
    assert list(rows['parent']) == [root_row, root_row, -1]
    empty = box_list_cloud(None, Header())
    assert empty.width == 0 and {
        name: len(v) for name, v in read_fields(empty).items()
    } == dict.fromkeys(BOX_FIELDS, 0)


def test_read_fields_names_a_missing_field(result):
    cloud = grasp_candidates_cloud(result.grasps, Header())
    assert set(read_fields(cloud, ['width', 'face'])) == {'width', 'face'}
    with pytest.raises(CloudFormatError, match='gripper'):
        read_fields(cloud, ['gripper'])


def test_read_fields_reads_big_endian_padded_clouds():
    points = np.arange(12, dtype=np.float64).reshape(4, 3)
    cloud = create_cloud_xyz(
        points,
        fields_extra={'ring': np.array([1, 2, 3, 4], dtype=np.uint16)},
        is_bigendian=True,
        point_step=40,
    )
    fields = read_fields(cloud)
    np.testing.assert_array_equal(fields['ring'], [1, 2, 3, 4])
    np.testing.assert_array_equal(fields['z'], points[:, 2].astype(np.float32))
    assert fields['ring'].dtype == np.dtype('=u2')


@pytest.mark.ros
def test_node_publishes_candidates_like_its_grasps():
    graph = Graph()
    try:
        cloud = create_cloud_xyz(l_shape_points(), frame_id='camera_optical_frame')
        cloud.header.stamp = Time(sec=42, nanosec=7)
        grasps = graph.publish_until_answered(graph.publisher(), cloud)

        def stamped(messages):
            return [m for m in messages if (m.header.stamp.sec, m.header.stamp.nanosec) == (42, 7)]

        assert graph.spin_until(lambda: stamped(graph.candidates) and stamped(graph.box_lists))
        candidates = stamped(graph.candidates)[-1]
        box_list = read_fields(stamped(graph.box_lists)[-1])
        assert candidates.header == grasps.header, 'stamped like ~/grasps'
        rows = read_fields(candidates)
        assert len(rows['x']) == len(grasps.poses) > 0, 'one point per grasp'
        maximum = graph.node.settings.grasps.gripper_max_width
        for index, pose in enumerate(grasps.poses):
            position = [pose.position.x, pose.position.y, pose.position.z]
            q = pose.orientation
            np.testing.assert_allclose(
                [rows['x'][index], rows['y'][index], rows['z'][index]], position, atol=1e-6
            )
            quaternion = [rows[n][index] for n in ('qx', 'qy', 'qz', 'qw')]
            np.testing.assert_allclose(quaternion, [q.x, q.y, q.z, q.w], atol=1e-6)
            # As documented: the opening the object needs along the closing line (the gripper's
            # y axis with approach_axis z) plus the width margin: on the L shape's boxes, about
            # the box's extent there plus 1 cm, within the gripper's reach.
            box = int(rows['box_index'][index])
            assert box_list['leaf'][box] == 1
            box_rotation = Rotation.from_quat(
                [box_list[n][box] for n in ('qx', 'qy', 'qz', 'qw')]
            ).as_matrix()
            closing = Rotation.from_quat(quaternion).as_matrix()[:, 1]
            sizes = np.array([box_list[n][box] for n in ('size_x', 'size_y', 'size_z')])
            along = float(np.abs(box_rotation.T @ closing) @ sizes)  # the box's extent there
            margin = graph.node.settings.refinement.width_margin
            assert rows['width'][index] <= min(along + margin + 0.01, maximum) + 1e-6
            assert rows['width'][index] >= 0.045, 'the L shape is 5 cm thick everywhere'
            assert rows['depth'][index] > graph.node.settings.grasps.standoff
            assert 0.0 <= rows['score'][index] <= 1.0
            assert 0 <= rows['face'][index] < 6 and rows['object_index'][index] == 0
        expected = [g.score for g in graph.node._last_result.grasps]
        np.testing.assert_allclose(rows['score'], expected, rtol=1e-6)
        cubes = [m for m in graph.boxes[-1].markers if m.type == Marker.CUBE]
        assert int(np.sum(box_list['leaf'])) == len(cubes)
    finally:
        graph.close()
