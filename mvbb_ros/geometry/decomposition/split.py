"""
Split measure and best cut of one box (paper Sec. III-C, eq. 1); numpy and numba, no ROS import.

A box P with axes a, b, c (rotation columns 0, 1, 2) is cut only by planes parallel to its faces.
The points are expressed in P's frame and each axis is divided into a grid of ``grid_cells``
equal cells spanning the points' range along it; a cut lies on a cell boundary, and the part
below it holds the points of the cells below it.

Split measure theta (``'area'``, the paper's): project the points onto a face plane of P and cut
the projection by a line parallel to one of the face's edges. theta is the summed area of the two
parts' bounding rectangles divided by the area of the whole projection's rectangle. The faces are
A (normal a, spanned by b and c), B (normal b) and C (normal c), which gives the paper's six
families in its order::

    theta_1(A, c)  theta_2(A, b)  theta_3(C, a)  theta_4(C, b)  theta_5(B, a)  theta_6(B, c)

where the second symbol is the axis the cut is perpendicular to. Two families cut perpendicular
to the same axis (the same partitions of the points) but measure them in different projections.

Option ``'volume'`` (beyond the paper): theta is the summed volume of the two parts' boxes in P's
frame (the product of each part's three extents) over the volume of the whole, one family per
axis, at the same cost.

The grid only discretises the cut positions; the rectangle and box bounds are the parts' exact
point bounds. Per-cell minima and maxima (one pass over the points, O(n)) followed by prefix and
suffix minima and maxima over the cells (O(cells)) give every cut of every family at once, in one
compiled call (:func:`score_kernel`). theta is a ratio, so it does not depend on the units of the
points.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, get_args, Literal

from mvbb_ros.arrays import FloatArray, IndexArray
from mvbb_ros.geometry.box import Box
import numba as nb
import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Split measures: ``'area'`` is the paper's 2D projection measure, ``'volume'`` the 3D option.
SplitMeasure = Literal['area', 'volume']
SPLIT_MEASURES: tuple[SplitMeasure, ...] = get_args(SplitMeasure)

#: Default number of grid cells per box axis: the 31 inner cell boundaries are the candidate
#: cut positions, about 3 % of the box apart whatever its size (scale-free). Measured with
#: ``benchmarks/decompose.py --sweep grid_cells`` over 8 .. 256 cells: 8 and 16 miss good cuts
#: (mean leaf/root volume on the scans at t = 0.98: 0.27 and 0.25); from 32 on it stays at
#: 0.23-0.24 and the paper's models keep their counts at t = 0.90 and 0.94, while the counts at
#: t = 0.98 only move within their noise. The cost, O(n + cells), is negligible next to the box
#: fits either way.
DEFAULT_GRID_CELLS = 32

#: The paper's six families (eq. 1) as (projection axis, cut axis): theta_1 .. theta_6.
AREA_FAMILIES: tuple[tuple[int, int], ...] = ((0, 2), (0, 1), (2, 0), (2, 1), (1, 0), (1, 2))

_FACE_NAMES = 'ABC'
_AXIS_NAMES = 'abc'


@dataclass(frozen=True, eq=False)
class Cut:
    """
    A plane cutting a box P in two, parallel to one of P's faces.

    :ivar axis: P's axis (0, 1, 2 for a, b, c) that the cut plane is perpendicular to.
    :ivar projection_axis: the axis projected away for the ``'area'`` measure (the normal of the
        face whose projection was cut), or None for the ``'volume'`` measure.
    :ivar cell: index of the first grid cell on the upper side (1 .. cells - 1).
    :ivar cells: number of grid cells along ``axis``.
    :ivar offset: position of the plane along ``axis`` in P's frame (from P's centre), in units
        of the points; midway between the two parts' facing point bounds.
    :ivar theta: the split measure of this cut (dimensionless; below 1 when the parts'
        rectangles or boxes are smaller than the whole).
    :ivar lower_count: number of P's points below the cut (they go to the first child).
    :ivar upper_count: number of P's points above the cut (they go to the second child).
    :ivar point: a point of the plane in the world frame.
    :ivar normal: unit normal of the plane in the world frame, pointing to the upper side.
    """

    axis: int
    projection_axis: int | None
    cell: int
    cells: int
    offset: float
    theta: float
    lower_count: int
    upper_count: int
    point: FloatArray
    normal: FloatArray

    @property
    def family(self) -> int | None:
        """Return the paper's family number 1..6 (eq. 1) of an ``'area'`` cut, else None."""
        if self.projection_axis is None:
            return None
        return AREA_FAMILIES.index((self.projection_axis, self.axis)) + 1

    @property
    def label(self) -> str:
        """Return a readable name, e.g. ``theta_6(B, c)`` or ``volume(c)``."""
        if self.projection_axis is None:
            return f'volume({_AXIS_NAMES[self.axis]})'
        face = _FACE_NAMES[self.projection_axis]
        return f'theta_{self.family}({face}, {_AXIS_NAMES[self.axis]})'

    def to_dict(self) -> dict[str, Any]:
        """Return the cut as a JSON-ready dict (world plane point and normal included)."""
        return {
            'label': self.label,
            'family': self.family,
            'axis': self.axis,
            'projection_axis': self.projection_axis,
            'cell': self.cell,
            'cells': self.cells,
            'offset': self.offset,
            'theta': self.theta,
            'lower_count': self.lower_count,
            'upper_count': self.upper_count,
            'point': [float(v) for v in self.point],
            'normal': [float(v) for v in self.normal],
        }


