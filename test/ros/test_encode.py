"""
The PointCloud2 encoder (ros.encode): layouts, options, rclpy and rosbags messages, serialization.

Every cloud it makes is read back with the reference decoder of :mod:`support.pointcloud2`.
"""

from __future__ import annotations

import array
import struct
from types import SimpleNamespace
from typing import Any

from mvbb_ros.pipeline.decode import read_xyz, read_xyz_grid
from mvbb_ros.ros.encode import create_cloud_xyz, to_rclpy_cloud, to_rosbags_cloud
import numpy as np
import pytest

# In flake8-import-order's order (ruff's isort sorts INT8 before INT16).
from support.pointcloud2 import (
    as_message,
    build_layout_case,
    constructed_bag_clouds,
    decode_reference,
    expected_points,
    FLOAT32,
    FLOAT64,
    grid_indices,
    INT16,
    INT32,
    INT8,
    NUMPY_TYPES,
    random_column,
    STRUCT_FORMATS,
    typestore,
    UINT16,
    UINT32,
    UINT8,
)


def read_field_reference(cloud: Any, name: str) -> list[tuple]:
    """Every point's values of one field, point by point with struct.unpack_from."""
    data = bytes(cloud.data)
    endian = '>' if cloud.is_bigendian else '<'
    field = next(field for field in cloud.fields if field.name == name)
    fmt = endian + STRUCT_FORMATS[field.datatype] * field.count
    return [
        struct.unpack_from(fmt, data, row * cloud.row_step + col * cloud.point_step + field.offset)
        for row, col in grid_indices(cloud.height, cloud.width)
    ]


def test_create_cloud_xyz_default_layout():
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2

    points = np.random.default_rng(5).normal(size=(10, 3))
    message = create_cloud_xyz(points, frame_id='camera', stamp=Time(sec=12, nanosec=34))

    assert isinstance(message, PointCloud2)
    assert [(f.name, f.offset, f.datatype, f.count) for f in message.fields] == [
        ('x', 0, FLOAT32, 1),
        ('y', 4, FLOAT32, 1),
        ('z', 8, FLOAT32, 1),
    ]
    assert (message.height, message.width, message.point_step, message.row_step) == (
        1,
        10,
        12,
        120,
    )
    assert message.is_bigendian is False and message.is_dense is True
    assert isinstance(message.data, array.array) and len(message.data) == 120
    assert (message.header.frame_id, message.header.stamp.sec, message.header.stamp.nanosec) == (
        'camera',
        12,
        34,
    )
    expected = points.astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(read_xyz(message), expected)
    np.testing.assert_array_equal(decode_reference(message), expected)


