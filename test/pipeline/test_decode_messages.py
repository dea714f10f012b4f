"""
The PointCloud2 decoder (pipeline.decode) on messages: every layout, malformed clouds, real bags.

Clouds are built by the reference encoder of :mod:`support.pointcloud2` and checked against the
values they were built from and against its per-point reference decoder. The compiled kernels
against the reference, without rclpy or Open3D, are in ``test_decode.py``.
"""

from __future__ import annotations

import array
import dataclasses
import re
from types import SimpleNamespace
from typing import Any

from hypothesis import event, given, HealthCheck, settings
from hypothesis import strategies as st
from mvbb_ros.pipeline.decode import CloudFormatError, read_xyz, read_xyz_grid
import numpy as np
import pytest
from support.data import require_shared_data

# In flake8-import-order's order (ruff's isort sorts INT8 before INT16).
from support.pointcloud2 import (
    as_message,
    build_layout_case,
    CloudSpec,
    constructed_bag_clouds,
    decode_reference,
    encode_reference,
    expected_points,
    Field,
    FLOAT32,
    FLOAT64,
    FLOAT_DATATYPES,
    INT16,
    INT32,
    INT8,
    LAYOUT_CASES,
    pack_fields,
    random_column,
    read_bag_clouds,
    STRUCT_SIZES,
    UINT16,
    UINT32,
    UINT8,
)

ALL_DATATYPES = (INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64)


FLAVOURS = ('plain', 'rclpy', 'rosbags')


def data_snapshot(message: Any) -> bytes:
    return bytes(message.data)


@pytest.mark.parametrize('flavour', FLAVOURS)
@pytest.mark.parametrize('case', list(LAYOUT_CASES))
def test_every_layout_decodes_to_the_encoded_values(case, flavour):
    spec, columns = build_layout_case(case)
    message = as_message(spec, flavour)
    before = data_snapshot(message)

    points = read_xyz(message)

    np.testing.assert_array_equal(points, expected_points(columns))
    np.testing.assert_array_equal(points, decode_reference(message))
    assert data_snapshot(message) == before
    assert points.dtype == np.float64


@pytest.mark.parametrize('flavour', FLAVOURS)
def test_result_is_a_writable_contiguous_copy_not_a_view_of_the_message(flavour):
    spec, columns = build_layout_case('packed xyz float32 unorganized')
    message = as_message(spec, flavour)
    before = data_snapshot(message)

    points = read_xyz(message)
    grid = read_xyz_grid(message)

    for result in (points, grid, read_xyz(message, skip_nonfinite=False)):
        assert result.flags.c_contiguous
        assert result.flags.writeable
        assert not np.shares_memory(result, np.frombuffer(message.data, dtype=np.uint8))
    points[:] = 0.0
    grid[:] = 0.0
    assert data_snapshot(message) == before
    np.testing.assert_array_equal(read_xyz(message), expected_points(columns))


@pytest.mark.parametrize('flavour', FLAVOURS)
@pytest.mark.parametrize('is_dense_claim', [True, False])
def test_nonfinite_points_are_dropped_whatever_is_dense_says(flavour, is_dense_claim):
    rng = np.random.default_rng(3)
    shape = (4, 6)
    columns = {name: random_column(rng, FLOAT32, shape) for name in 'xyz'}
    columns['x'][0, 1] = np.nan
    columns['y'][1, 2] = np.inf
    columns['z'][2, 3] = -np.inf
    columns['x'][3, :] = np.nan  # a whole invalid row, as depth cameras produce
    fields, packed = pack_fields([(name, FLOAT32, 1) for name in 'xyz'], [0, 0, 0])
    spec = encode_reference(columns, fields, point_step=packed + 4, is_dense=is_dense_claim)
    message = as_message(spec, flavour)

    points = read_xyz(message)
    everything = read_xyz(message, skip_nonfinite=False)

    assert points.shape == (4 * 6 - 3 - 6, 3)
    assert np.isfinite(points).all()
    np.testing.assert_array_equal(points, expected_points(columns))
    assert everything.shape == (24, 3)
    np.testing.assert_array_equal(everything, expected_points(columns, skip_nonfinite=False))


