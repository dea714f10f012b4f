"""
Tests of the PointCloud2 decoder (pipeline.decode) and encoder (ros.encode).

Clouds are built by a straightforward reference encoder (struct.pack_into, point by point) and
checked against the values they were built from and against a per-point reference decoder
(struct.unpack_from). Random bytes are written into every padding byte so that reading padding
shows up as wrong values.
"""

from __future__ import annotations

import array
from collections.abc import Iterator, Sequence
import dataclasses
import math
import re
import struct
from types import SimpleNamespace
from typing import Any

from conftest import require_shared_data
from hypothesis import event, given, HealthCheck, settings
from hypothesis import strategies as st
from mvbb_ros.pipeline import decode
from mvbb_ros.pipeline.decode import CloudFormatError, read_xyz, read_xyz_grid
from mvbb_ros.ros.encode import create_cloud_xyz, to_rclpy_cloud, to_rosbags_cloud
import numpy as np
import pytest

# PointField datatypes (taken through the module: ruff and flake8 sort INT8/INT16 differently).
INT8, UINT8, INT16, UINT16 = (
    decode.INT8,
    decode.UINT8,
    decode.INT16,
    decode.UINT16,
)
INT32, UINT32, FLOAT32, FLOAT64 = (
    decode.INT32,
    decode.UINT32,
    decode.FLOAT32,
    decode.FLOAT64,
)
ALL_DATATYPES = (INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64)
FLOAT_DATATYPES = (FLOAT32, FLOAT64)
STRUCT_FORMATS = {
    INT8: 'b',
    UINT8: 'B',
    INT16: 'h',
    UINT16: 'H',
    INT32: 'i',
    UINT32: 'I',
    FLOAT32: 'f',
    FLOAT64: 'd',
}
NUMPY_TYPES = {
    INT8: np.int8,
    UINT8: np.uint8,
    INT16: np.int16,
    UINT16: np.uint16,
    INT32: np.int32,
    UINT32: np.uint32,
    FLOAT32: np.float32,
    FLOAT64: np.float64,
}
FLAVOURS = ('plain', 'rclpy', 'rosbags')


STRUCT_SIZES = {datatype: struct.calcsize(fmt) for datatype, fmt in STRUCT_FORMATS.items()}


def size_of(datatype: int) -> int:
    return STRUCT_SIZES[datatype]


# --------------------------------------------------------------------------------------------
# Reference encoder / decoder and message flavours.


@dataclasses.dataclass
class Field:
    name: str
    offset: int
    datatype: int
    count: int = 1


@dataclasses.dataclass
class CloudSpec:
    """Every PointCloud2 attribute, as plain values; turned into a message by as_message()."""

    height: int
    width: int
    fields: list[Field]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: bytes
    is_dense: bool = True
    frame_id: str = 'sensor'


def pack_fields(entries: Sequence[tuple[str, int, int]], gaps: Sequence[int]) -> tuple[list, int]:
    """Lay out (name, datatype, count) entries in order, with gaps[i] bytes before entry i."""
    fields, offset = [], 0
    for (name, datatype, count), gap in zip(entries, gaps, strict=True):
        offset += gap
        fields.append(Field(name, offset, datatype, count))
        offset += size_of(datatype) * count
    return fields, offset


def grid_indices(height: int, width: int) -> Iterator[tuple[int, int]]:
    """(row, col) in row-major order (lazily: a huge height with width 0 yields nothing fast)."""
    if width == 0:
        return
    for row in range(height):
        for col in range(width):
            yield row, col


def encode_reference(
    columns: dict[str, np.ndarray],
    fields: list[Field],
    *,
    point_step: int,
    row_padding: int = 0,
    is_bigendian: bool = False,
    last_row_short: bool = False,
    tail: bytes = b'',
    is_dense: bool = True,
    seed: int = 0,
) -> CloudSpec:
    """
    Encode point by point with struct.pack_into; padding and unnamed fields hold random bytes.

    columns maps field names to (H, W) arrays; fields without a column keep random bytes.
    """
    height, width = next(iter(columns.values())).shape
    row_step = width * point_step + row_padding
    size = height * row_step - (row_padding if last_row_short and height else 0)
    buffer = bytearray(np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8))
    endian = '>' if is_bigendian else '<'
    for row, col in grid_indices(height, width):
        base = row * row_step + col * point_step
        for field in fields:
            if field.name in columns:
                value = columns[field.name][row, col].item()
                fmt = endian + STRUCT_FORMATS[field.datatype]
                struct.pack_into(fmt, buffer, base + field.offset, value)
    return CloudSpec(
        height=height,
        width=width,
        fields=fields,
        is_bigendian=is_bigendian,
        point_step=point_step,
        row_step=row_step,
        data=bytes(buffer) + tail,
        is_dense=is_dense,
    )


