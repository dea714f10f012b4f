"""
sensor_msgs/PointCloud2 <-> numpy, written for this package (no sensor_msgs_py).

Layout rules of a PointCloud2 (what the decoder assumes and checks)
-------------------------------------------------------------------
* The cloud is a grid of ``height`` rows by ``width`` points; ``height == 1`` means unorganized.
* Point ``(r, c)`` starts at byte ``r * row_step + c * point_step`` of ``data``. ``point_step`` may
  be larger than the fields need (padding between points) and ``row_step`` may be larger than
  ``width * point_step`` (padding at the end of each row). ``row_step < width * point_step`` is
  rejected. The last row only has to hold ``width * point_step`` bytes, so the data must be at
  least ``(height - 1) * row_step + width * point_step`` bytes long. Longer data is accepted and
  the tail is ignored (some drivers pad the buffer; nothing after the last point is read).
* Each field has a ``name``, a byte ``offset`` inside the point, a ``datatype`` (the PointField
  constants INT8=1, UINT8=2, INT16=3, UINT16=4, INT32=5, UINT32=6, FLOAT32=7, FLOAT64=8) and a
  ``count``. Every field with a known datatype must fit inside the point:
  ``offset + count * size <= point_step``. Fields with other datatypes are ignored unless they are
  x, y or z.
* ``x``, ``y`` and ``z`` must each appear exactly once, with ``count == 1``, in any order and at
  any offset, and must not overlap each other. Each may have any of the eight datatypes,
  independently. Integer coordinates are converted to float64 as they are (no scaling); every
  integer datatype is exact in float64.
* ``is_bigendian`` gives the byte order of every field. The message is never modified: byte order
  is handled by numpy dtypes while converting, never by swapping the buffer in place.
* ``is_dense`` is not trusted: non-finite points (NaN or inf in any coordinate) are dropped by
  :func:`read_xyz` whatever it says.
* Zero points (``width == 0`` or ``height == 0``) is valid and decodes to a ``(0, 3)`` array; the
  field checks still apply.

A cloud that breaks these rules raises :class:`CloudFormatError` (a ``ValueError``) with a message
saying which rule, and nothing else: no ``IndexError``/``TypeError`` from deep inside numpy.

Messages are duck-typed: anything with the PointCloud2 attributes works, in particular rclpy's
``sensor_msgs.msg.PointCloud2`` (``data`` is an ``array.array('B')``) and rosbags' message classes
(``data`` is a numpy ``uint8`` array). Decoding is vectorised: the data is viewed (not copied)
through a numpy structured dtype with ``strides=(row_step, point_step)``, then x, y and z are
copied once into a new float64 array that owns its memory.

Organized clouds: :func:`read_xyz_grid` keeps the ``(height, width, 3)`` grid with its non-finite
points, so callers that need pixel structure can do::

    grid = read_xyz_grid(cloud)
    valid = np.isfinite(grid).all(axis=2)  # (height, width) mask of kept points
    points = grid[valid]  # the same points, in the same order, as read_xyz(cloud)

Encoding: :func:`create_cloud_xyz` builds an rclpy message (x, y, z packed at offsets 0, s, 2s in
the requested dtype, then any extra fields, no row padding). :func:`to_rosbags_cloud` and
:func:`to_rclpy_cloud` copy any cloud into a rosbags typestore's class or into rclpy's class, so
the same encoder serves the publisher and the bag writer.
"""

from __future__ import annotations

import array
from collections.abc import Mapping
import dataclasses
import operator
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

__all__ = [
    'FLOAT32',
    'FLOAT64',
    'INT8',
    'INT16',
    'INT32',
    'UINT8',
    'UINT16',
    'UINT32',
    'CloudFormatError',
    'create_cloud_xyz',
    'read_points',
    'read_xyz',
    'read_xyz_grid',
    'to_rclpy_cloud',
    'to_rosbags_cloud',
]

# sensor_msgs/PointField datatype constants (identical in ROS 1, ROS 2 and rosbags).
INT8 = 1
UINT8 = 2
INT16 = 3
UINT16 = 4
INT32 = 5
UINT32 = 6
FLOAT32 = 7
FLOAT64 = 8

#: PointField datatype -> numpy scalar type code (byte order added per cloud).
_DATATYPE_CODES = {
    INT8: 'i1',
    UINT8: 'u1',
    INT16: 'i2',
    UINT16: 'u2',
    INT32: 'i4',
    UINT32: 'u4',
    FLOAT32: 'f4',
    FLOAT64: 'f8',
}
_DATATYPE_NAMES = {
    INT8: 'INT8',
    UINT8: 'UINT8',
    INT16: 'INT16',
    UINT16: 'UINT16',
    INT32: 'INT32',
    UINT32: 'UINT32',
    FLOAT32: 'FLOAT32',
    FLOAT64: 'FLOAT64',
}
_CODE_DATATYPES = {code: datatype for datatype, code in _DATATYPE_CODES.items()}
_XYZ = ('x', 'y', 'z')
_UINT32_MAX = 2**32 - 1


