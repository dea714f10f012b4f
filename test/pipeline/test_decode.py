"""
The compiled PointCloud2 decoder (decode_xyz and its readers) against a point-by-point reference.

The reference reads every coordinate with ``struct.unpack_from``; layouts are random (field
order, offsets, gaps, point and row padding, byte order, the eight datatypes per coordinate)
and every byte the decoder must not read holds random values. The message-level rules (field
checks, malformed clouds, bags) are in ``test_pointcloud2.py``. Runs without rclpy and Open3D
(the numba 0.59 venv of ``make compat``); the tests on messages skip there.
"""

from __future__ import annotations

import array
import math
import struct
from types import SimpleNamespace

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from mvbb_ros.pipeline import decode
from mvbb_ros.pipeline.decode import (
    CloudFormatError,
    decode_points,
    decode_xyz,
    read_points,
    read_xyz,
    read_xyz_grid,
)
import numpy as np
import pytest

FORMATS = {1: 'b', 2: 'B', 3: 'h', 4: 'H', 5: 'i', 6: 'I', 7: 'f', 8: 'd'}
SIZES = {datatype: struct.calcsize(code) for datatype, code in FORMATS.items()}
INTEGER_RANGES = {1: (-128, 127), 2: (0, 255), 3: (-(2**15), 2**15 - 1), 4: (0, 2**16 - 1),
                  5: (-(2**31), 2**31 - 1), 6: (0, 2**32 - 1)}  # fmt: skip
SPECIALS = [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e-45, 3.4e38, -3.4e38]


def reference(data: bytes, layout: dict, *, skip_nonfinite: bool = True) -> np.ndarray:
    """Decode x, y, z point by point with struct.unpack_from, as float64."""
    order = '>' if layout['is_bigendian'] else '<'
    rows = []
    for row in range(layout['height']):
        for column in range(layout['width']):
            base = row * layout['row_step'] + column * layout['point_step']
            point = [
                struct.unpack_from(order + FORMATS[datatype], data, base + offset)[0]
                for offset, datatype in zip(layout['offsets'], layout['datatypes'], strict=True)
            ]
            if skip_nonfinite and not all(math.isfinite(value) for value in point):
                continue
            rows.append(point)
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


@st.composite
def clouds(draw: st.DrawFn) -> tuple[bytes, dict]:
    """Draw a random layout and a buffer: random x, y, z values, random bytes elsewhere."""
    datatypes = tuple(draw(st.sampled_from(sorted(FORMATS))) for _ in range(3))
    order = draw(st.permutations([0, 1, 2]))
    gaps = [draw(st.integers(0, 5)) for _ in range(3)]
    offsets = [0, 0, 0]
    at = 0
    for axis, gap in zip(order, gaps, strict=True):
        at += gap
        offsets[axis] = at
        at += SIZES[datatypes[axis]]
    point_step = at + draw(st.integers(0, 7))
    height = draw(st.integers(0, 4))
    width = draw(st.integers(0, 6))
    row_step = width * point_step + draw(st.integers(0, 9))
    is_bigendian = draw(st.booleans())
    tail = draw(st.integers(0, 5))
    size = max(0, (height - 1) * row_step + width * point_step) + tail
    buffer = bytearray(draw(st.binary(min_size=size, max_size=size)))
    code = '>' if is_bigendian else '<'
    for row in range(height):
        for column in range(width):
            base = row * row_step + column * point_step
            for offset, datatype in zip(offsets, datatypes, strict=True):
                if datatype in (7, 8):
                    value = draw(
                        st.one_of(
                            st.sampled_from(SPECIALS),
                            st.floats(-1e6, 1e6, width=32 if datatype == 7 else 64),
                        )
                    )
                    if datatype == 7 and math.isfinite(value) and abs(value) > 3.4e38:
                        value = math.copysign(3.4e38, value)
                else:
                    low, high = INTEGER_RANGES[datatype]
                    value = draw(st.integers(low, high))
                struct.pack_into(code + FORMATS[datatype], buffer, base + offset, value)
    layout = {
        'height': height,
        'width': width,
        'point_step': point_step,
        'row_step': row_step,
        'offsets': tuple(offsets),
        'datatypes': datatypes,
        'is_bigendian': is_bigendian,
    }
    return bytes(buffer), layout


def as_buffer(data: bytes, kind: str) -> object:
    """Hand the bytes over as the message flavours do (misaligned on purpose)."""
    if kind == 'bytes':
        return data
    if kind == 'array':
        return array.array('B', data)
    padded = np.frombuffer(b'\0' + data, dtype=np.uint8)
    return padded[1:]  # a numpy view that starts at an odd address


