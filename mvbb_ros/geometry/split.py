"""
Split measure and best cut of one box (paper Sec. III-C, eq. 1); plain numpy, no ROS import.

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
point bounds. Per-cell minima and maxima (a radix sort of the cell keys and one reduction, O(n))
followed by prefix and suffix minima and maxima over the cells (O(cells)) give every cut of every
family at once. theta is a
ratio, so it does not depend on the units of the points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, get_args, Literal

from mvbb_ros.arrays import FloatArray, IndexArray
from mvbb_ros.geometry.box import Box
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


def _bounds(pts: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Return the per-axis minimum and maximum of (n, 3) points."""
    # Reducing the contiguous (3, n) copy is over ten times faster than pts.min(axis=0).
    columns = np.ascontiguousarray(pts.T)
    return columns.min(axis=1), columns.max(axis=1)


def _cell_index(pts: FloatArray, low: FloatArray, width: FloatArray, cells: int) -> IndexArray:
    scale = np.divide(cells, width, out=np.zeros(3), where=width > 0.0)
    # The scaled offsets are >= 0, so truncation is the floor; the top point goes in the last cell.
    return np.minimum((pts - low) * scale, cells - 1).astype(np.intp)


def grid_cell_index(local: ArrayLike, cells: int) -> IndexArray:
    """
    Return the grid cell (0 .. cells - 1) of each point along each axis, (n, 3).

    Each axis is divided into `cells` equal cells spanning the points' own range along it; an
    axis along which all points coincide puts every point in cell 0.
    """
    pts = np.asarray(local, dtype=np.float64).reshape(-1, 3)
    low, high = _bounds(pts)
    return _cell_index(pts, low, high - low, _check_cells(cells))


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
    pts = np.asarray(local, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        raise ValueError('score_cuts needs at least one point')
    low, high = _bounds(pts)
    whole_extent = high - low
    cell_index = _cell_index(pts, low, whole_extent, cells)
    count = len(pts)

    # Per-cell bounds of every coordinate, for each cut axis k: group the points by cell with a
    # stable sort of the small integer cell keys (a radix sort, O(n)), then reduce each group.
    cell_min = np.full((3, cells, 3), np.inf)
    cell_max = np.full((3, cells, 3), -np.inf)
    counts = np.empty((3, cells), dtype=np.intp)
    key_type = np.int16 if cells <= np.iinfo(np.int16).max else np.intp
    for axis in range(3):
        keys = cell_index[:, axis]
        grouped = np.take(pts, np.argsort(keys.astype(key_type), kind='stable'), axis=0)
        counts[axis] = np.bincount(keys, minlength=cells)
        occupied = np.flatnonzero(counts[axis])
        starts = (np.cumsum(counts[axis]) - counts[axis])[occupied]
        cell_min[axis, occupied] = np.minimum.reduceat(grouped, starts, axis=0)
        cell_max[axis, occupied] = np.maximum.reduceat(grouped, starts, axis=0)
    cell_min = cell_min.transpose(0, 2, 1)  # (cut axis, coordinate, cell)
    cell_max = cell_max.transpose(0, 2, 1)

    # Part below cut i holds cells < i (prefix), the part above cells >= i (suffix).
    lower_min = np.minimum.accumulate(cell_min, axis=2)[:, :, :-1]
    lower_max = np.maximum.accumulate(cell_max, axis=2)[:, :, :-1]
    upper_min = np.minimum.accumulate(cell_min[:, :, ::-1], axis=2)[:, :, ::-1][:, :, 1:]
    upper_max = np.maximum.accumulate(cell_max[:, :, ::-1], axis=2)[:, :, ::-1][:, :, 1:]
    lower_count = np.cumsum(counts, axis=1)[:, :-1]
    valid = (lower_count > 0) & (lower_count < count)
    if min_thickness > 0.0:
        axes = np.arange(3)
        with np.errstate(invalid='ignore'):
            valid &= lower_max[axes, axes] - lower_min[axes, axes] >= min_thickness
            valid &= upper_max[axes, axes] - upper_min[axes, axes] >= min_thickness
    with np.errstate(invalid='ignore'):
        lower_extent = np.where(valid[:, None, :], lower_max - lower_min, 0.0)
        upper_extent = np.where(valid[:, None, :], upper_max - upper_min, 0.0)

    families: list[tuple[int | None, int]] = []
    rows = []
    if measure == 'area':
        for projection_axis, cut_axis in AREA_FAMILIES:
            other = 3 - projection_axis - cut_axis
            whole = whole_extent[cut_axis] * whole_extent[other]
            parts = (
                lower_extent[cut_axis, cut_axis] * lower_extent[cut_axis, other]
                + upper_extent[cut_axis, cut_axis] * upper_extent[cut_axis, other]
            )
            rows.append(_ratio(parts, whole, valid[cut_axis]))
            families.append((projection_axis, cut_axis))
    else:
        whole = float(np.prod(whole_extent))
        for cut_axis in range(3):
            lower = np.prod(lower_extent[cut_axis], axis=0)
            parts = lower + np.prod(upper_extent[cut_axis], axis=0)
            rows.append(_ratio(parts, whole, valid[cut_axis]))
            families.append((None, cut_axis))

    axes = np.arange(3)
    return CutScores(
        theta=np.stack(rows),
        families=tuple(families),
        cell_index=cell_index,
        lower_count=lower_count,
        lower_max=lower_max[axes, axes],
        upper_min=upper_min[axes, axes],
        cells=cells,
    )


def _ratio(parts: FloatArray, whole: float, valid: NDArray[np.bool_]) -> FloatArray:
    if not whole > 0.0:
        return np.full(parts.shape, np.inf)
    return np.where(valid, parts / whole, np.inf)


def _make_cut(scores: CutScores, row: int, position: int, box: Box, count: int) -> Cut:
    projection_axis, axis = scores.families[row]
    offset = 0.5 * (scores.lower_max[axis, position] + scores.upper_min[axis, position])
    lower = int(scores.lower_count[axis, position])
    normal = box.rotation[:, axis].copy()
    local_point = np.zeros(3)
    local_point[axis] = offset
    return Cut(
        axis=int(axis),
        projection_axis=None if projection_axis is None else int(projection_axis),
        cell=int(position) + 1,
        cells=scores.cells,
        offset=float(offset),
        theta=float(scores.theta[row, position]),
        lower_count=lower,
        upper_count=count - lower,
        point=box.to_world(local_point[None, :])[0],
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
    flat_best = int(np.argmin(theta))
    best_row, best_position = np.unravel_index(flat_best, theta.shape)
    if not np.isfinite(theta[best_row, best_position]):
        return []
    cuts = [_make_cut(scores, int(best_row), int(best_position), box, count)]
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