def decode_reference(cloud: Any, *, skip_nonfinite: bool = True) -> np.ndarray:
    """Decode x, y, z point by point with struct.unpack_from (works on any message flavour)."""
    data = bytes(cloud.data)
    endian = '>' if cloud.is_bigendian else '<'
    by_name = {field.name: field for field in cloud.fields}
    rows = []
    for row, col in grid_indices(cloud.height, cloud.width):
        base = row * cloud.row_step + col * cloud.point_step
        point = []
        for name in 'xyz':
            field = by_name[name]
            fmt = endian + STRUCT_FORMATS[field.datatype]
            point.append(struct.unpack_from(fmt, data, base + field.offset)[0])
        if skip_nonfinite and not all(math.isfinite(value) for value in point):
            continue
        rows.append(point)
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


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


_TYPESTORE = None


def typestore() -> Any:
    global _TYPESTORE
    if _TYPESTORE is None:
        from rosbags.typesys import get_typestore, Stores

        _TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
    return _TYPESTORE


def as_message(spec: CloudSpec, flavour: str) -> Any:
    """Build the cloud as a plain namespace (bytes data), an rclpy message or a rosbags message."""
    if flavour == 'plain':
        fields = [SimpleNamespace(**dataclasses.asdict(field)) for field in spec.fields]
        header = SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=2), frame_id=spec.frame_id)
        attributes = dataclasses.asdict(spec)
        del attributes['frame_id']
        return SimpleNamespace(**{**attributes, 'fields': fields, 'header': header})
    if flavour == 'rclpy':
        from builtin_interfaces.msg import Time
        from sensor_msgs.msg import PointCloud2, PointField
        from std_msgs.msg import Header

        field_class, cloud_class = PointField, PointCloud2
        header = Header(stamp=Time(sec=1, nanosec=2), frame_id=spec.frame_id)
        data: Any = array.array('B', spec.data)
    else:
        types = typestore().types
        field_class = types['sensor_msgs/msg/PointField']
        cloud_class = types['sensor_msgs/msg/PointCloud2']
        header = types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=1, nanosec=2), frame_id=spec.frame_id
        )
        data = np.frombuffer(spec.data, dtype=np.uint8).copy()
    return cloud_class(
        header=header,
        height=spec.height,
        width=spec.width,
        fields=[field_class(**dataclasses.asdict(field)) for field in spec.fields],
        is_bigendian=spec.is_bigendian,
        point_step=spec.point_step,
        row_step=spec.row_step,
        data=data,
        is_dense=spec.is_dense,
    )


def random_column(rng: np.random.Generator, datatype: int, shape: tuple) -> np.ndarray:
    """Values exactly representable in the datatype, over its whole range for integers."""
    if datatype in FLOAT_DATATYPES:
        return (rng.normal(scale=100.0, size=shape)).astype(NUMPY_TYPES[datatype])
    info = np.iinfo(NUMPY_TYPES[datatype])
    return rng.integers(info.min, info.max, size=shape, endpoint=True).astype(
        NUMPY_TYPES[datatype]
    )


def expected_points(columns: dict[str, np.ndarray], *, skip_nonfinite: bool = True) -> np.ndarray:
    points = np.stack([columns[name].astype(np.float64) for name in 'xyz'], axis=-1)
    points = points.reshape(-1, 3)
    return points[np.isfinite(points).all(axis=1)] if skip_nonfinite else points


def data_snapshot(message: Any) -> bytes:
    return bytes(message.data)


# --------------------------------------------------------------------------------------------
# Every layout, built by the reference encoder.

