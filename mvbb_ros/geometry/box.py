"""
Oriented box: an immutable value on numpy arrays (no ROS import).

A box is a centre, a rotation whose columns are the unit box axes (right-handed, det +1) and the
full edge lengths along those axes. Units are those of the points it was made from (metres for
sensor data).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import itertools
import math
from typing import Any

from mvbb_ros.arrays import column_max, column_min, FloatArray
import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

#: Face order used by :meth:`Box.face_centers`, :meth:`Box.face_normals` and the grasp module:
#: +a, -a, +b, -b, +c, -c, where a, b, c are the box axes (rotation columns 0, 1, 2).
FACE_NAMES: tuple[str, ...] = ('+x', '-x', '+y', '-y', '+z', '-z')

_CORNER_SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
#: Corner index pairs of the 12 box edges, for wireframes (corners differ in one sign).
EDGES: tuple[tuple[int, int], ...] = tuple(
    (i, j)
    for i in range(8)
    for j in range(i + 1, 8)
    if np.count_nonzero(_CORNER_SIGNS[i] != _CORNER_SIGNS[j]) == 1
)


def _readonly(array: ArrayLike, shape: tuple[int, ...], name: str) -> FloatArray:
    out = np.array(array, dtype=np.float64, copy=True)
    if out.shape != shape:
        raise ValueError(f'Box {name} must have shape {shape}, got {out.shape}')
    if not np.all(np.isfinite(out)):
        raise ValueError(f'Box {name} must be finite, got {out!r}')
    out.setflags(write=False)
    return out


def right_handed(rotation: ArrayLike) -> FloatArray:
    """
    Return `rotation` with its third column flipped when its determinant is negative.

    Flipping an axis leaves the box itself unchanged (a box is symmetric about each axis).
    """
    out = np.array(rotation, dtype=np.float64, copy=True)
    if np.linalg.det(out) < 0.0:
        out[:, 2] = -out[:, 2]
    return out


@dataclass(frozen=True, eq=False)
class Box:
    """
    An oriented box.

    :ivar center: (3,) centre in the world frame.
    :ivar rotation: (3, 3) rotation; column k is the unit direction of box axis k (world frame).
    :ivar extents: (3,) full edge lengths along the three axes (>= 0).

    """

    center: FloatArray
    rotation: FloatArray
    extents: FloatArray

    def __post_init__(self) -> None:
        center = _readonly(self.center, (3,), 'center')
        rotation = _readonly(self.rotation, (3, 3), 'rotation')
        extents = _readonly(self.extents, (3,), 'extents')
        if np.any(extents < 0.0):
            raise ValueError(f'Box extents must be >= 0, got {extents}')
        if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-6):
            raise ValueError('Box rotation must be orthonormal')
        if np.linalg.det(rotation) < 0.0:
            raise ValueError('Box rotation must be right-handed (det +1)')
        object.__setattr__(self, 'center', center)
        object.__setattr__(self, 'rotation', rotation)
        object.__setattr__(self, 'extents', extents)

    # Construction -------------------------------------------------------------------------------

    @classmethod
    def enclosing(cls, points: ArrayLike, rotation: ArrayLike | None = None) -> Box:
        """
        Return the smallest box with the given axes that encloses `points` ((N, 3), N >= 1).

        With no rotation the box is axis-aligned. A left-handed rotation is made right-handed.
        Coordinates are taken relative to the first point, so clouds far from the origin keep
        their precision.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(pts) == 0:
            raise ValueError('Box.enclosing needs at least one point')
        rot = np.eye(3) if rotation is None else right_handed(rotation)
        origin = pts[0]
        local = (pts - origin) @ rot
        low = column_min(local)
        high = column_max(local)
        center = origin + rot @ ((low + high) / 2.0)
        return cls(center=center, rotation=rot, extents=high - low)

    @classmethod
    def trusted(cls, center: FloatArray, rotation: FloatArray, extents: FloatArray) -> Box:
        """
        Return a box made of arrays known to be valid, without checking or copying them.

        For compiled kernels' outputs: fresh float64 arrays of shapes (3,), (3, 3) and (3,),
        finite, the rotation orthonormal and right-handed, the extents >= 0 (what the
        constructor checks costs as much as a small fit). The arrays are
        taken over and made read-only; the caller must not keep writable views of them.
        """
        box = object.__new__(cls)
        for name, value in (('center', center), ('rotation', rotation), ('extents', extents)):
            value.setflags(write=False)
            object.__setattr__(box, name, value)
        return box

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Box:
        """Build a box from :meth:`to_dict` output (centre, quaternion x y z w, extents)."""
        rotation = Rotation.from_quat(np.asarray(data['quaternion'], dtype=float)).as_matrix()
        return cls(center=data['center'], rotation=rotation, extents=data['extents'])

    # Derived quantities --------------------------------------------------------------------------

    @property
    def volume(self) -> float:
        """Volume (product of the extents), in cubed units of the points."""
        # As np.prod multiplies, left to right, without its call overhead (a decomposition asks
        # for volumes hundreds of times).
        a, b, c = self.extents.tolist()
        return a * b * c

    @property
    def half_extents(self) -> FloatArray:
        """Half edge lengths (3,)."""
        return self.extents / 2.0

    @property
    def quaternion(self) -> FloatArray:
        """Orientation as a unit quaternion ordered x, y, z, w with w >= 0, as in ROS messages."""
        return box_quaternions([self])[0]

    def corners(self) -> FloatArray:
        """
        Return the eight corners, shape (8, 3), signed as ``itertools.product((-1, 1), repeat=3)``.

        :data:`EDGES` lists which corner pairs form the twelve edges.
        """
        return self.to_world(_CORNER_SIGNS * self.half_extents)

    def face_normals(self) -> FloatArray:
        """Return the outward unit normals, shape (6, 3), in :data:`FACE_NAMES` order."""
        axes = self.rotation.T
        return np.stack([axes[0], -axes[0], axes[1], -axes[1], axes[2], -axes[2]])

    def face_centers(self) -> FloatArray:
        """Return the face centres, shape (6, 3), in :data:`FACE_NAMES` order (+a, -a, +b, ...)."""
        offsets = np.repeat(self.half_extents, 2)
        return self.center + self.face_normals() * offsets[:, None]

    # Frames --------------------------------------------------------------------------------------

    def to_local(self, points: ArrayLike) -> FloatArray:
        """Map world points (N, 3) to box-frame coordinates (origin at the centre, box axes)."""
        return (np.asarray(points, dtype=np.float64) - self.center) @ self.rotation

    def to_world(self, local: ArrayLike) -> FloatArray:
        """Map box-frame coordinates (N, 3) to world points."""
        return np.asarray(local, dtype=np.float64) @ self.rotation.T + self.center

    def transformed(self, rotation: ArrayLike, translation: ArrayLike) -> Box:
        """Return this box moved by the rigid motion x -> rotation @ x + translation."""
        rot = np.asarray(rotation, dtype=np.float64)
        return Box(
            center=rot @ self.center + np.asarray(translation, dtype=np.float64),
            rotation=right_handed(rot @ self.rotation),
            extents=self.extents,
        )

    def default_tolerance(self) -> float:
        """Return the containment tolerance: 1e-9 of the box size plus the centre's rounding."""
        scale = float(np.max(self.extents))
        return 1e-9 * scale + 8.0 * np.finfo(float).eps * float(np.max(np.abs(self.center)))

    def contains(self, points: ArrayLike, tol: float | None = None) -> NDArray[np.bool_]:
        """
        Tell, per point (N,), whether it lies inside the box grown by `tol` on every side.

        `tol` is in the points' units; None uses :meth:`default_tolerance`.
        """
        margin = self.default_tolerance() if tol is None else float(tol)
        pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        return _inside(pts, self.center, self.rotation, self.half_extents + margin)

    # Serialisation -------------------------------------------------------------------------------

    def to_dict(self) -> dict[str, list[float] | float]:
        """Return a JSON-ready dict: centre, quaternion x y z w, extents and volume."""
        return {
            'center': [float(v) for v in self.center],
            'quaternion': [float(v) for v in self.quaternion],
            'extents': [float(v) for v in self.extents],
            'volume': self.volume,
        }

    def __repr__(self) -> str:
        center = np.array2string(self.center, precision=4)
        extents = np.array2string(self.extents, precision=4)
        return f'Box(center={center}, extents={extents}, volume={self.volume:.6g})'


