"""
Decode sensor_msgs/PointCloud2 into numpy points, written for this package (no sensor_msgs_py).

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
"""

from __future__ import annotations

from collections.abc import Sequence
import operator
from typing import Any, NamedTuple

import numpy as np

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
    'DATATYPE_CODES',
    'XYZ_FIELDS',
    'data_bytes',
    'message_attribute',
    'read_fields',
    'read_points',
    'read_xyz',
    'read_xyz_grid',
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
DATATYPE_CODES = {
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
#: The coordinate fields every cloud must have.
XYZ_FIELDS = ('x', 'y', 'z')
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


def message_attribute(message: Any, name: str, kind: str = 'PointCloud2') -> Any:
    """Return ``message.name``, or raise :class:`CloudFormatError` saying it is not a `kind`."""
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
    return int(DATATYPE_CODES[datatype][1])


def _check_layout(cloud: Any) -> _Layout:
    """Read and check the header numbers and fields of a cloud (not the data length)."""
    height = _uint32(message_attribute(cloud, 'height'), 'height')
    width = _uint32(message_attribute(cloud, 'width'), 'width')
    point_step = _uint32(message_attribute(cloud, 'point_step'), 'point_step')
    row_step = _uint32(message_attribute(cloud, 'row_step'), 'row_step')
    is_bigendian = _flag(message_attribute(cloud, 'is_bigendian'), 'is_bigendian')
    fields = message_attribute(cloud, 'fields')
    try:
        fields = list(fields)
    except TypeError:
        raise CloudFormatError(
            f'fields must be a sequence of PointField, got {fields!r}'
        ) from None

    found: dict[str, _FieldSlot] = {}
    for index, field in enumerate(fields):
        name = message_attribute(field, 'name', 'PointField')
        if not isinstance(name, str):
            raise CloudFormatError(f'field {index} has a non-string name {name!r}')
        what = f'field {name!r}'
        offset = _uint32(message_attribute(field, 'offset', 'PointField'), f'{what} offset')
        count = _uint32(message_attribute(field, 'count', 'PointField'), f'{what} count')
        datatype = message_attribute(field, 'datatype', 'PointField')
        known = (
            isinstance(datatype, int | np.integer)
            and not isinstance(datatype, bool)
            and int(datatype) in DATATYPE_CODES
        )
        if name in XYZ_FIELDS:
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
    missing = [name for name in XYZ_FIELDS if name not in found]
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


def data_bytes(data: Any) -> np.ndarray:
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
    for axis, name in enumerate(XYZ_FIELDS):
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
    data = data_bytes(message_attribute(cloud, 'data'))
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
            'formats': [order + DATATYPE_CODES[slot.datatype] for slot in layout.xyz],
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
    columns: tuple[np.ndarray, ...]
    if packed is not None:
        columns = (packed[:, 0], packed[:, 1], packed[:, 2])
    else:
        columns = tuple(view[name].reshape(-1) for name in XYZ_FIELDS)
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


def read_fields(cloud: Any, names: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """
    Decode named fields of every point of a PointCloud2, each in its own dtype.

    For clouds that carry more than coordinates, such as the node's ``~/grasp_candidates``
    (one point per grasp with its width, score and indices). Points are in row-major order and
    nothing is dropped (``N == height * width``); the layout rules of the module docstring
    apply, so the cloud needs x, y and z.

    :param cloud: a sensor_msgs/PointCloud2 (rclpy message, rosbags message or anything with the
        same attributes).
    :param names: the fields to read; None reads every field of a known datatype.
    :return: name -> a new array of shape ``(N,)`` (``(N, count)`` for a field with count > 1)
        in the field's type, native byte order.
    :raises CloudFormatError: the cloud breaks the layout rules, or lacks one of `names`.
    """
    layout, data, _ = _xyz_view(cloud)
    known = {
        str(field.name): field
        for field in message_attribute(cloud, 'fields')
        if isinstance(field.datatype, int | np.integer) and int(field.datatype) in DATATYPE_CODES
    }
    wanted = list(known) if names is None else list(names)
    missing = [name for name in wanted if name not in known]
    if missing:
        raise CloudFormatError(f'cloud has no field(s) {missing} (fields: {list(known)})')
    count = layout.height * layout.width
    order = '>' if layout.is_bigendian else '<'
    values: dict[str, np.ndarray] = {}
    for name in wanted:
        field = known[name]
        dtype = np.dtype(order + DATATYPE_CODES[int(field.datatype)])
        shape = (layout.height, layout.width, int(field.count))
        if count == 0:
            column = np.empty(shape, dtype=dtype.newbyteorder('='))
        else:
            column = np.ndarray(
                shape=shape,
                dtype=dtype,
                buffer=data,
                offset=int(field.offset),
                strides=(layout.row_step, layout.point_step, dtype.itemsize),
            )
        flat = column.reshape(count, int(field.count)).astype(dtype.newbyteorder('='))
        values[name] = flat[:, 0] if int(field.count) == 1 else flat
    return values
