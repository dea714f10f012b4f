"""
A point-by-point PointCloud2 reference codec and the shared bags' clouds, for codec tests.

Clouds are built by a straightforward reference encoder (struct.pack_into, point by point) and
read by a per-point reference decoder (struct.unpack_from). Random bytes are written into every
padding byte so that reading padding shows up as wrong values.
"""

from __future__ import annotations

import array
from collections.abc import Iterator, Sequence
import dataclasses
import math
import struct
from types import SimpleNamespace
from typing import Any

from mvbb_ros.pipeline import decode
import numpy as np
from support.data import require_shared_data

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


STRUCT_SIZES = {datatype: struct.calcsize(fmt) for datatype, fmt in STRUCT_FORMATS.items()}


def size_of(datatype: int) -> int:
    return STRUCT_SIZES[datatype]


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


def constructed_bag_clouds() -> list:
    return read_bag_clouds('constructed_real_objects_ros2')