def box_quaternions(boxes: Sequence[Box]) -> FloatArray:
    """
    Return the boxes' orientations, (B, 4) unit quaternions x, y, z, w with w >= 0.

    One conversion for all boxes: :attr:`Box.quaternion` of each, at the cost of one.
    """
    if not boxes:
        return np.zeros((0, 4))
    return rotation_quaternions(np.stack([box.rotation for box in boxes]))


@nb.njit('float64[:, :](float64[:, :, :])', cache=True, nogil=True)
def _quaternions(matrices: FloatArray) -> FloatArray:
    """
    Return the unit quaternions (x, y, z, w, w >= 0) of rotation matrices (Markley's method).

    Per matrix, the quaternion component of largest magnitude is computed first, from the
    largest of the trace and the diagonal (no square root of a small difference), the others
    from sums and differences of the off-diagonal entries; then it is normalized.
    """
    count = matrices.shape[0]
    out = np.empty((count, 4))
    for n in range(count):
        m = matrices[n]
        trace = m[0, 0] + m[1, 1] + m[2, 2]
        largest = 3
        value = trace
        for i in range(3):
            if m[i, i] > value:
                largest = i
                value = m[i, i]
        q = out[n]
        if largest == 3:
            q[0] = m[2, 1] - m[1, 2]
            q[1] = m[0, 2] - m[2, 0]
            q[2] = m[1, 0] - m[0, 1]
            q[3] = 1.0 + trace
        else:
            i = largest
            j = (i + 1) % 3
            k = (j + 1) % 3
            q[i] = 1.0 - trace + 2.0 * m[i, i]
            q[j] = m[j, i] + m[i, j]
            q[k] = m[k, i] + m[i, k]
            q[3] = m[k, j] - m[j, k]
        norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        sign = -1.0 if q[3] < 0.0 else 1.0
        for axis in range(4):
            q[axis] *= sign / norm
    return out