def test_organized_grid_keeps_structure_and_the_mask_recipe_matches_read_xyz():
    spec, columns = build_layout_case('organized with row padding')
    columns['z'][1, 2] = np.nan
    fields = spec.fields
    spec = encode_reference(
        columns,
        fields,
        point_step=spec.point_step,
        row_padding=spec.row_step - 5 * spec.point_step,
    )
    message = as_message(spec, 'rclpy')

    grid = read_xyz_grid(message)
    valid = np.isfinite(grid).all(axis=2)

    assert grid.shape == (4, 5, 3)
    np.testing.assert_array_equal(grid[..., 0], columns['x'].astype(np.float64))
    np.testing.assert_array_equal(grid[..., 2], columns['z'].astype(np.float64))
    assert valid.sum() == 19 and not valid[1, 2]
    np.testing.assert_array_equal(grid[valid], read_xyz(message))


@pytest.mark.parametrize('flavour', FLAVOURS)
def test_last_row_may_end_at_the_last_point_and_longer_data_is_ignored(flavour):
    name = 'organized with row padding'
    short, columns = build_layout_case(name, last_row_short=True)
    long, _ = build_layout_case(name, tail=b'\x00\x00\xc0\x7f' * 9)
    assert len(short.data) == 3 * short.row_step + short.width * short.point_step

    for spec in (short, long):
        np.testing.assert_array_equal(
            read_xyz(as_message(spec, flavour)), expected_points(columns)
        )
    truncated = dataclasses.replace(short, data=short.data[:-1])
    with pytest.raises(CloudFormatError, match='data has'):
        read_xyz(as_message(truncated, flavour))


@pytest.mark.parametrize('flavour', FLAVOURS)
@pytest.mark.parametrize(('height', 'width'), [(0, 5), (3, 0), (0, 0)])
def test_zero_points_give_an_empty_array(flavour, height, width):
    fields, packed = pack_fields([(name, FLOAT32, 1) for name in 'xyz'], [0, 0, 0])
    spec = CloudSpec(height, width, fields, False, packed, width * packed, b'')

    points = read_xyz(as_message(spec, flavour))

    assert points.shape == (0, 3) and points.dtype == np.float64
    assert read_xyz_grid(as_message(spec, flavour)).shape == (height, width, 3)


@pytest.mark.parametrize(
    'data',
    [
        pytest.param(lambda raw: raw, id='bytes'),
        pytest.param(bytearray, id='bytearray'),
        pytest.param(memoryview, id='memoryview'),
        pytest.param(list, id='list of ints'),
        pytest.param(lambda raw: np.repeat(np.frombuffer(raw, np.uint8), 2)[::2], id='strided'),
        pytest.param(lambda raw: array.array('B', raw), id='array.array'),
    ],
)
def test_data_may_be_any_bytes_like_container(data):
    spec, columns = build_layout_case('zyx order with intensity in between')
    message = as_message(spec, 'plain')
    message.data = data(spec.data)

    np.testing.assert_array_equal(read_xyz(message), expected_points(columns))


def test_fields_of_unknown_datatype_other_than_xyz_are_ignored():
    spec, columns = build_layout_case('zyx order with intensity in between')
    spec.fields[1] = Field('intensity', 4, 0, 1)  # datatype 0: not a PointField type
    spec.fields.append(Field('future', 999, 42, 7))

    np.testing.assert_array_equal(read_xyz(as_message(spec, 'plain')), expected_points(columns))


def valid_spec() -> CloudSpec:
    spec, _ = build_layout_case('PCL-like point_step 32 padding')  # x y z at 0 4 8, rgb at 16
    return spec


def with_fields(*fields: Field, **changes: Any) -> CloudSpec:
    return dataclasses.replace(valid_spec(), fields=list(fields), **changes)


X, Y, Z = (Field(name, 4 * index, FLOAT32) for index, name in enumerate('xyz'))


RGB = Field('rgb', 16, FLOAT32)


