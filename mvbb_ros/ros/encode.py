"""
Encode numpy points as sensor_msgs/PointCloud2 and copy clouds between message classes.

:func:`create_cloud_xyz` builds an rclpy message (x, y, z packed at offsets 0, s, 2s in
the requested dtype, then any extra fields, no row padding). :func:`to_rosbags_cloud` and
:func:`to_rclpy_cloud` copy any cloud into a rosbags typestore's class or into rclpy's class, so
the same encoder serves the publisher and the bag writer.

The reading half, with the layout rules every cloud must follow, is
:mod:`mvbb_ros.pipeline.decode`.
"""

from __future__ import annotations

import array
from collections.abc import Mapping
import dataclasses
from typing import Any

from builtin_interfaces.msg import Time
from mvbb_ros.pipeline.decode import data_bytes, DATATYPE_CODES, message_attribute, XYZ_FIELDS
import numpy as np
from numpy.typing import ArrayLike, DTypeLike
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

#: numpy scalar type code -> PointField datatype.
_CODE_DATATYPES = {code: datatype for datatype, code in DATATYPE_CODES.items()}


@dataclasses.dataclass(frozen=True)
class _FieldSpec:
    name: str
    offset: int
    datatype: int
    count: int


def _datatype_of(dtype: np.dtype, what: str) -> int:
    code = f'{dtype.kind}{dtype.itemsize}'  # byte order does not matter here
    if code not in _CODE_DATATYPES:
        raise ValueError(
            f'{what} has dtype {dtype}, which has no PointField datatype '
            '(use int8, uint8, int16, uint16, int32, uint32, float32 or float64)'
        )
    return _CODE_DATATYPES[code]


def _stamp_parts(stamp: Any) -> tuple[int, int]:
    if hasattr(stamp, 'to_msg'):  # rclpy.time.Time
        stamp = stamp.to_msg()
    return int(stamp.sec), int(stamp.nanosec)


def create_cloud_xyz(
    points: ArrayLike,
    *,
    frame_id: str = '',
    stamp: Any = None,
    header: Any = None,
    fields_extra: Mapping[str, ArrayLike] | None = None,
    dtype: DTypeLike = np.float32,
    organized_shape: tuple[int, int] | None = None,
    is_bigendian: bool = False,
    point_step: int | None = None,
) -> Any:
    """
    Build an rclpy ``sensor_msgs.msg.PointCloud2`` holding the given points.

    x, y and z are stored at offsets 0, s and 2s (s = the size of ``dtype``), followed by the
    ``fields_extra`` in the mapping's order, packed without alignment; ``point_step`` defaults to
    that packed size and any larger value adds zero padding at the end of each point. Rows are
    not padded (``row_step == width * point_step``). ``is_dense`` is True when every coordinate
    is finite.

    :param points: ``(N, 3)`` or organized ``(H, W, 3)`` coordinates.
    :param frame_id: the header's frame (not allowed together with ``header``).
    :param stamp: the header's stamp: a ``builtin_interfaces`` Time (anything with ``sec`` and
        ``nanosec``) or an ``rclpy.time.Time``; zero when None (not allowed with ``header``).
    :param header: a std_msgs Header (rclpy or rosbags) to copy instead of frame_id/stamp.
    :param fields_extra: more fields, name -> values of shape ``(N,)`` or ``(N, count)`` (or
        ``(H, W)``/``(H, W, count)``), each in one of the eight PointField dtypes.
    :param dtype: the dtype of x, y and z: float32, float64 or one of the six integer dtypes (the
        points must then be integers in its range).
    :param organized_shape: ``(H, W)`` for ``(N, 3)`` points with ``N == H * W``; taken from the
        points when they are ``(H, W, 3)``. Unorganized (``(1, N)``) when None.
    :param is_bigendian: write big-endian data.
    :param point_step: bytes per point, at least the packed size of the fields.
    :return: A new rclpy PointCloud2 message.
    :raises ValueError: inconsistent shapes, unsupported dtypes, bad field names or a point_step
        smaller than the fields.
    """
    if header is not None and (frame_id or stamp is not None):
        raise ValueError('pass either header or frame_id/stamp, not both')
    if header is None:
        sec, nanosec = _stamp_parts(stamp) if stamp is not None else (0, 0)
        header = Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)
    cloud = _encode(
        points,
        header=header,
        fields_extra=fields_extra,
        dtype=dtype,
        organized_shape=organized_shape,
        is_bigendian=is_bigendian,
        point_step=point_step,
    )
    return to_rclpy_cloud(cloud)


