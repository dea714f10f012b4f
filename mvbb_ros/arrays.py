"""
Array type aliases shared by every layer (one place, so a dtype means the same everywhere).

And the column reductions of (N, 3) point arrays that every layer takes (bounds, extents), the
cross product, the axes perpendicular to a direction and read-only copies.

Coordinates are float64 unless a name says otherwise: the decoder keeps float32 clouds as they
are (:data:`Float32Array`) and the filters return float64.
"""

from __future__ import annotations

from typing import cast, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

_Number = TypeVar('_Number', bound=np.number)

#: float64 arrays: points (N, 3), rotations (3, 3), extents, directions.
FloatArray = NDArray[np.float64]
#: float32 arrays: clouds as sensors and PointCloud2 messages deliver them.
Float32Array = NDArray[np.float32]
#: Indices into other arrays (point indices of a box, hull vertices).
IndexArray = NDArray[np.intp]
#: Masks.
BoolArray = NDArray[np.bool_]
#: int32 images (labels of rendered depth frames).
IntArray = NDArray[np.int32]


# Column reductions -----------------------------------------------------------------------------
# numpy reduces an (N, 3) array along axis 0 with one ufunc loop of 3 values per row, many times
# slower than column by column (numpy 1.26 and 2.4 alike; ``docs/performance.md``). The same
# values: a minimum or maximum does not depend on the order it is taken in.


def column_min(values: NDArray[_Number]) -> NDArray[_Number]:
    """Return the minimum of each column of an (N, k) array, N >= 1, as a (k,) array."""
    return np.array([values[:, column].min() for column in range(values.shape[1])])


def column_max(values: NDArray[_Number]) -> NDArray[_Number]:
    """Return the maximum of each column of an (N, k) array, N >= 1, as a (k,) array."""
    return np.array([values[:, column].max() for column in range(values.shape[1])])


def column_span(values: NDArray[_Number]) -> NDArray[_Number]:
    """Return the extent (maximum - minimum) of each column of an (N, k) array, N >= 1."""
    return cast('NDArray[_Number]', column_max(values) - column_min(values))


# Sorting -----------------------------------------------------------------------------------------
# np.lexsort compares its keys through a generic indirect merge sort, much slower than
# a stable argsort of one float64 key, which gives the same order when the first key has no ties.


def lexicographic_order(*keys: NDArray[np.generic]) -> IndexArray:
    """
    Return ``np.lexsort(keys[::-1])``: the stable order by `keys[0]`, ties by `keys[1]`, ...

    Each key is a 1D array of finite values, all of one length. One stable argsort when the
    first key has no ties (points' coordinates rarely do), else np.lexsort.
    """
    order = np.argsort(keys[0], kind='stable')
    first = keys[0][order]
    if len(keys) == 1 or not np.any(first[1:] == first[:-1]):
        return order
    return np.lexsort(keys[::-1])


# Vector products -------------------------------------------------------------------------------
# np.cross moves axes and checks shapes, a fixed cost a call whatever the size, and the
# grasps, the refinement and the completion call it a dozen times a cloud. The same products in
# the same order (a1 b2 - a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0), so the same values bit for bit.


def cross(first: ArrayLike, second: ArrayLike) -> FloatArray:
    """Return the cross products of 3-vectors along the last axes (broadcast like np.cross)."""
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64)
    if a.shape == b.shape == (3,):  # Python floats are IEEE doubles: the same products
        a0, a1, a2 = a.tolist()
        b0, b1, b2 = b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    np.subtract(a[..., 1] * b[..., 2], a[..., 2] * b[..., 1], out=out[..., 0])
    np.subtract(a[..., 2] * b[..., 0], a[..., 0] * b[..., 2], out=out[..., 1])
    np.subtract(a[..., 0] * b[..., 1], a[..., 1] * b[..., 0], out=out[..., 2])
    return out


def perpendicular_axes(axis: FloatArray) -> tuple[FloatArray, FloatArray]:
    """
    Return two unit vectors that make a right-handed frame (first, second, axis) with `axis`.

    `axis` is a unit 3-vector; `first` is perpendicular to it and to the coordinate axis it is
    least along, `second` is ``axis x first``.
    """
    first = cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
    first /= np.linalg.norm(first)
    return first, cross(axis, first)


def read_only(values: ArrayLike) -> FloatArray:
    """Return a float64 copy of `values` that cannot be written (shared or cached results)."""
    out = np.array(values, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out