MALFORMED = {
    'no z field': (with_fields(X, Y, RGB), r"no field\(s\) \['z'\]"),
    'no fields at all': (with_fields(), r"no field\(s\) \['x', 'y', 'z'\]"),
    'duplicated x': (with_fields(X, Y, Z, Field('x', 16, FLOAT32)), "'x' appears more than once"),
    'z beyond point_step': (with_fields(X, Y, Field('z', 30, FLOAT32)), 'beyond point_step 32'),
    'extra field beyond point_step': (
        with_fields(X, Y, Z, Field('rgb', 16, FLOAT64, 3)),
        "'rgb'.*beyond point_step",
    ),
    'point_step smaller than the fields': (
        with_fields(X, Y, Z, point_step=10),
        "'z'.*ends at byte 12, beyond point_step 10",
    ),
    'count 2 for y': (with_fields(X, Field('y', 4, FLOAT32, 2), Z), "'y' must have count 1"),
    'count 0 for z': (with_fields(X, Y, Field('z', 8, FLOAT32, 0)), "'z' must have count 1"),
    'unknown datatype for x': (with_fields(Field('x', 0, 9), Y, Z), "'x' has unknown datatype 9"),
    'datatype 0 for y': (with_fields(X, Field('y', 4, 0), Z), "'y' has unknown datatype 0"),
    'x and y overlap': (with_fields(X, Field('y', 2, FLOAT32), Z), "'x' and 'y' overlap"),
    'row_step smaller than width * point_step': (
        dataclasses.replace(valid_spec(), row_step=9 * 32 - 1),
        r'row_step 287 is smaller than width \* point_step',
    ),
    'data one byte short': (
        dataclasses.replace(valid_spec(), data=valid_spec().data[:-1]),
        'data has 287 bytes.* need 288',
    ),
    'no data': (dataclasses.replace(valid_spec(), data=b''), 'data has 0 bytes'),
}


@pytest.mark.parametrize('flavour', FLAVOURS)
@pytest.mark.parametrize('case', list(MALFORMED))
def test_malformed_clouds_are_rejected_with_a_clear_message(case, flavour):
    spec, message_pattern = MALFORMED[case]
    message = as_message(spec, flavour)
    before = data_snapshot(message)

    with pytest.raises(CloudFormatError, match=message_pattern):
        read_xyz(message)
    assert data_snapshot(message) == before


@pytest.mark.parametrize(
    ('change', 'message_pattern'),
    [
        ({'width': -1}, r'width must be in \[0, 2\*\*32 - 1\]'),
        ({'height': 2**32}, r'height must be in \[0, 2\*\*32 - 1\]'),
        ({'point_step': 16.0}, 'point_step must be an integer'),
        ({'row_step': '288'}, 'row_step must be an integer'),
        ({'height': True}, 'height must be an integer, got a bool'),
        ({'is_bigendian': 'yes'}, 'is_bigendian must be a bool'),
        ({'fields': [Field('x', 0, True), Y, Z]}, "'x' has unknown datatype True"),
        ({'fields': 5}, 'fields must be a sequence'),
        ({'fields': [X, Y, 'z']}, "not a PointField: it has no attribute 'name'"),
        ({'fields': [X, Y, Z, Field(b'rgb', 16, FLOAT32)]}, 'non-string name'),
        ({'fields': [X, Y, Field('z', -8, FLOAT32)]}, "'z' offset must be in"),
        ({'data': 3.5}, 'data must be bytes-like'),
        ({'data': [0, 1, 300]}, 'data must be bytes-like'),
        ({'data': np.array([object()] * 288)}, 'data must hold bytes'),
        ({'data': None}, 'data must be bytes-like'),
    ],
)
def test_duck_typed_clouds_with_bad_attribute_values_are_rejected(change, message_pattern):
    message = as_message(valid_spec(), 'plain')
    for attribute, value in change.items():
        setattr(message, attribute, value)

    with pytest.raises(CloudFormatError, match=message_pattern):
        read_xyz(message)