@dataclasses.dataclass(frozen=True)
class _PlainCloud:
    """A PointCloud2 as plain Python values, before it becomes a message class."""

    header: Any
    height: int
    width: int
    fields: tuple[_FieldSpec, ...]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: np.ndarray
    is_dense: bool


def _per_point_values(values: ArrayLike, name: str, height: int, width: int) -> np.ndarray:
    """Return an extra field's values as ``(N, count)`` (from 1-D, 2-D or organized)."""
    values = np.asarray(values)
    point_count = height * width
    if values.ndim in (2, 3) and values.shape[:2] == (height, width):
        values = values.reshape(point_count, *values.shape[2:])
    if values.ndim == 1 and values.shape[0] == point_count:
        return values.reshape(point_count, 1)
    if values.ndim == 2 and values.shape[0] == point_count and values.shape[1] >= 1:
        return values
    raise ValueError(
        f'extra field {name!r} has shape {values.shape}; expected ({point_count},), '
        f'({point_count}, count), ({height}, {width}) or ({height}, {width}, count)'
    )


def _encode(
    points: ArrayLike,
    *,
    header: Any,
    fields_extra: Mapping[str, ArrayLike] | None,
    dtype: DTypeLike,
    organized_shape: tuple[int, int] | None,
    is_bigendian: bool,
    point_step: int | None,
) -> _PlainCloud:
    coordinates = np.asarray(points)
    if coordinates.ndim == 3 and coordinates.shape[2] == 3:
        shape = coordinates.shape[:2]
        if organized_shape is not None and tuple(organized_shape) != shape:
            raise ValueError(f'organized_shape {organized_shape} != points shape {shape}')
    elif coordinates.ndim == 2 and coordinates.shape[1] == 3:
        count = coordinates.shape[0]
        shape = (1, count) if organized_shape is None else tuple(organized_shape)
        if len(shape) != 2 or min(shape) < 0 or shape[0] * shape[1] != count:
            raise ValueError(f'organized_shape {organized_shape} does not hold {count} points')
    else:
        raise ValueError(f'points must have shape (N, 3) or (H, W, 3), got {coordinates.shape}')
    height, width = int(shape[0]), int(shape[1])
    flat = coordinates.reshape(-1, 3)

    coordinate_dtype = np.dtype(dtype)
    coordinate_datatype = _datatype_of(coordinate_dtype, 'dtype')
    if coordinate_dtype.kind in 'iu':
        info = np.iinfo(coordinate_dtype)
        if flat.size and (
            not np.isfinite(flat).all()
            or (flat != np.round(flat)).any()
            or flat.min() < info.min
            or flat.max() > info.max
        ):
            raise ValueError(f'points are not all integers in the range of {coordinate_dtype}')

    fields = [
        _FieldSpec(name, axis * coordinate_dtype.itemsize, coordinate_datatype, 1)
        for axis, name in enumerate(XYZ_FIELDS)
    ]
    extra_values = []
    offset = 3 * coordinate_dtype.itemsize
    for name, values in (fields_extra or {}).items():
        if not isinstance(name, str) or not name or name in XYZ_FIELDS:
            raise ValueError(
                f'extra field name {name!r} must be a non-empty string other than x/y/z'
            )
        values = _per_point_values(values, name, height, width)
        datatype = _datatype_of(values.dtype, f'extra field {name!r}')
        fields.append(_FieldSpec(name, offset, datatype, values.shape[1]))
        extra_values.append(values)
        offset += values.shape[1] * values.dtype.itemsize

    packed_step = offset
    if point_step is None:
        point_step = packed_step
    elif point_step < packed_step:
        raise ValueError(
            f'point_step {point_step} is smaller than the fields ({packed_step} bytes)'
        )
    order = '>' if is_bigendian else '<'
    record_dtype = np.dtype(
        {
            'names': [field.name for field in fields],
            'formats': [
                (order + DATATYPE_CODES[field.datatype], (field.count,))
                if field.count != 1
                else order + DATATYPE_CODES[field.datatype]
                for field in fields
            ],
            'offsets': [field.offset for field in fields],
            'itemsize': point_step,
        }
    )
    records = np.zeros(height * width, dtype=record_dtype)
    for axis, name in enumerate(XYZ_FIELDS):
        records[name] = flat[:, axis]
    for field, values in zip(fields[3:], extra_values, strict=True):
        records[field.name] = values if field.count != 1 else values[:, 0]
    return _PlainCloud(
        header=header,
        height=height,
        width=width,
        fields=tuple(fields),
        is_bigendian=is_bigendian,
        point_step=point_step,
        row_step=width * point_step,
        data=records.view(np.uint8).reshape(-1),
        is_dense=bool(np.isfinite(flat).all()),
    )