class CloudFormatError(ValueError):
    """A PointCloud2 whose layout is inconsistent or lacks what the decoder needs."""


class _FieldSlot(NamedTuple):
    """Where one coordinate lives inside a point."""

    name: str
    offset: int
    datatype: int


class _Layout(NamedTuple):
    """The checked geometry of a cloud's buffer."""

    height: int
    width: int
    point_step: int
    row_step: int
    is_bigendian: bool
    xyz: tuple[_FieldSlot, _FieldSlot, _FieldSlot]


def _attribute(message: Any, name: str, kind: str = 'PointCloud2') -> Any:
    try:
        return getattr(message, name)
    except AttributeError:
        raise CloudFormatError(f'not a {kind}: it has no attribute {name!r}') from None


def _uint32(value: Any, what: str) -> int:
    """Return an integer header value, checked to be a uint32 as in the message definition."""
    if isinstance(value, bool | np.bool_):
        raise CloudFormatError(f'{what} must be an integer, got a bool')
    try:
        number = operator.index(value)
    except TypeError:
        raise CloudFormatError(f'{what} must be an integer, got {value!r}') from None
    if not 0 <= number <= _UINT32_MAX:
        raise CloudFormatError(f'{what} must be in [0, 2**32 - 1] (uint32), got {number}')
    return number


def _flag(value: Any, what: str) -> bool:
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer) and int(value) in (0, 1):
        return bool(value)
    raise CloudFormatError(f'{what} must be a bool, got {value!r}')


def _field_size(datatype: int) -> int:
    return int(_DATATYPE_CODES[datatype][1])


def _check_layout(cloud: Any) -> _Layout:
    """Read and check the header numbers and fields of a cloud (not the data length)."""
    height = _uint32(_attribute(cloud, 'height'), 'height')
    width = _uint32(_attribute(cloud, 'width'), 'width')
    point_step = _uint32(_attribute(cloud, 'point_step'), 'point_step')
    row_step = _uint32(_attribute(cloud, 'row_step'), 'row_step')
    is_bigendian = _flag(_attribute(cloud, 'is_bigendian'), 'is_bigendian')
    fields = _attribute(cloud, 'fields')
    try:
        fields = list(fields)
    except TypeError:
        raise CloudFormatError(
            f'fields must be a sequence of PointField, got {fields!r}'
        ) from None

    found: dict[str, _FieldSlot] = {}
    for index, field in enumerate(fields):
        name = _attribute(field, 'name', 'PointField')
        if not isinstance(name, str):
            raise CloudFormatError(f'field {index} has a non-string name {name!r}')
        what = f'field {name!r}'
        offset = _uint32(_attribute(field, 'offset', 'PointField'), f'{what} offset')
        count = _uint32(_attribute(field, 'count', 'PointField'), f'{what} count')
        datatype = _attribute(field, 'datatype', 'PointField')
        known = (
            isinstance(datatype, int | np.integer)
            and not isinstance(datatype, bool)
            and int(datatype) in _DATATYPE_CODES
        )
        if name in _XYZ:
            if name in found:
                raise CloudFormatError(f'field {name!r} appears more than once')
            if not known:
                raise CloudFormatError(
                    f'{what} has unknown datatype {datatype!r} (expected 1..8: INT8..FLOAT64)'
                )
            if count != 1:
                raise CloudFormatError(f'{what} must have count 1, got {count}')
            found[name] = _FieldSlot(name, offset, int(datatype))
        if known:
            end = offset + count * _field_size(int(datatype))
            if end > point_step:
                raise CloudFormatError(
                    f'{what} (offset {offset}, {count} x {_DATATYPE_NAMES[int(datatype)]}) '
                    f'ends at byte {end}, beyond point_step {point_step}'
                )
    missing = [name for name in _XYZ if name not in found]
    if missing:
        present = [getattr(field, 'name', '?') for field in fields]
        raise CloudFormatError(f'cloud has no field(s) {missing} (fields: {present})')
    xyz = (found['x'], found['y'], found['z'])
    spans = sorted(
        (slot.offset, slot.offset + _field_size(slot.datatype), slot.name) for slot in xyz
    )
    for (_, end, first), (start, _, second) in zip(spans, spans[1:], strict=False):
        if start < end:
            raise CloudFormatError(f'fields {first!r} and {second!r} overlap')
    if width * point_step > row_step and height > 0:
        raise CloudFormatError(
            f'row_step {row_step} is smaller than width * point_step = {width} * {point_step}'
        )
    return _Layout(height, width, point_step, row_step, is_bigendian, xyz)