@pytest.mark.parametrize('dtype', [np.float32, np.float64])
@pytest.mark.parametrize('is_bigendian', [False, True])
@pytest.mark.parametrize('point_step', [None, 40])
def test_create_cloud_xyz_layout_options_match_the_reference_decoder(
    dtype, is_bigendian, point_step
):
    points = np.random.default_rng(6).normal(size=(6, 3))
    points[2, 1] = np.nan
    message = create_cloud_xyz(
        points, dtype=dtype, is_bigendian=is_bigendian, point_step=point_step
    )

    size = np.dtype(dtype).itemsize
    assert message.point_step == (point_step or 3 * size)
    assert message.is_bigendian is is_bigendian and message.is_dense is False
    first_x = bytes(message.data[:size])
    assert first_x == struct.pack(('>' if is_bigendian else '<') + 'fd'[size // 8], points[0, 0])
    expected = points.astype(dtype).astype(np.float64)
    np.testing.assert_array_equal(decode_reference(message, skip_nonfinite=False), expected)
    np.testing.assert_array_equal(read_xyz(message), expected[np.isfinite(expected).all(axis=1)])
    if point_step:
        xyz_bytes = 3 * size
        padding = np.frombuffer(message.data, np.uint8).reshape(6, point_step)[:, xyz_bytes:]
        assert not padding.any()


@pytest.mark.parametrize('datatype', [INT8, UINT8, INT16, UINT16, INT32, UINT32])
def test_create_cloud_xyz_with_integer_coordinates(datatype):
    rng = np.random.default_rng(datatype)
    points = random_column(rng, datatype, (7, 3))
    message = create_cloud_xyz(points.astype(np.float64), dtype=NUMPY_TYPES[datatype])

    assert {field.datatype for field in message.fields} == {datatype}
    np.testing.assert_array_equal(read_xyz(message), points.astype(np.float64))
    with pytest.raises(ValueError, match='not all integers in the range'):
        create_cloud_xyz(points + 0.5, dtype=NUMPY_TYPES[datatype])


def test_create_cloud_xyz_organized():
    grid = np.random.default_rng(7).normal(size=(3, 4, 3)).astype(np.float32)
    grid[1, 1] = np.nan
    from_grid = create_cloud_xyz(grid)
    from_flat = create_cloud_xyz(grid.reshape(-1, 3), organized_shape=(3, 4))

    for message in (from_grid, from_flat):
        assert (message.height, message.width, message.row_step) == (3, 4, 48)
        np.testing.assert_array_equal(read_xyz_grid(message), grid.astype(np.float64))
        assert read_xyz(message).shape == (11, 3)
    assert bytes(from_grid.data) == bytes(from_flat.data)


def test_create_cloud_xyz_extra_fields():
    rng = np.random.default_rng(8)
    points = rng.normal(size=(5, 3))
    rgb = rng.random(5).astype(np.float32)
    intensity = rng.integers(0, 2**16, 5).astype(np.uint16)
    normals = rng.normal(size=(5, 3))
    message = create_cloud_xyz(
        points,
        fields_extra={'rgb': rgb, 'intensity': intensity, 'normal': normals},
        is_bigendian=True,
        point_step=64,
    )

    layout = [(f.name, f.offset, f.datatype, f.count) for f in message.fields]
    assert layout == [
        ('x', 0, FLOAT32, 1),
        ('y', 4, FLOAT32, 1),
        ('z', 8, FLOAT32, 1),
        ('rgb', 12, FLOAT32, 1),
        ('intensity', 16, UINT16, 1),
        ('normal', 18, FLOAT64, 3),
    ]
    assert read_field_reference(message, 'rgb') == [(value,) for value in rgb.tolist()]
    assert read_field_reference(message, 'intensity') == [(value,) for value in intensity.tolist()]
    assert read_field_reference(message, 'normal') == [tuple(row) for row in normals.tolist()]
    np.testing.assert_array_equal(read_xyz(message), points.astype(np.float32).astype(np.float64))


@pytest.mark.parametrize(
    ('arguments', 'message_pattern'),
    [
        ({'points': np.zeros((4, 2))}, r'shape \(N, 3\) or \(H, W, 3\)'),
        ({'points': np.zeros(3)}, r'shape \(N, 3\) or \(H, W, 3\)'),
        ({'organized_shape': (3, 3)}, 'does not hold 4 points'),
        ({'points': np.zeros((2, 2, 3)), 'organized_shape': (1, 4)}, r'!= points shape'),
        ({'dtype': np.int64}, 'no PointField datatype'),
        ({'dtype': np.float16}, 'no PointField datatype'),
        ({'fields_extra': {'x': np.zeros(4, np.float32)}}, 'other than x/y/z'),
        ({'fields_extra': {'rgb': np.zeros(5, np.float32)}}, "'rgb' has shape"),
        ({'fields_extra': {'rgb': np.zeros(4, np.int64)}}, 'int64, which has no PointField'),
        ({'point_step': 11}, r'point_step 11 is smaller than the fields \(12 bytes\)'),
        ({'frame_id': 'a', 'header': SimpleNamespace()}, 'either header or frame_id/stamp'),
    ],
)
def test_create_cloud_xyz_rejects_bad_arguments(arguments, message_pattern):
    arguments = {'points': np.zeros((4, 3)), **arguments}
    with pytest.raises(ValueError, match=message_pattern):
        create_cloud_xyz(**arguments)


def test_create_cloud_xyz_header_and_stamp_types():
    from rclpy.time import Time as RclpyTime

    points = np.zeros((2, 3))
    stamped = create_cloud_xyz(points, stamp=RclpyTime(seconds=3, nanoseconds=5))
    rosbags_header = typestore().types['std_msgs/msg/Header'](
        stamp=typestore().types['builtin_interfaces/msg/Time'](sec=7, nanosec=8), frame_id='bag'
    )
    copied = create_cloud_xyz(points, header=rosbags_header)

    assert (stamped.header.stamp.sec, stamped.header.stamp.nanosec) == (3, 5)
    assert (copied.header.frame_id, copied.header.stamp.sec, copied.header.stamp.nanosec) == (
        'bag',
        7,
        8,
    )


def test_rclpy_serialization_round_trip():
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    rng = np.random.default_rng(9)
    grid = rng.normal(size=(3, 5, 3))
    grid[0, 0] = np.nan
    messages = [
        create_cloud_xyz(rng.normal(size=(20, 3)), frame_id='a'),
        create_cloud_xyz(grid, dtype=np.float64, is_bigendian=True, point_step=40),
        create_cloud_xyz(np.zeros((0, 3))),
        create_cloud_xyz(rng.normal(size=(4, 3)), fields_extra={'rgb': rng.random(4)}),
        to_rclpy_cloud(as_message(build_layout_case('organized with row padding')[0], 'rosbags')),
    ]
    for message in messages:
        restored = deserialize_message(serialize_message(message), PointCloud2)
        assert restored == message
        np.testing.assert_array_equal(
            read_xyz(restored, skip_nonfinite=False), read_xyz(message, skip_nonfinite=False)
        )


def test_conversion_between_rclpy_and_rosbags_through_each_others_serializer():
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    store = typestore()
    msgtype = 'sensor_msgs/msg/PointCloud2'
    spec, columns = build_layout_case('big-endian float64 organized with row padding')
    original = as_message(spec, 'rclpy')
    original.header.frame_id = 'lidar'

    in_bag = to_rosbags_cloud(original, store)
    from_rclpy_bytes = store.deserialize_cdr(serialize_message(original), msgtype)
    back_in_rclpy = deserialize_message(bytes(store.serialize_cdr(in_bag, msgtype)), PointCloud2)

    assert back_in_rclpy == original
    assert to_rclpy_cloud(from_rclpy_bytes) == original
    for message in (in_bag, from_rclpy_bytes, back_in_rclpy):
        np.testing.assert_array_equal(read_xyz(message), expected_points(columns))
        assert message.header.frame_id == 'lidar' and message.header.stamp.nanosec == 2
    assert not np.shares_memory(in_bag.data, np.frombuffer(original.data, np.uint8))


def test_conversion_to_a_ros1_typestore():
    from rosbags.typesys import get_typestore, Stores

    store = get_typestore(Stores.ROS1_NOETIC)
    message = create_cloud_xyz(np.arange(12.0).reshape(4, 3), frame_id='old')
    in_ros1 = to_rosbags_cloud(message, store)
    restored = store.deserialize_ros1(
        store.serialize_ros1(in_ros1, in_ros1.__msgtype__), in_ros1.__msgtype__
    )

    assert restored.header.seq == 0 and restored.header.frame_id == 'old'
    np.testing.assert_array_equal(read_xyz(restored), np.arange(12.0).reshape(4, 3))


@pytest.fixture(scope='module')
def constructed_clouds() -> list:
    return constructed_bag_clouds()


def test_bag_clouds_survive_conversion_to_rclpy_and_serialization(constructed_clouds):
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    for _, _, message in constructed_clouds[:2]:
        restored = deserialize_message(serialize_message(to_rclpy_cloud(message)), PointCloud2)
        np.testing.assert_array_equal(read_xyz_grid(restored), read_xyz_grid(message))
        assert restored.header.frame_id == message.header.frame_id