def _copy_cloud(
    cloud: Any,
    *,
    cloud_class: Any,
    field_class: Any,
    header_class: Any,
    time_class: Any,
    make_data: Any,
) -> Any:
    """Copy a duck-typed cloud into the given message classes (shared by both converters)."""
    source_header = message_attribute(cloud, 'header')
    sec, nanosec = _stamp_parts(source_header.stamp)
    header_arguments = {'stamp': time_class(sec=sec, nanosec=nanosec)}
    header_arguments['frame_id'] = str(source_header.frame_id)
    if 'seq' in getattr(header_class, '__dataclass_fields__', {}):  # ROS 1 typestores
        header_arguments['seq'] = int(getattr(source_header, 'seq', 0))
    return cloud_class(
        header=header_class(**header_arguments),
        height=int(cloud.height),
        width=int(cloud.width),
        fields=[
            field_class(
                name=str(field.name),
                offset=int(field.offset),
                datatype=int(field.datatype),
                count=int(field.count),
            )
            for field in cloud.fields
        ],
        is_bigendian=bool(cloud.is_bigendian),
        point_step=int(cloud.point_step),
        row_step=int(cloud.row_step),
        data=make_data(data_bytes(cloud.data)),
        is_dense=bool(cloud.is_dense),
    )


def _rclpy_data(data: np.ndarray) -> array.array:
    # rclpy checks every element of a non-array.array value in Python; array.array is taken as is.
    values = array.array('B')
    values.frombytes(data.data)  # the array's buffer, not a copy
    return values


def to_rclpy_cloud(cloud: Any) -> Any:
    """
    Copy any PointCloud2 (for example a rosbags message read from a bag) into rclpy's class.

    :param cloud: a sensor_msgs/PointCloud2 with the usual attributes.
    :return: A new ``sensor_msgs.msg.PointCloud2`` with copied data (array.array('B')).
    """
    return _copy_cloud(
        cloud,
        cloud_class=PointCloud2,
        field_class=PointField,
        header_class=Header,
        time_class=Time,
        make_data=_rclpy_data,
    )


def to_rosbags_cloud(cloud: Any, typestore: Any) -> Any:
    """
    Copy any PointCloud2 (for example from :func:`create_cloud_xyz`) into a rosbags class.

    Use it to write clouds into a bag::

        message = to_rosbags_cloud(create_cloud_xyz(points, frame_id='camera'), typestore)
        writer.write(connection, stamp_ns, typestore.serialize_cdr(message, message.__msgtype__))

    :param cloud: a sensor_msgs/PointCloud2 with the usual attributes.
    :param typestore: a rosbags typestore (``rosbags.typesys.get_typestore(Stores.ROS2_JAZZY)``);
        ROS 1 typestores work too (their header ``seq`` is copied or set to 0).
    :return: A new instance of the typestore's ``sensor_msgs/msg/PointCloud2`` with copied data
        (a numpy uint8 array).
    """
    types = typestore.types
    return _copy_cloud(
        cloud,
        cloud_class=types['sensor_msgs/msg/PointCloud2'],
        field_class=types['sensor_msgs/msg/PointField'],
        header_class=types['std_msgs/msg/Header'],
        time_class=types['builtin_interfaces/msg/Time'],
        make_data=np.array,
    )