def _data_bytes(data: Any) -> np.ndarray:
    """Return a read-only flat uint8 view of a message's data (copied only if not contiguous)."""
    if isinstance(data, np.ndarray):
        if data.dtype.hasobject:
            raise CloudFormatError(f'data must hold bytes, got an array of dtype {data.dtype}')
        view = np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    else:
        try:
            view = np.frombuffer(memoryview(data).cast('B'), dtype=np.uint8)
        except TypeError:
            view = _byte_values(data)
    view = view.view()
    view.flags.writeable = False
    return view


def _byte_values(data: Any) -> np.ndarray:
    """Copy data given as a plain sequence of ints in [0, 255] (not a buffer) to uint8."""
    problem = CloudFormatError(
        f'data must be bytes-like or a sequence of byte values, got {type(data).__name__}'
    )
    try:
        values = np.asarray(data)
    except (TypeError, ValueError, OverflowError):
        raise problem from None
    if values.size == 0:
        return np.zeros(0, dtype=np.uint8)
    if values.ndim != 1 or values.dtype.kind not in 'iu':
        raise problem
    if values.min() < 0 or values.max() > 255:
        raise problem
    return values.astype(np.uint8)


def read_xyz_grid(cloud: Any) -> np.ndarray:
    """
    Decode x, y, z of every point, keeping the organized structure and non-finite points.

    :param cloud: a sensor_msgs/PointCloud2 (rclpy message, rosbags message or anything with the
        same attributes).
    :return: A new C-contiguous, writable float64 array of shape ``(height, width, 3)``
        (``(1, N, 3)`` for an unorganized cloud) that does not share memory with the message.
    :raises CloudFormatError: the cloud breaks the layout rules in the module docstring.
    """
    layout, _, view = _xyz_view(cloud)
    if view is None:
        return np.empty((layout.height, layout.width, 3), dtype=np.float64)
    grid = np.empty((layout.height, layout.width, 3), dtype=np.float64)
    for axis, name in enumerate(_XYZ):
        grid[:, :, axis] = view[name]
    return grid


def read_xyz(cloud: Any, *, skip_nonfinite: bool = True) -> np.ndarray:
    """
    Decode the x, y, z coordinates of a PointCloud2 into an ``(N, 3)`` float64 array.

    Points are returned in row-major order (row 0 first). The result is a new C-contiguous,
    writable array that does not share memory with the message; the message is not modified.

    :param cloud: a sensor_msgs/PointCloud2 (rclpy message, rosbags message or anything with the
        same attributes).
    :param skip_nonfinite: drop points with NaN or inf in any coordinate, whatever ``is_dense``
        says. With False every point is returned (``N == height * width``).
    :return: The points, float64 of shape ``(N, 3)``; ``(0, 3)`` for a cloud without points.
    :raises CloudFormatError: the cloud breaks the layout rules in the module docstring.
    """
    points = read_xyz_grid(cloud).reshape(-1, 3)
    if not skip_nonfinite:
        return points
    # Column by column and compress(): both several times faster than isfinite(...).all(axis=1)
    # and boolean indexing on (N, 3).
    finite = np.isfinite(points[:, 0])
    finite &= np.isfinite(points[:, 1])
    finite &= np.isfinite(points[:, 2])
    if finite.all():
        return points
    return points.compress(finite, axis=0)


def _xyz_view(cloud: Any) -> tuple[_Layout, np.ndarray, np.ndarray | None]:
    """
    Check a cloud; return its layout, its data bytes and a structured view of x, y, z.

    The (height, width) view shares the message's buffer (read-only); it is None for a cloud
    without points.
    """
    layout = _check_layout(cloud)
    data = _data_bytes(_attribute(cloud, 'data'))
    height, width = layout.height, layout.width
    if height == 0 or width == 0:
        return layout, data, None
    # Checked before anything is allocated: the result is then at most 24 bytes per byte of
    # data (x, y and z take at least 3 bytes of every point), whatever the header claims.
    needed = (height - 1) * layout.row_step + width * layout.point_step
    if data.size < needed:
        raise CloudFormatError(
            f'data has {data.size} bytes, but height {height}, width {width}, row_step '
            f'{layout.row_step} and point_step {layout.point_step} need {needed}'
        )
    order = '>' if layout.is_bigendian else '<'
    # The structured dtype only spans the x/y/z bytes; the strides step over the padding.
    point_dtype = np.dtype(
        {
            'names': [slot.name for slot in layout.xyz],
            'formats': [order + _DATATYPE_CODES[slot.datatype] for slot in layout.xyz],
            'offsets': [slot.offset for slot in layout.xyz],
            'itemsize': max(slot.offset + _field_size(slot.datatype) for slot in layout.xyz),
        }
    )
    view = np.ndarray(
        shape=(height, width),
        dtype=point_dtype,
        buffer=data,
        strides=(layout.row_step, layout.point_step),
    )
    return layout, data, view


