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
(``data`` is a numpy ``uint8`` array).

How x, y, z are read: one compiled pass (numba)
-----------------------------------------------
One kernel reads every layout: for each point it assembles x, y and z from their bytes with
shifts (no alignment assumed, the message never modified or swapped in place), converts the
datatype, tests the three for finiteness, applies the optional crop box, measures the kept
points' bounds and appends the kept points to a compact ``(N, 3)`` array, float32 when x, y and
z are FLOAT32 (no float64 copy of a whole depth frame), float64 otherwise (:func:`decode_xyz`,
:class:`Decoded`). The bounds and the finite count go on to the filters
(:func:`mvbb_ros.pipeline.filtering.filter_points`), which then skip a pass over the points of
their own.

Speed comes from specialising that one loop, not from a second implementation: it is inlined
three times, with the constants (FLOAT32 x 3, little-endian), with (FLOAT64 x 3,
little-endian), and with the cloud's own layout (any other layout, slower), so that in
the common cases the compiler folds the datatype switch away and merges the byte loads into one
load per coordinate. Offsets are unsigned 64-bit integers: numba then emits no negative-index
wrap-around code, which costs a branch per byte and blocks merging the loads.
The constants are passed as int64 values, not numba literals (literals compile every helper once
per constant, multiplying the compile time). The kernel does no bounds checks (numba never does):
the layout and the data length are checked in Python before it runs, so a malformed header cannot
make it read outside the buffer.

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

from llvmlite import ir
from mvbb_ros.pipeline.filtering import (
    BOX,
    crop_box,
    inside_box,
    NO_CORNERS,
    store_corners,
    widened,
)
from numba import njit, types
from numba.extending import intrinsic
import numpy as np
from numpy.typing import ArrayLike, NDArray

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
    'Decoded',
    'XYZ_FIELDS',
    'data_bytes',
    'decode_points',
    'decode_xyz',
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


def _bitcast(source: Any, target: Any, llvm_type: Any) -> Any:
    """Return a numba intrinsic that reinterprets a `source` bit pattern as `target`."""

    def typer(typingctx: Any, bits: Any) -> Any:
        def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
            return builder.bitcast(args[0], llvm_type)

        return target(source), codegen

    return intrinsic(typer)


#: A uint32 bit pattern as a float32, and a uint64 one as a float64 (no conversion).
_float32_from_bits = _bitcast(types.uint32, types.float32, ir.FloatType())
_float64_from_bits = _bitcast(types.uint64, types.float64, ir.DoubleType())


@njit
def _load16(data: Any, at: Any, big: Any) -> Any:
    first = np.uint32(data[at])
    second = np.uint32(data[at + np.uint64(1)])
    if big:
        return np.uint32((first << np.uint32(8)) | second)
    return np.uint32(first | (second << np.uint32(8)))


@njit
def _load32(data: Any, at: Any, big: Any) -> Any:
    b0 = np.uint32(data[at])
    b1 = np.uint32(data[at + np.uint64(1)])
    b2 = np.uint32(data[at + np.uint64(2)])
    b3 = np.uint32(data[at + np.uint64(3)])
    if big:
        return np.uint32((b0 << np.uint32(24)) | (b1 << np.uint32(16)) | (b2 << np.uint32(8)) | b3)
    return np.uint32(b0 | (b1 << np.uint32(8)) | (b2 << np.uint32(16)) | (b3 << np.uint32(24)))


@njit
def _load64(data: Any, at: Any, big: Any) -> Any:
    low = np.uint64(_load32(data, at, big))
    high = np.uint64(_load32(data, at + np.uint64(4), big))
    if big:
        low, high = high, low
    return np.uint64(low | (high << np.uint64(32)))


@njit
def _coordinate(data: Any, at: Any, datatype: Any, big: Any) -> Any:
    """Read one value of a PointField datatype at byte `at`, as float64 (exact for all eight)."""
    if datatype == FLOAT32:
        return np.float64(_float32_from_bits(_load32(data, at, big)))
    if datatype == FLOAT64:
        return _float64_from_bits(_load64(data, at, big))
    if datatype == UINT8:
        return np.float64(data[at])
    if datatype == INT8:
        return np.float64(np.int8(data[at]))
    if datatype == UINT16:
        return np.float64(_load16(data, at, big))
    if datatype == INT16:
        return np.float64(np.int16(_load16(data, at, big)))
    if datatype == UINT32:
        return np.float64(_load32(data, at, big))
    return np.float64(np.int32(_load32(data, at, big)))  # INT32