def test_an_object_without_cloud_attributes_is_rejected():
    with pytest.raises(CloudFormatError, match="not a PointCloud2: it has no attribute 'height'"):
        read_xyz(np.zeros((5, 3)))


def test_cloud_format_error_is_a_value_error():
    # Callers (the node) may catch ValueError for every bad input.
    with pytest.raises(ValueError, match='data has 0 bytes'):
        read_xyz(as_message(dataclasses.replace(valid_spec(), data=b''), 'plain'))


#: Header numbers that break the uint32 rule: negative, beyond int32/uint32, beyond int64.
weird_numbers = st.one_of(
    st.integers(-3, -1), st.integers(2**31 - 2, 2**32 + 2), st.sampled_from([2**63, 2**64])
)


weird_datatypes = st.one_of(st.integers(-1, 10), st.sampled_from([7.0, None, True]))


def mostly(plausible: st.SearchStrategy, weird: st.SearchStrategy) -> st.SearchStrategy:
    """Draw from plausible about 19 times in 20, else from weird (shrinking towards plausible)."""
    return st.sampled_from([plausible] * 19 + [weird]).flatmap(lambda strategy: strategy)


@st.composite
def valid_layouts(draw: st.DrawFn) -> tuple[CloudSpec, dict, str]:
    """Any valid layout: field order, datatypes, gaps, padding, endianness, shape, NaN holes."""
    entries = [(name, draw(st.sampled_from(ALL_DATATYPES)), 1) for name in 'xyz']
    extras = draw(
        st.lists(st.tuples(st.sampled_from(ALL_DATATYPES), st.integers(1, 3)), max_size=2)
    )
    entries += [
        (f'extra{index}', datatype, count) for index, (datatype, count) in enumerate(extras)
    ]
    entries = draw(st.permutations(entries))
    gaps = draw(st.lists(st.integers(0, 5), min_size=len(entries), max_size=len(entries)))
    fields, packed = pack_fields(entries, gaps)
    shape = (
        draw(mostly(st.integers(1, 4), st.just(0))),
        draw(mostly(st.integers(1, 6), st.just(0))),
    )
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    columns = {}
    for name, datatype, _ in entries:
        if name in 'xyz':
            columns[name] = random_column(rng, datatype, shape)
            if datatype in FLOAT_DATATYPES:
                holes = rng.random(shape) < draw(st.sampled_from([0.0, 0.2, 1.0]))
                columns[name][holes] = rng.choice([np.nan, np.inf, -np.inf], size=holes.sum())
    spec = encode_reference(
        columns,
        fields,
        point_step=packed + draw(st.integers(0, 9)),
        row_padding=draw(st.integers(0, 11)),
        is_bigendian=draw(st.booleans()),
        last_row_short=draw(st.booleans()),
        tail=draw(st.binary(max_size=7)),
        is_dense=draw(st.booleans()),
        seed=seed,
    )
    return spec, columns, draw(st.sampled_from(FLAVOURS))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(valid_layouts())
def test_property_any_valid_layout_matches_the_reference_decoder(layout):
    spec, columns, flavour = layout
    message = as_message(spec, flavour)
    before = data_snapshot(message)

    points = read_xyz(message)
    everything = read_xyz(message, skip_nonfinite=False)

    np.testing.assert_array_equal(points, decode_reference(message))
    np.testing.assert_array_equal(points, expected_points(columns))
    np.testing.assert_array_equal(everything, decode_reference(message, skip_nonfinite=False))
    assert points.shape[1] == 3 and points.dtype == np.float64 and points.flags.c_contiguous
    assert data_snapshot(message) == before