def rotation_quaternions(matrices: FloatArray) -> FloatArray:
    """
    Return (N, 4) unit quaternions x, y, z, w with w >= 0 of (N, 3, 3) rotations.

    :raises ValueError: when `matrices` is not (N, 3, 3) or a matrix is not a rotation (its
        determinant not near +1: a reflection or a degenerate frame).
    """
    stack = np.ascontiguousarray(matrices, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[1:] != (3, 3):
        raise ValueError(f'rotation_quaternions needs (N, 3, 3) matrices, got {stack.shape}')
    if len(stack) and not np.all(np.abs(np.linalg.det(stack) - 1.0) <= 1e-6):
        raise ValueError('rotation_quaternions needs rotations (determinant +1)')
    return _quaternions(stack)


@nb.njit(cache=True, nogil=True)
def _inside(
    points: FloatArray, center: FloatArray, rotation: FloatArray, limits: FloatArray
) -> NDArray[np.bool_]:
    """Tell which points lie within `limits` of `center` along every box axis (one pass)."""
    inside = np.empty(points.shape[0], dtype=np.bool_)
    for i in range(points.shape[0]):
        dx = points[i, 0] - center[0]
        dy = points[i, 1] - center[1]
        dz = points[i, 2] - center[2]
        ok = True
        for axis in range(3):
            local = dx * rotation[0, axis] + dy * rotation[1, axis] + dz * rotation[2, axis]
            ok &= abs(local) <= limits[axis]
        inside[i] = ok
    return inside


def warm_up() -> None:
    """Run the module's kernels once (see :mod:`mvbb_ros.kernels`)."""
    _quaternions(np.eye(3)[None])
    Box(np.zeros(3), np.eye(3), np.ones(3)).contains(np.zeros((1, 3)))