@pytest.mark.slow
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(clouds(), st.sampled_from(['bytes', 'array', 'numpy']))
def test_property_matches_point_by_point_reference(cloud, kind):
    data, layout = cloud
    before = bytes(data)
    decoded = decode_xyz(as_buffer(data, kind), **layout)
    expected = reference(data, layout)
    all_float32 = all(datatype == 7 for datatype in layout['datatypes'])
    assert decoded.points.dtype == (np.float32 if all_float32 else np.float64)
    assert decoded.points.flags.c_contiguous and decoded.points.flags.writeable
    np.testing.assert_array_equal(decoded.points.astype(np.float64), expected)
    assert decoded.finite == len(expected)
    if len(expected):
        np.testing.assert_array_equal(decoded.bounds[0], expected.min(axis=0))
        np.testing.assert_array_equal(decoded.bounds[1], expected.max(axis=0))
    everything = decode_xyz(data, skip_nonfinite=False, **layout).points
    np.testing.assert_array_equal(
        everything.astype(np.float64), reference(data, layout, skip_nonfinite=False)
    )
    assert bytes(data) == before


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    clouds(),
    st.lists(st.floats(-2e4, 2e4), min_size=3, max_size=3),
    st.lists(st.floats(0, 4e4), min_size=3, max_size=3),
)
def test_property_crop_keeps_the_points_inside(cloud, low, span):
    data, layout = cloud
    high = [a + b for a, b in zip(low, span, strict=True)]
    decoded = decode_xyz(data, crop_min=low, crop_max=high, **layout)
    finite = reference(data, layout)
    inside = np.all((finite >= low) & (finite <= high), axis=1)
    np.testing.assert_array_equal(decoded.points.astype(np.float64), finite[inside])
    assert decoded.finite == len(finite)


def test_common_layouts_take_the_fast_paths_and_agree():
    rng = np.random.default_rng(3)
    grid = rng.normal(size=(7, 9, 3)).astype(np.float32)
    grid[rng.random((7, 9)) < 0.3] = np.nan
    expected = grid.reshape(-1, 3)[np.isfinite(grid.reshape(-1, 3)).all(axis=1)]
    for dtype, code, datatype in ((np.float32, 'f4', 7), (np.float64, 'f8', 8)):
        for order in '<>':
            size = np.dtype(dtype).itemsize
            record = np.dtype(
                {'names': ['x', 'y', 'z'], 'formats': [order + code] * 3,
                 'offsets': [0, size, 2 * size], 'itemsize': 4 * size}
            )  # fmt: skip
            records = np.zeros(grid.shape[:2], dtype=record)
            for axis, name in enumerate('xyz'):
                records[name] = grid[:, :, axis]
            decoded = decode_xyz(
                records.tobytes(), height=7, width=9, point_step=4 * size,
                row_step=36 * size, offsets=(0, size, 2 * size), datatypes=(datatype,) * 3,
                is_bigendian=order == '>',
            )  # fmt: skip
            assert decoded.points.dtype == dtype
            np.testing.assert_array_equal(decoded.points, expected.astype(dtype))


@pytest.mark.parametrize(
    ('change', 'message'),
    [
        ({'point_step': 8}, 'does not fit'),
        ({'row_step': 11}, 'row_step'),
        ({'height': 3}, 'data has'),
        ({'datatypes': (7, 7, 9)}, 'unknown PointField datatype'),
        ({'offsets': (0, 4, -4)}, 'does not fit'),
        ({'width': -1}, '>= 0'),
    ],
)
def test_bad_layouts_are_refused_before_reading(change, message):
    layout = {'height': 2, 'width': 1, 'point_step': 12, 'row_step': 12, 'offsets': (0, 4, 8),
              'datatypes': (7, 7, 7), 'is_bigendian': False}  # fmt: skip
    layout.update(change)
    with pytest.raises(CloudFormatError, match=message):
        decode_xyz(bytes(24), **layout)


def test_crop_needs_skip_nonfinite():
    layout = {'height': 1, 'width': 2, 'point_step': 12, 'row_step': 24, 'offsets': (0, 4, 8),
              'datatypes': (7, 7, 7), 'is_bigendian': False}  # fmt: skip
    with pytest.raises(ValueError, match='skip_nonfinite'):
        decode_xyz(
            bytes(24), skip_nonfinite=False, crop_min=(0, 0, 0), crop_max=(1, 1, 1), **layout
        )


def test_empty_one_point_and_all_nan():
    layout = {'height': 1, 'point_step': 12, 'offsets': (0, 4, 8), 'datatypes': (7, 7, 7),
              'is_bigendian': False}  # fmt: skip
    empty = decode_xyz(b'', width=0, row_step=0, **layout)
    assert empty.points.shape == (0, 3) and empty.finite == 0
    assert np.isinf(empty.bounds).all()
    one = decode_xyz(np.float32([1, 2, 3]).tobytes(), width=1, row_step=12, **layout)
    np.testing.assert_array_equal(one.points, [[1, 2, 3]])
    np.testing.assert_array_equal(one.bounds, [[1, 2, 3], [1, 2, 3]])
    nans = np.full((5, 3), np.nan, dtype=np.float32).tobytes()
    none = decode_xyz(nans, width=5, row_step=60, **layout)
    assert none.points.shape == (0, 3) and none.finite == 0