@st.composite
def random_clouds(draw: st.DrawFn) -> SimpleNamespace:
    """Clouds with random headers, fields and bytes: often valid, often slightly broken."""
    names = [name for name in 'xyz' if draw(mostly(st.just(True), st.just(False)))]
    names += draw(
        st.lists(st.sampled_from(['rgb', 'intensity', '', 'X', 'label', 'x']), max_size=2)
    )
    fields, offset = [], 0
    for name in draw(st.permutations(names)):
        datatype = draw(mostly(st.sampled_from(ALL_DATATYPES), weird_datatypes))
        offset += draw(st.integers(0, 3))
        fields.append(
            SimpleNamespace(
                name=name,
                offset=draw(mostly(st.just(offset), st.integers(0, 24) | weird_numbers)),
                datatype=datatype,
                count=draw(mostly(st.just(1), st.integers(0, 3) | weird_numbers)),
            )
        )
        offset += STRUCT_SIZES.get(datatype, 1) if isinstance(datatype, int) else 1
    point_step = draw(mostly(st.integers(-1, 8).map(lambda extra: offset + extra), weird_numbers))
    height = draw(mostly(st.integers(1, 4), st.just(0) | weird_numbers))
    width = draw(mostly(st.integers(1, 8), st.just(0) | weird_numbers))
    row_step = draw(
        mostly(
            st.integers(-1, 12).map(lambda extra: max(0, width * point_step + extra)),
            weird_numbers,
        )
    )
    # Mostly enough bytes (or a few more), sometimes fewer; never more than 3000.
    needed = min(max(max(height - 1, 0) * row_step + width * point_step, 0), 3000)
    length = draw(mostly(st.integers(needed, needed + 6), st.integers(0, needed + 2)))
    raw = np.random.default_rng(draw(st.integers(0, 2**32 - 1))).bytes(length)
    data = draw(
        st.sampled_from(
            [
                raw,
                np.frombuffer(raw, np.uint8),
                array.array('B', raw),
                memoryview(raw),
                list(raw)[:40] + draw(st.lists(st.integers(-1, 256), max_size=2)),
            ]
        )
    )
    return SimpleNamespace(
        height=height,
        width=width,
        point_step=point_step,
        row_step=row_step,
        is_bigendian=draw(mostly(st.booleans(), st.integers(0, 2))),
        is_dense=draw(st.booleans()),
        fields=fields,
        data=data,
    )


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(random_clouds())
def test_property_random_headers_and_bytes_give_a_valid_result_or_our_error(cloud):
    try:
        points = read_xyz(cloud, skip_nonfinite=False)
    except CloudFormatError as error:
        event(f'rejected: {re.sub(r"[0-9]+", "#", str(error))[:50]}')
        return
    event('decoded' if points.size else 'decoded, no points')
    assert points.shape == (cloud.height * cloud.width, 3)
    np.testing.assert_array_equal(points, decode_reference(cloud, skip_nonfinite=False))


LUMINAR_FIELDS = [
    ('x', 0, FLOAT32, 1),
    ('y', 4, FLOAT32, 1),
    ('z', 8, FLOAT32, 1),
    ('intensity', 16, FLOAT32, 1),
    ('time_sec', 20, UINT32, 1),
    ('time_nsec', 24, UINT32, 1),
    ('laser_id', 28, UINT16, 1),
]


@pytest.fixture(scope='module')
def luminar_clouds() -> dict[str, list]:
    return {
        bag: read_bag_clouds(bag)
        for bag in ('embag_luminar_lidar_ros1.bag', 'embag_luminar_lidar_ros2')
    }


@pytest.mark.parametrize('bag', ['embag_luminar_lidar_ros1.bag', 'embag_luminar_lidar_ros2'])
def test_luminar_lidar_bag_clouds(luminar_clouds, bag):
    clouds = luminar_clouds[bag]

    assert len(clouds) == 5
    for topic, _, message in clouds:
        assert topic == '/luminar_pointcloud' and message.header.frame_id == 'luminar_lidar'
        assert [(f.name, f.offset, f.datatype, f.count) for f in message.fields] == LUMINAR_FIELDS
        assert (message.height, message.point_step, message.is_dense) == (1, 32, True)
        assert message.row_step == 32 * message.width == len(message.data)
        before = data_snapshot(message)
        points = read_xyz(message)
        assert points.shape == (message.width, 3)  # no NaNs, per the MANIFEST
        ranges = np.linalg.norm(points, axis=1)
        assert 3.0 < ranges.min() and ranges.max() < 260.0  # "ranges ~4-250 m"
        assert np.median(points[:, 1]) > 0  # "y is forward"
        assert data_snapshot(message) == before
    first = clouds[0][2]
    assert first.width == 35707  # the MANIFEST describes the first cloud
    np.testing.assert_array_equal(read_xyz(first), decode_reference(first))