LAYOUT_CASES = {
    # name: (entries in memory order, gaps before each, extra point padding, row padding,
    #        big-endian, (height, width))
    'packed xyz float32 unorganized': (
        [('x', FLOAT32, 1), ('y', FLOAT32, 1), ('z', FLOAT32, 1)],
        [0, 0, 0],
        0,
        0,
        False,
        (1, 17),
    ),
    'zyx order with intensity in between': (
        [('z', FLOAT32, 1), ('intensity', FLOAT32, 1), ('y', FLOAT32, 1), ('x', FLOAT32, 1)],
        [0, 0, 0, 0],
        0,
        0,
        False,
        (1, 11),
    ),
    'PCL-like point_step 32 padding': (
        [('x', FLOAT32, 1), ('y', FLOAT32, 1), ('z', FLOAT32, 1), ('rgb', FLOAT32, 1)],
        [0, 0, 0, 4],
        12,
        0,
        False,
        (1, 9),
    ),
    'organized with row padding': (
        [('y', FLOAT32, 1), ('x', FLOAT32, 1), ('z', FLOAT32, 1)],
        [0, 2, 1],
        3,
        13,
        False,
        (4, 5),
    ),
    'big-endian float32': (
        [('x', FLOAT32, 1), ('y', FLOAT32, 1), ('z', FLOAT32, 1)],
        [0, 0, 0],
        4,
        0,
        True,
        (1, 8),
    ),
    'big-endian float64 organized with row padding': (
        [('x', FLOAT64, 1), ('y', FLOAT64, 1), ('z', FLOAT64, 1)],
        [0, 0, 0],
        0,
        7,
        True,
        (3, 4),
    ),
    'float64 little-endian unaligned offsets': (
        [('label', UINT8, 1), ('x', FLOAT64, 1), ('y', FLOAT64, 1), ('z', FLOAT64, 1)],
        [0, 0, 3, 1],
        5,
        0,
        False,
        (2, 3),
    ),
    'mixed float32 and float64 axes': (
        [('x', FLOAT64, 1), ('y', FLOAT32, 1), ('z', FLOAT64, 1)],
        [0, 0, 0],
        0,
        0,
        False,
        (1, 6),
    ),
    'extra field with count 3 between axes': (
        [('x', FLOAT32, 1), ('normal', FLOAT32, 3), ('y', FLOAT32, 1), ('z', FLOAT32, 1)],
        [0, 0, 0, 0],
        0,
        0,
        True,
        (2, 2),
    ),
    **{
        f'integer {STRUCT_FORMATS[datatype]} axes {endian}': (
            [('x', datatype, 1), ('y', datatype, 1), ('z', datatype, 1)],
            [0, 1, 0],
            2,
            5,
            endian == 'big-endian',
            (2, 7),
        )
        for datatype in (INT8, UINT8, INT16, UINT16, INT32, UINT32)
        for endian in ('little-endian', 'big-endian')
    },
}


def build_layout_case(name: str, seed: int = 0, **encode_options: Any) -> tuple[CloudSpec, dict]:
    entries, gaps, point_padding, row_padding, is_bigendian, shape = LAYOUT_CASES[name]
    fields, packed = pack_fields(entries, gaps)
    rng = np.random.default_rng(seed)
    columns = {
        entry_name: random_column(rng, datatype, shape)
        for entry_name, datatype, count in entries
        if entry_name in 'xyz' and count == 1
    }
    spec = encode_reference(
        columns,
        fields,
        point_step=packed + point_padding,
        row_padding=row_padding,
        is_bigendian=is_bigendian,
        seed=seed + 1,
        **encode_options,
    )
    return spec, columns


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


# --------------------------------------------------------------------------------------------
# Malformed clouds: a clear CloudFormatError saying what is wrong.


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


# --------------------------------------------------------------------------------------------
# Property tests.


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


# --------------------------------------------------------------------------------------------
# create_cloud_xyz and the conversions between message classes.


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


# --------------------------------------------------------------------------------------------
# The real bags in the shared data.


def read_bag_clouds(relative: str) -> list[tuple[str, int, Any]]:
    """(topic, log time ns, rosbags message) of every PointCloud2 in a shared bag."""
    from rosbags.highlevel import AnyReader

    path = require_shared_data('bags', relative)
    with AnyReader([path], default_typestore=typestore()) as reader:
        connections = [c for c in reader.connections if c.msgtype == 'sensor_msgs/msg/PointCloud2']
        return [
            (connection.topic, timestamp, reader.deserialize(raw, connection.msgtype))
            for connection, timestamp, raw in reader.messages(connections=connections)
        ]


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
    return read_bag_clouds('constructed_real_objects_ros2')


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


def test_bag_clouds_survive_conversion_to_rclpy_and_serialization(constructed_clouds):
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import PointCloud2

    for _, _, message in constructed_clouds[:2]:
        restored = deserialize_message(serialize_message(to_rclpy_cloud(message)), PointCloud2)
        np.testing.assert_array_equal(read_xyz_grid(restored), read_xyz_grid(message))
        assert restored.header.frame_id == message.header.frame_id