@dataclass(frozen=True, eq=False)
class CutScores:
    """
    Every candidate cut of one box: theta per family and cut position.

    :ivar theta: (families, cells - 1) split measure; +inf where a part would be empty or the
        family's whole rectangle (or box) has zero size.
    :ivar families: (projection axis or None, cut axis) of each row of ``theta``.
    :ivar cell_index: (n, 3) grid cell of each point along each axis.
    :ivar lower_count: (3, cells - 1) number of points below each cut, per cut axis.
    :ivar lower_max: (3, cells - 1) largest coordinate below each cut along its axis (P's frame).
    :ivar upper_min: (3, cells - 1) smallest coordinate above each cut along its axis.
    :ivar cells: number of grid cells per axis.
    """

    theta: FloatArray
    families: tuple[tuple[int | None, int], ...]
    cell_index: IndexArray
    lower_count: IndexArray
    lower_max: FloatArray
    upper_min: FloatArray
    cells: int


def _check_cells(cells: int) -> int:
    if isinstance(cells, bool) or not isinstance(cells, (int, np.integer)) or cells < 2:
        raise ValueError(f'grid_cells must be an integer >= 2, got {cells!r}')
    return int(cells)


def _check_measure(measure: str) -> str:
    if measure not in SPLIT_MEASURES:
        raise ValueError(f'split_measure must be one of {SPLIT_MEASURES}, got {measure!r}')
    return measure


@nb.njit(cache=True, nogil=True)
def cell_index_kernel(points: np.ndarray, cells: int) -> tuple:
    """
    Return the grid cell of each point along each axis, and the points' bounds.

    Each axis is divided into `cells` equal cells spanning the points' own range along it; a
    point's cell is its offset from the low end times ``cells / range``, truncated, the top end
    falling in the last cell; an axis along which all points coincide puts every point in cell
    0. (A range so small that ``cells / range`` overflows divides the offset by the range
    instead.)

    :param points: (n, 3) C-contiguous points, n >= 1.
    :param cells: cells per axis, >= 1.
    :return: the cells (n, 3) int64, the lower bounds (3,) and the upper bounds (3,).
    """
    count = points.shape[0]
    low = np.empty(3)
    high = np.empty(3)
    for k in range(3):
        low[k] = points[0, k]
        high[k] = points[0, k]
    for i in range(1, count):
        for k in range(3):
            value = points[i, k]
            if value < low[k]:
                low[k] = value
            if value > high[k]:
                high[k] = value
    scale = np.zeros(3)
    width = np.empty(3)
    for k in range(3):
        width[k] = high[k] - low[k]
        if width[k] > 0.0:
            scale[k] = cells / width[k]
    last = float(cells - 1)
    index = np.empty((count, 3), dtype=np.int64)
    for i in range(count):
        for k in range(3):
            offset = points[i, k] - low[k]
            if scale[k] < np.inf:
                position = offset * scale[k]
            else:
                position = offset / width[k] * cells
            index[i, k] = int(min(position, last))
    return index, low, high