def test_luminar_ros1_and_ros2_bags_decode_to_the_same_points(luminar_clouds):
    ros1 = luminar_clouds['embag_luminar_lidar_ros1.bag']
    ros2 = luminar_clouds['embag_luminar_lidar_ros2']

    assert [time for _, time, _ in ros1] == [time for _, time, _ in ros2]
    for (_, _, from_ros1), (_, _, from_ros2) in zip(ros1, ros2, strict=True):
        np.testing.assert_array_equal(read_xyz(from_ros1), read_xyz(from_ros2))


#: /segmented_object messages of the constructed bag, in time order, from the MANIFEST:
#: (scans/ file stem, point count, frame, has rgb).
CONSTRUCTED_OBJECTS = [
    ('pcl_stereo_mug', 15212, 'stereo_optical_frame', False),
    ('pcl_kinect_laptop', 36800, 'camera_rgb_optical_frame', True),
    ('pcl_kinect_box', 12993, 'camera_rgb_optical_frame', True),
    ('mosd_learn33_obj1', 15305, 'camera_rgb_optical_frame', True),
    ('mosd_learn33_obj2', 9289, 'camera_rgb_optical_frame', True),
    ('mosd_learn33_obj3', 5735, 'camera_rgb_optical_frame', True),
    ('mosd_learn33_obj4', 3949, 'camera_rgb_optical_frame', True),
    ('mosd_learn33_obj5', 3336, 'camera_rgb_optical_frame', True),
]


@pytest.fixture(scope='module')
def constructed_clouds() -> list:
    return constructed_bag_clouds()


def test_constructed_bag_organized_scene(constructed_clouds):
    topic, time, scene = constructed_clouds[0]

    assert (topic, time) == ('/camera/depth_registered/points', 1_700_000_000_000_000_000)
    assert (scene.height, scene.width, scene.point_step, scene.is_dense) == (480, 640, 16, False)
    grid = read_xyz_grid(scene)
    valid = np.isfinite(grid).all(axis=2)
    points = read_xyz(scene)
    assert grid.shape == (480, 640, 3)
    assert points.shape == (179131, 3)  # the MANIFEST's point count of mosd_learn33
    assert valid.sum() == 179131 and (~valid).sum() == 307200 - 179131
    assert not np.isfinite(grid[~valid]).all(axis=1).any()
    np.testing.assert_array_equal(grid[valid], points)
    assert 0.3 < np.median(points[:, 2]) < 3.0  # Kinect depths, metres


def test_constructed_bag_object_clouds_equal_the_wrapped_scans(constructed_clouds):
    objects = constructed_clouds[1:]
    scene_points = read_xyz(constructed_clouds[0][2])
    scene_rows = set(map(bytes, scene_points))

    assert len(objects) == len(CONSTRUCTED_OBJECTS)
    for index, ((topic, time, message), (stem, count, frame, has_rgb)) in enumerate(
        zip(objects, CONSTRUCTED_OBJECTS, strict=True)
    ):
        assert (
            topic == '/segmented_object'
            and time == 1_700_000_000_000_000_000 + (index + 1) * 10**9
        )
        assert message.header.frame_id == frame and message.is_dense
        assert (message.height, message.width, message.point_step) == (1, count, 16)
        assert [field.name for field in message.fields] == ['x', 'y', 'z', 'rgb'][: 3 + has_rgb]
        points = read_xyz(message)
        scan = np.load(require_shared_data('scans', f'{stem}.npy'))
        assert points.shape == (count, 3)
        np.testing.assert_array_equal(points, scan.astype(np.float64))
        if stem.startswith('mosd_learn33'):  # cut out of the scene above: every point is in it
            assert all(bytes(row) in scene_rows for row in points)