# --------------------------------------------------------------------------------------------
# Messages: the readers against the point-by-point reference.


def message_layout(message: object) -> dict:
    """Return the decode_xyz layout of a message, read from its fields."""
    fields = {field.name: field for field in message.fields}
    return {
        'height': message.height,
        'width': message.width,
        'point_step': message.point_step,
        'row_step': message.row_step,
        'offsets': tuple(fields[name].offset for name in 'xyz'),
        'datatypes': tuple(fields[name].datatype for name in 'xyz'),
        'is_bigendian': bool(message.is_bigendian),
    }


def messages() -> list:
    """Messages of every flavour: four datatypes, both byte orders, point and row padding."""
    pytest.importorskip('rclpy', reason='the messages are rclpy messages (not in make compat)')
    from mvbb_ros.ros.encode import create_cloud_xyz

    rng = np.random.default_rng(7)
    grid = rng.normal(size=(40, 50, 3)).astype(np.float32)
    grid[rng.random((40, 50)) < 0.4] = np.nan
    grid[0, 0, 2] = np.inf
    flat = grid.reshape(-1, 3)
    extra = {'rgb': rng.integers(0, 2**32, len(flat), dtype=np.uint32)}
    made = []
    for dtype in (np.float32, np.float64, np.int16, np.uint8):
        if np.issubdtype(dtype, np.integer):
            values = np.clip(np.round(np.nan_to_num(flat * 10, posinf=0.0)), 0, 100).astype(dtype)
        else:
            values = flat
        for is_bigendian in (False, True):
            made.append(
                create_cloud_xyz(
                    values,
                    dtype=dtype,
                    organized_shape=(40, 50),
                    is_bigendian=is_bigendian,
                    fields_extra=extra,
                )  # fmt: skip
            )
    padded = create_cloud_xyz(flat, point_step=32)
    made.append(padded)
    names = ('header', 'height', 'width', 'fields', 'is_bigendian', 'point_step', 'is_dense')
    rowpad = SimpleNamespace(**{name: getattr(padded, name) for name in names})
    rowpad.height, rowpad.width, rowpad.row_step = 40, 50, 50 * 32 + 7
    data = np.zeros((40, 50 * 32 + 7), dtype=np.uint8)
    data[:, : 50 * 32] = np.asarray(padded.data, dtype=np.uint8).reshape(40, -1)
    rowpad.data = data.reshape(-1)
    made.append(rowpad)
    return made


def test_readers_match_the_reference_on_messages():
    for message in messages():
        before = bytes(message.data)
        layout = message_layout(message)
        expected = reference(before, layout)
        everything = reference(before, layout, skip_nonfinite=False)
        float32 = all(datatype == 7 for datatype in layout['datatypes'])
        points = read_points(message)
        assert points.dtype == (np.float32 if float32 else np.float64)
        np.testing.assert_array_equal(points.astype(np.float64), expected)
        np.testing.assert_array_equal(read_xyz(message), expected)
        assert read_xyz(message).dtype == np.float64
        np.testing.assert_array_equal(read_xyz(message, skip_nonfinite=False), everything)
        grid = read_xyz_grid(message)
        np.testing.assert_array_equal(grid, everything.reshape(layout['height'], -1, 3))
        assert bytes(message.data) == before


def test_decode_points_crops_and_measures_as_the_pipeline_needs():
    for message in messages()[:2]:
        finite = read_points(message).astype(np.float64)
        low, high = (-0.5, -1.0, -2.0), (1.0, 0.5, 2.0)
        decoded = decode_points(message, crop_min=low, crop_max=high)
        inside = np.all((finite >= low) & (finite <= high), axis=1)
        np.testing.assert_array_equal(decoded.points.astype(np.float64), finite[inside])
        assert decoded.finite == len(finite)
        np.testing.assert_array_equal(decoded.bounds[0], finite[inside].min(axis=0))
        np.testing.assert_array_equal(decoded.bounds[1], finite[inside].max(axis=0))


def test_organized_frame_as_the_pipeline_sees_it():
    pytest.importorskip('rclpy', reason='the frame is an rclpy message (not in make compat)')
    pytest.importorskip('open3d', reason='the frame is rendered with Open3D (not in make compat)')
    from mvbb_ros.evaluation.synthetic import organized_frame
    from mvbb_ros.ros.encode import create_cloud_xyz

    grid = organized_frame(20_000)
    message = create_cloud_xyz(grid.reshape(-1, 3), organized_shape=grid.shape[:2])
    points = read_points(message)
    assert points.dtype == np.float32
    flat = grid.reshape(-1, 3)
    np.testing.assert_array_equal(points, flat[np.isfinite(flat).all(axis=1)])


def test_module_constants_match_pointfield():
    assert (decode.INT8, decode.FLOAT32, decode.FLOAT64) == (1, 7, 8)