@njit(inline='always')
def _decode_rows(
    data: Any,
    shape: Any,
    offsets: Any,
    datatypes: Any,
    big: Any,
    keep_nonfinite: Any,
    box: Any,
    crop: Any,
    out: Any,
    bounds: Any,
) -> Any:
    """
    Decode every point row by row and append the kept ones to `out`.

    `shape` is (height, width, row_step, point_step), `offsets` and `datatypes` those of x, y
    and z. Kept: finite and inside the crop box (every point when `keep_nonfinite`). The min
    and max corners of the kept finite points go to ``bounds[0]`` and ``bounds[1]``, for the
    voxel grid's anchor (one pass over the points saved: they are in registers here).

    :return: (points kept, finite points).
    """
    height, width, row_step, point_step = shape
    x_at, y_at, z_at = offsets
    x_type, y_type, z_type = datatypes
    count = finite = 0
    corners = NO_CORNERS
    for row in range(height):
        start = np.uint64(row) * row_step
        for column in range(width):
            at = start + np.uint64(column) * point_step
            x = _coordinate(data, at + x_at, x_type, big)
            y = _coordinate(data, at + y_at, y_type, big)
            z = _coordinate(data, at + z_at, z_type, big)
            if np.isfinite(x) and np.isfinite(y) and np.isfinite(z):
                finite += 1
                if crop and not inside_box(x, y, z, box):
                    continue
                corners = widened(corners, x, y, z)
            elif not keep_nonfinite:
                continue
            out[count, 0] = x
            out[count, 1] = y
            out[count, 2] = z
            count += 1
    store_corners(bounds, corners)
    return count, finite


#: (height, width, row_step, point_step): the loop counts as int64, the byte steps unsigned.
_SHAPE = types.Tuple((types.int64, types.int64, types.uint64, types.uint64))
_SIGNATURES = [
    types.UniTuple(types.int64, 2)(
        types.Array(types.uint8, 1, 'C', readonly=True),
        _SHAPE,
        types.UniTuple(types.uint64, 3),
        types.UniTuple(types.int64, 3),
        types.boolean,
        types.boolean,
        BOX,
        types.boolean,
        types.Array(dtype, 2, 'C'),
        types.float64[:, ::1],
    )
    for dtype in (types.float32, types.float64)
]


@njit(_SIGNATURES, cache=True, nogil=True)
def _decode(
    data: Any,
    shape: Any,
    offsets: Any,
    datatypes: Any,
    big: Any,
    keep_nonfinite: Any,
    box: Any,
    crop: Any,
    out: Any,
    bounds: Any,
) -> Any:
    """Pick the specialisation of :func:`_decode_rows` for this layout and run it."""
    # The constants are int64/bool values, not literals: numba compiles the loop's helpers once
    # and LLVM folds the constants into the inlined copies.
    little = big and not big
    x_type, y_type, z_type = datatypes
    same = x_type == y_type and y_type == z_type
    if not big and same and x_type == FLOAT32:
        float32 = np.int64(FLOAT32)
        return _decode_rows(
            data, shape, offsets, (float32, float32, float32), little, keep_nonfinite, box,
            crop, out, bounds,
        )  # fmt: skip
    if not big and same and x_type == FLOAT64:
        float64 = np.int64(FLOAT64)
        return _decode_rows(
            data, shape, offsets, (float64, float64, float64), little, keep_nonfinite, box,
            crop, out, bounds,
        )  # fmt: skip
    return _decode_rows(
        data, shape, offsets, datatypes, big, keep_nonfinite, box, crop, out, bounds
    )


class Decoded(NamedTuple):
    """What :func:`decode_xyz` returns: the kept points and what the filters need of them."""

    #: The kept points, ``(N, 3)``: float32 when x, y and z are FLOAT32, float64 otherwise.
    points: NDArray[np.floating]
    #: How many points of the cloud are finite (before the crop).
    finite: int
    #: ``(2, 3)`` float64: min and max corners of the kept finite points (inf, -inf if none).
    bounds: NDArray[np.float64]


def _empty_bounds() -> NDArray[np.float64]:
    bounds = np.empty((2, 3))
    bounds[0], bounds[1] = np.inf, -np.inf
    return bounds