def _packed_float_view(layout: _Layout, data: np.ndarray) -> np.ndarray | None:
    """
    Return an (N, 3) view of x, y, z when they are packed native floats, else None.

    Packed means: one float type for the three, in native byte order, x at some offset, y right
    after it and z right after y (the layout of nearly every driver), and no row padding, so
    every point is one row of the flat view. Nothing is copied.
    """
    x, y, z = layout.xyz
    if not (x.datatype == y.datatype == z.datatype and x.datatype in (FLOAT32, FLOAT64)):
        return None
    size = _field_size(x.datatype)
    if y.offset != x.offset + size or z.offset != y.offset + size:
        return None
    if layout.is_bigendian == np.little_endian:  # not the machine's byte order
        return None
    if layout.height > 1 and layout.row_step != layout.width * layout.point_step:
        return None
    return np.ndarray(
        shape=(layout.height * layout.width, 3),
        dtype=np.float32 if x.datatype == FLOAT32 else np.float64,
        buffer=data,
        offset=x.offset,
        strides=(layout.point_step, size),
    )


def read_points(cloud: Any) -> np.ndarray:
    """
    Decode the finite points of a PointCloud2 into an ``(N, 3)`` array of their own float type.

    The fast path of the pipeline: the same points in the same order as :func:`read_xyz`, but
    float32 when x, y and z are all FLOAT32 (the common case: no float64 copy of a whole depth
    frame), float64 otherwise (integer or float64 fields, or a mix). Non-finite points are
    dropped whatever ``is_dense`` says; the finite test runs once, on the coordinates as they
    are in the message, and only the finite points are copied out. The result is a new
    C-contiguous, writable array that does not share memory with the message.

    :param cloud: a sensor_msgs/PointCloud2 (rclpy message, rosbags message or anything with the
        same attributes).
    :return: the finite points, ``(N, 3)``; ``(0, 3)`` for a cloud without points.
    :raises CloudFormatError: the cloud breaks the layout rules in the module docstring.
    """
    layout, data, view = _xyz_view(cloud)
    all_float32 = all(slot.datatype == FLOAT32 for slot in layout.xyz)
    dtype = np.float32 if all_float32 else np.float64
    if view is None:
        return np.empty((0, 3), dtype=dtype)
    packed = _packed_float_view(layout, data)
    if packed is not None:
        columns = (packed[:, 0], packed[:, 1], packed[:, 2])
    else:
        columns = tuple(view[name].reshape(-1) for name in _XYZ)
    # Column by column into one mask, then one gather of the finite rows: several times
    # faster than np.isfinite(points).all(axis=1) and boolean indexing on (N, 3).
    finite = np.isfinite(columns[0])
    finite &= np.isfinite(columns[1])
    finite &= np.isfinite(columns[2])
    if packed is not None:
        return packed.compress(finite, axis=0)
    points = np.empty((int(np.count_nonzero(finite)), 3), dtype=dtype)
    for axis, column in enumerate(columns):
        points[:, axis] = column.compress(finite)
    return points


# --------------------------------------------------------------------------------------------
# Encoding and conversion between message classes.


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
    from builtin_interfaces.msg import Time
    from std_msgs.msg import Header

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
        for axis, name in enumerate(_XYZ)
    ]
    extra_values = []
    offset = 3 * coordinate_dtype.itemsize
    for name, values in (fields_extra or {}).items():
        if not isinstance(name, str) or not name or name in _XYZ:
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
                (order + _DATATYPE_CODES[field.datatype], (field.count,))
                if field.count != 1
                else order + _DATATYPE_CODES[field.datatype]
                for field in fields
            ],
            'offsets': [field.offset for field in fields],
            'itemsize': point_step,
        }
    )
    records = np.zeros(height * width, dtype=record_dtype)
    for axis, name in enumerate(_XYZ):
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
    source_header = _attribute(cloud, 'header')
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
        data=make_data(_data_bytes(cloud.data)),
        is_dense=bool(cloud.is_dense),
    )


def _rclpy_data(data: np.ndarray) -> array.array:
    # rclpy checks every element of a non-array.array value in Python; array.array is taken as is.
    values = array.array('B')
    values.frombytes(data)
    return values


def to_rclpy_cloud(cloud: Any) -> Any:
    """
    Copy any PointCloud2 (for example a rosbags message read from a bag) into rclpy's class.

    :param cloud: a sensor_msgs/PointCloud2 with the usual attributes.
    :return: A new ``sensor_msgs.msg.PointCloud2`` with copied data (array.array('B')).
    """
    from builtin_interfaces.msg import Time
    from sensor_msgs.msg import PointCloud2, PointField
    from std_msgs.msg import Header

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