@nb.njit(cache=True, nogil=True)
def frame_points_kernel(
    points: np.ndarray, indices: np.ndarray, center: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """
    Return ``(points[indices] - center) @ rotation``: some points in a box's frame, (n, 3).

    :param points: (N, 3) C-contiguous points.
    :param indices: (n,) indices of the points to take.
    :param center: (3,) the box's centre.
    :param rotation: (3, 3) the box's rotation (columns are its axes).
    """
    out = np.empty((indices.shape[0], 3))
    for i in range(indices.shape[0]):
        j = indices[i]
        x = points[j, 0] - center[0]
        y = points[j, 1] - center[1]
        z = points[j, 2] - center[2]
        for k in range(3):
            out[i, k] = x * rotation[0, k] + y * rotation[1, k] + z * rotation[2, k]
    return out


@nb.njit
def _part_ratio(parts: float, whole: float, valid: bool) -> float:
    """Return theta of one cut: the parts' size over the whole's, +inf when not a candidate."""
    if not whole > 0.0 or not valid:
        return np.inf
    return parts / whole


@nb.njit(cache=True, nogil=True)
def score_kernel(points: np.ndarray, cells: int, volume: bool, min_thickness: float) -> tuple:
    """
    Compute theta of every grid cut of points given in their box's frame (see :func:`score_cuts`).

    Per cut axis, the per-cell bounds of every coordinate (one pass), then prefix and suffix
    bounds over the cells give every cut's two parts: O(n + cells).

    :param points: (n, 3) C-contiguous points in the box frame, n >= 1.
    :param cells: cells per axis, >= 2.
    :param volume: the ``'volume'`` measure (three families) instead of ``'area'`` (six).
    :param min_thickness: cuts leaving a part thinner than this along the cut axis are no
        candidates (0: every cut is).
    :return: theta (families, cells - 1), the cells (n, 3), the points below each cut (3,
        cells - 1) per cut axis, the largest coordinate below each cut along its axis (3,
        cells - 1) and the smallest above it (3, cells - 1).
    """
    count = points.shape[0]
    index, low, high = cell_index_kernel(points, cells)
    # cell_min[axis, coordinate, cell]: bounds of the points in each cell along the cut axis.
    cell_min = np.full((3, 3, cells), np.inf)
    cell_max = np.full((3, 3, cells), -np.inf)
    counts = np.zeros((3, cells), dtype=np.int64)
    # Selects, not branches (a branch per bound mispredicted; min and max keep the current
    # bound on ties as the branches did, so the bounds are the same bit for bit).
    for i in range(count):
        x = points[i, 0]
        y = points[i, 1]
        z = points[i, 2]
        for axis in range(3):
            cell = index[i, axis]
            counts[axis, cell] += 1
            cell_min[axis, 0, cell] = min(cell_min[axis, 0, cell], x)
            cell_max[axis, 0, cell] = max(cell_max[axis, 0, cell], x)
            cell_min[axis, 1, cell] = min(cell_min[axis, 1, cell], y)
            cell_max[axis, 1, cell] = max(cell_max[axis, 1, cell], y)
            cell_min[axis, 2, cell] = min(cell_min[axis, 2, cell], z)
            cell_max[axis, 2, cell] = max(cell_max[axis, 2, cell], z)
    cuts = cells - 1
    # The part below cut j holds cells <= j, the part above cells > j.
    lower_min = np.empty((3, 3, cuts))
    lower_max = np.empty((3, 3, cuts))
    upper_min = np.empty((3, 3, cuts))
    upper_max = np.empty((3, 3, cuts))
    lower_count = np.empty((3, cuts), dtype=np.int64)
    for axis in range(3):
        for k in range(3):
            running_min = np.inf
            running_max = -np.inf
            for j in range(cuts):
                running_min = min(running_min, cell_min[axis, k, j])
                running_max = max(running_max, cell_max[axis, k, j])
                lower_min[axis, k, j] = running_min
                lower_max[axis, k, j] = running_max
            running_min = np.inf
            running_max = -np.inf
            for j in range(cuts - 1, -1, -1):
                running_min = min(running_min, cell_min[axis, k, j + 1])
                running_max = max(running_max, cell_max[axis, k, j + 1])
                upper_min[axis, k, j] = running_min
                upper_max[axis, k, j] = running_max
        below = 0
        for j in range(cuts):
            below += counts[axis, j]
            lower_count[axis, j] = below
    valid = np.empty((3, cuts), dtype=np.bool_)
    lower_extent = np.zeros((3, 3, cuts))
    upper_extent = np.zeros((3, 3, cuts))
    for axis in range(3):
        for j in range(cuts):
            ok = 0 < lower_count[axis, j] < count
            if ok and min_thickness > 0.0:
                ok = (
                    lower_max[axis, axis, j] - lower_min[axis, axis, j] >= min_thickness
                    and upper_max[axis, axis, j] - upper_min[axis, axis, j] >= min_thickness
                )
            valid[axis, j] = ok
            if ok:
                for k in range(3):
                    lower_extent[axis, k, j] = lower_max[axis, k, j] - lower_min[axis, k, j]
                    upper_extent[axis, k, j] = upper_max[axis, k, j] - upper_min[axis, k, j]
    whole = np.empty(3)
    for k in range(3):
        whole[k] = high[k] - low[k]
    if volume:
        theta = np.empty((3, cuts))
        size = whole[0] * whole[1] * whole[2]
        for axis in range(3):
            for j in range(cuts):
                lower = lower_extent[axis, 0, j] * lower_extent[axis, 1, j]
                lower = lower * lower_extent[axis, 2, j]
                upper = upper_extent[axis, 0, j] * upper_extent[axis, 1, j]
                upper = upper * upper_extent[axis, 2, j]
                theta[axis, j] = _part_ratio(lower + upper, size, valid[axis, j])
    else:
        theta = np.empty((len(AREA_FAMILIES), cuts))
        for row in range(len(AREA_FAMILIES)):
            projection_axis, axis = AREA_FAMILIES[row]
            other = 3 - projection_axis - axis
            size = whole[axis] * whole[other]
            for j in range(cuts):
                lower = lower_extent[axis, axis, j] * lower_extent[axis, other, j]
                upper = upper_extent[axis, axis, j] * upper_extent[axis, other, j]
                theta[row, j] = _part_ratio(lower + upper, size, valid[axis, j])
    below_max = np.empty((3, cuts))
    above_min = np.empty((3, cuts))
    for axis in range(3):
        for j in range(cuts):
            below_max[axis, j] = lower_max[axis, axis, j]
            above_min[axis, j] = upper_min[axis, axis, j]
    return theta, index, lower_count, below_max, above_min


def grid_cell_index(local: ArrayLike, cells: int) -> IndexArray:
    """
    Return the grid cell (0 .. cells - 1) of each point along each axis, (n, 3).

    Each axis is divided into `cells` equal cells spanning the points' own range along it; an
    axis along which all points coincide puts every point in cell 0 (see
    :func:`cell_index_kernel`).
    """
    pts = np.ascontiguousarray(np.asarray(local, dtype=np.float64).reshape(-1, 3))
    if len(pts) == 0:
        return np.zeros((0, 3), dtype=np.intp)
    index, _, _ = cell_index_kernel(pts, _check_cells(cells))
    return index


def score_cuts(
    local: ArrayLike,
    *,
    cells: int = DEFAULT_GRID_CELLS,
    measure: str = 'area',
    min_thickness: float = 0.0,
) -> CutScores:
    """
    Compute the split measure theta of every grid cut of points given in their box's frame.

    :param local: (n, 3) points in the box frame (column k = coordinate along box axis k).
    :param cells: grid cells per axis (>= 2); the cuts are the cells - 1 inner cell boundaries.
    :param measure: ``'area'`` (paper, six families) or ``'volume'`` (three families).
    :param min_thickness: cuts leaving a part thinner than this along the cut axis (in the
        points' units) are not candidates; 0 (the paper) allows every cut.
    :return: the scores; rows of ``theta`` follow the paper's family order for ``'area'`` and
        the axes a, b, c for ``'volume'``.
    :raises ValueError: for no points, fewer than 2 cells or an unknown measure.
    """
    cells = _check_cells(cells)
    measure = _check_measure(measure)
    pts = np.ascontiguousarray(np.asarray(local, dtype=np.float64).reshape(-1, 3))
    if len(pts) == 0:
        raise ValueError('score_cuts needs at least one point')
    theta, cell_index, lower_count, lower_max, upper_min = score_kernel(
        pts, cells, measure == 'volume', float(min_thickness)
    )
    families: tuple[tuple[int | None, int], ...] = (
        tuple((None, axis) for axis in range(3)) if measure == 'volume' else AREA_FAMILIES
    )
    return CutScores(
        theta=theta,
        families=families,
        cell_index=cell_index,
        lower_count=lower_count,
        lower_max=lower_max,
        upper_min=upper_min,
        cells=cells,
    )


def _make_cut(scores: CutScores, row: int, position: int, box: Box, count: int) -> Cut:
    projection_axis, axis = scores.families[row]
    offset = 0.5 * (scores.lower_max[axis, position] + scores.upper_min[axis, position])
    lower = int(scores.lower_count[axis, position])
    normal = box.rotation[:, axis].copy()
    return Cut(
        axis=int(axis),
        projection_axis=None if projection_axis is None else int(projection_axis),
        cell=int(position) + 1,
        cells=scores.cells,
        offset=float(offset),
        theta=float(scores.theta[row, position]),
        lower_count=lower,
        upper_count=count - lower,
        # The plane's point in the box frame is offset along the axis: centre + offset * axis.
        point=box.center + normal * offset,
        normal=normal,
    )


def candidate_cuts(scores: CutScores, box: Box, *, limit: int = 1) -> list[Cut]:
    """
    Return the best `limit` cuts with distinct partitions, best (smallest theta) first.

    With ``limit=1`` this is the paper's best cut theta*: the smallest theta over all families
    and positions (ties go to the earlier family in the paper's order, then the lower position).
    With a larger limit the further candidates are local minima of theta along their family
    (neighbouring positions of one minimum are nearly the same cut), each partition once.

    :param scores: the output of :func:`score_cuts` for the points of `box` in its frame.
    :param box: the box the scores were computed in (gives the planes' world position).
    :param limit: how many cuts at most (>= 1).
    :return: up to `limit` cuts; empty when no cut splits the points into two non-empty parts
        with a finite theta (fewer than two distinct points, or a degenerate extent).
    """
    if limit < 1:
        raise ValueError(f'limit must be >= 1, got {limit}')
    theta = scores.theta
    count = len(scores.cell_index)
    best_row, best_position = divmod(int(np.argmin(theta)), theta.shape[1])
    if not math.isfinite(theta[best_row, best_position]):
        return []
    cuts = [_make_cut(scores, best_row, best_position, box, count)]
    if limit == 1:
        return cuts

    padded = np.pad(theta, ((0, 0), (1, 1)), constant_values=np.inf)
    # A local minimum: no larger than its lower neighbour, smaller than its upper neighbour (the
    # last position of a plateau).
    is_minimum = (theta <= padded[:, :-2]) & (theta < padded[:, 2:]) & np.isfinite(theta)
    rows, positions = np.nonzero(is_minimum)
    order = np.lexsort((positions, rows, theta[rows, positions]))
    seen = {_partition_key(scores, cuts[0])}
    for k in order:
        cut = _make_cut(scores, int(rows[k]), int(positions[k]), box, count)
        # Different cuts, even along different axes, can split the points the same way.
        key = _partition_key(scores, cut)
        if key in seen:
            continue
        seen.add(key)
        cuts.append(cut)
        if len(cuts) == limit:
            break
    return cuts


def _partition_key(scores: CutScores, cut: Cut) -> bytes:
    """Identify the unordered pair of parts a cut makes (the part of point 0 is False)."""
    upper = cut_mask(scores, cut)
    return np.packbits(upper ^ upper[0]).tobytes()


def cut_mask(scores: CutScores, cut: Cut) -> NDArray[np.bool_]:
    """Return per point whether it lies on the upper side of `cut` (the second child)."""
    return scores.cell_index[:, cut.axis] >= cut.cell


def best_cut(
    points: ArrayLike,
    box: Box,
    *,
    cells: int = DEFAULT_GRID_CELLS,
    measure: str = 'area',
) -> Cut | None:
    """
    Return the paper's best cut theta* of `points` ((n, 3), world frame) in `box`'s frame.

    :return: the cut, or None when no cut splits the points into two non-empty parts (see
        :func:`candidate_cuts`).
    """
    scores = score_cuts(
        box.to_local(np.asarray(points, dtype=np.float64).reshape(-1, 3)),
        cells=cells,
        measure=measure,
    )
    cuts = candidate_cuts(scores, box, limit=1)
    return cuts[0] if cuts else None


def warm_up() -> None:
    """Run every kernel of this module once on a tiny cloud (see :mod:`mvbb_ros.kernels`)."""
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.2], [0.2, 1.0, 0.4], [0.9, 0.1, 1.0]])
    for measure in SPLIT_MEASURES:
        score_cuts(points, cells=4, measure=measure, min_thickness=0.1)
    # As the decomposition calls it: read-only points and a Box's read-only centre and axes.
    frozen = [points.copy(), points.mean(axis=0), np.eye(3)]
    for array in frozen:
        array.flags.writeable = False
    frame_points_kernel(frozen[0], np.arange(len(points)), frozen[1], frozen[2])