def decode_xyz(
    data: Any,
    *,
    height: int,
    width: int,
    point_step: int,
    row_step: int,
    offsets: tuple[int, int, int],
    datatypes: tuple[int, int, int],
    is_bigendian: bool,
    skip_nonfinite: bool = True,
    crop_min: ArrayLike | None = None,
    crop_max: ArrayLike | None = None,
) -> Decoded:
    """
    Decode x, y, z of a PointCloud2 buffer into a compact ``(N, 3)`` array in one pass.

    Points come out in row-major order. The result is float32 when x, y and z are all FLOAT32,
    float64 otherwise; it is a C-contiguous, writable array that does not share memory with
    `data` (it may be the first rows of a buffer sized for every point). The same pass applies
    the crop box and measures the kept points' bounds, which the voxel grid takes instead of a
    pass of its own. The layout is checked here, so the kernel never reads outside `data`;
    :func:`read_points` and the other readers run the message checks (field names, duplicates,
    overlaps, uint32 ranges) first.

    :param data: the message's ``data``: bytes, ``array.array('B')``, a uint8 numpy array or any
        buffer.
    :param height: rows (1 for an unorganized cloud).
    :param width: points per row.
    :param point_step: bytes per point.
    :param row_step: bytes per row (at least ``width * point_step`` when ``height > 1``).
    :param offsets: byte offsets of x, y and z inside a point.
    :param datatypes: PointField datatypes (1-8) of x, y and z.
    :param is_bigendian: byte order of every field.
    :param skip_nonfinite: drop points with NaN or inf in any coordinate; with False every point
        is returned (``N == height * width``, for the organized grid; no crop then).
    :param crop_min: lower corner of an axis-aligned crop box, bounds included; None or empty:
        no crop.
    :param crop_max: upper corner of the crop box.
    :return: the kept points, the finite count and the kept points' bounds.
    :raises CloudFormatError: the layout is inconsistent or `data` is too short for it.
    :raises ValueError: a crop box is given with ``skip_nonfinite=False``, or its corners are
        not two 3-vectors.
    """
    view = data_bytes(data)
    height, width, point_step, row_step = (int(height), int(width), int(point_step), int(row_step))
    if min(height, width, point_step, row_step) < 0:
        raise CloudFormatError('height, width, point_step and row_step must be >= 0')
    for offset, datatype in zip(offsets, datatypes, strict=True):
        if datatype not in DATATYPE_CODES:
            raise CloudFormatError(f'unknown PointField datatype {datatype!r} (expected 1..8)')
        size = _field_size(datatype)
        if not (0 <= offset and offset + size <= point_step):
            raise CloudFormatError(
                f'a field at offset {offset} of {size} bytes does not fit in point_step '
                f'{point_step}'
            )
    box, crop = crop_box(crop_min, crop_max)
    if crop and not skip_nonfinite:
        raise ValueError('a crop box needs skip_nonfinite=True')
    all_float32 = all(datatype == FLOAT32 for datatype in datatypes)
    dtype = np.float32 if all_float32 else np.float64
    bounds = _empty_bounds()
    if height == 0 or width == 0:
        return Decoded(np.empty((0, 3), dtype=dtype), 0, bounds)
    if height > 1 and row_step < width * point_step:
        raise CloudFormatError(
            f'row_step {row_step} is smaller than width * point_step = {width} * {point_step}'
        )
    # Checked before anything is allocated: the result is then at most 24 bytes per byte of
    # data (x, y and z take at least 3 bytes of every point), whatever the header claims.
    needed = (height - 1) * row_step + width * point_step
    if view.size < needed:
        raise CloudFormatError(
            f'data has {view.size} bytes, but height {height}, width {width}, row_step '
            f'{row_step} and point_step {point_step} need {needed}'
        )
    out = np.empty((height * width, 3), dtype=dtype)
    kept, finite = _decode(
        view,
        (height, width, np.uint64(row_step), np.uint64(point_step)),
        tuple(np.uint64(offset) for offset in offsets),
        tuple(int(datatype) for datatype in datatypes),
        bool(is_bigendian),
        not skip_nonfinite,
        box,
        crop,
        out,
        bounds,
    )
    return Decoded(out[:kept], finite, bounds)


def _checked_cloud(cloud: Any) -> tuple[_Layout, np.ndarray, dict[str, Any]]:
    """Check a message's header, fields and data length; return them and decode_xyz's layout."""
    layout = _check_layout(cloud)
    data = data_bytes(message_attribute(cloud, 'data'))
    needed = (layout.height - 1) * layout.row_step + layout.width * layout.point_step
    if layout.height and layout.width and data.size < needed:
        raise CloudFormatError(
            f'data has {data.size} bytes, but height {layout.height}, width {layout.width}, '
            f'row_step {layout.row_step} and point_step {layout.point_step} need {needed}'
        )
    arguments = {
        'height': layout.height,
        'width': layout.width,
        'point_step': layout.point_step,
        'row_step': layout.row_step,
        'offsets': tuple(slot.offset for slot in layout.xyz),
        'datatypes': tuple(slot.datatype for slot in layout.xyz),
        'is_bigendian': layout.is_bigendian,
    }
    return layout, data, arguments


def decode_points(
    cloud: Any, *, crop_min: ArrayLike | None = None, crop_max: ArrayLike | None = None
) -> Decoded:
    """
    Decode the finite points of a PointCloud2 inside an optional crop box, with their bounds.

    What the pipeline reads a message with (:func:`mvbb_ros.pipeline.process.process_cloud`):
    the crop is applied while decoding, and the finite count and the bounds go on to the
    filters. The points are those of :func:`read_points` inside the box, in the same order.

    :param cloud: a sensor_msgs/PointCloud2 (rclpy message, rosbags message or anything with the
        same attributes).
    :param crop_min: lower corner of an axis-aligned crop box, bounds included; None or empty:
        no crop.
    :param crop_max: upper corner of the crop box.
    :return: the kept points (float32 when x, y, z are FLOAT32), the finite count before the
        crop and the kept points' min and max corners.
    :raises CloudFormatError: the cloud breaks the layout rules in the module docstring.
    """
    _, data, arguments = _checked_cloud(cloud)
    return decode_xyz(data, crop_min=crop_min, crop_max=crop_max, **arguments)


def read_points(cloud: Any) -> np.ndarray:
    """
    Decode the finite points of a PointCloud2 into an ``(N, 3)`` array of their own float type.

    The same points in the same order as :func:`read_xyz`, but float32 when x, y and z are all
    FLOAT32 (the common case: no float64 copy of a whole depth frame), float64 otherwise
    (integer or float64 fields, or a mix). Non-finite points are dropped whatever ``is_dense``
    says. The result is a new C-contiguous, writable array that does not share memory with the
    message.

    :param cloud: a sensor_msgs/PointCloud2 (rclpy message, rosbags message or anything with the
        same attributes).
    :return: the finite points, ``(N, 3)``; ``(0, 3)`` for a cloud without points.
    :raises CloudFormatError: the cloud breaks the layout rules in the module docstring.
    """
    return decode_points(cloud).points


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
    _, data, arguments = _checked_cloud(cloud)
    points = decode_xyz(data, skip_nonfinite=skip_nonfinite, **arguments).points
    return np.ascontiguousarray(points, dtype=np.float64)


def read_xyz_grid(cloud: Any) -> np.ndarray:
    """
    Decode x, y, z of every point, keeping the organized structure and non-finite points.

    :param cloud: a sensor_msgs/PointCloud2 (rclpy message, rosbags message or anything with the
        same attributes).
    :return: A new C-contiguous, writable float64 array of shape ``(height, width, 3)``
        (``(1, N, 3)`` for an unorganized cloud) that does not share memory with the message.
    :raises CloudFormatError: the cloud breaks the layout rules in the module docstring.
    """
    _, data, arguments = _checked_cloud(cloud)
    points = decode_xyz(data, skip_nonfinite=False, **arguments).points
    shape = (arguments['height'], arguments['width'], 3)
    return np.ascontiguousarray(points, dtype=np.float64).reshape(shape)


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
    layout, data, _ = _checked_cloud(cloud)
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


def warm_up() -> None:
    """Run every kernel of this module once (see :mod:`mvbb_ros.kernels`)."""
    for dtype, datatype in ((np.float32, FLOAT32), (np.float64, FLOAT64)):
        data = np.arange(6, dtype=dtype).tobytes()
        size = np.dtype(dtype).itemsize
        decode_xyz(
            data,
            height=1,
            width=2,
            point_step=3 * size,
            row_step=6 * size,
            offsets=(0, size, 2 * size),
            datatypes=(datatype,) * 3,
            is_bigendian=False,
        )
