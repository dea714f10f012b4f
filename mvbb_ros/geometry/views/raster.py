"""
The view a sensor had of an object: an angular raster of its outline and nearest ranges.

:func:`view_raster` rasterises observed points as seen from the viewpoint (cells about one and
a half point spacings wide): the object's outline, with a band outside it where a surface seen
too obliquely could still be (:data:`GRAZING_DEG`), and the nearest observed range per cell.
:class:`ViewRaster` answers what the sensor could not have seen (:meth:`ViewRaster.hidden`);
:func:`behind_others` tells points that lie behind another surface along their ray. The shape
completion (:mod:`mvbb_ros.geometry.views.completion`) tests mirror planes against it
(:mod:`mvbb_ros.geometry.views.mirror`) and fills the space behind the seen surface along its
rays (:mod:`mvbb_ros.geometry.views.fill`); the object separation
(:mod:`mvbb_ros.geometry.views.objects`) asks whether two pieces touch in the view.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from mvbb_ros.arrays import (
    BoolArray,
    column_max,
    column_min,
    column_span,
    FloatArray,
    IndexArray,
    perpendicular_axes,
)
import numba as nb
import numpy as np
from numpy.typing import ArrayLike

#: Raster cells per point spacing: a cell holds one or two points, so the outline has no holes.
CELLS_PER_SPACING = 1.5
#: Most raster cells along a side (coarser cells for objects very large for their spacing).
MAX_RASTER_SIDE = 256
#: A depth sensor returns nothing where its ray meets a surface more obliquely than this angle
#: from the surface's normal (degrees; 80 for the evaluation's camera, about a Kinect's). Such a
#: surface leaves a band outside the observed outline where the object may still be: a point
#: at range r whose lateral distance to an outline cell of range r0 is at most
#: tan(90 - GRAZING_DEG) * (r - r0) may lie on a surface the sensor saw too obliquely.
GRAZING_DEG = 80.0
#: tan(90 - GRAZING_DEG): the lateral reach of an unseen oblique surface per metre of depth.
GRAZING_SLOPE = math.tan(math.radians(90.0 - GRAZING_DEG))
#: Most raster cells that band reaches past the outline (the raster's margin grows to it).
MAX_GRAZING_CELLS = 16


@dataclass(frozen=True, eq=False)
class ViewRaster:
    """
    The object as the sensor saw it: an angular image around the viewing direction.

    :ivar viewpoint: (3,) sensor position, metres.
    :ivar frame: (3, 3) rows: image x, image y and the viewing direction (unit vectors).
    :ivar origin: (2,) tangent-plane coordinates (x / z, y / z) of cell (0, 0)'s corner.
    :ivar cell: cell size in tangent-plane units (about radians).
    :ivar mask: (rows, cols) cells the object covers (small holes closed, one cell of margin).
    :ivar near: (rows, cols) smallest observed range (metres) in and next to each cell, +inf
        where nothing was observed.
    :ivar oblique: (rows, cols) outside the outline, the least range (metres) from which a
        point in the cell may lie on a surface the sensor saw too obliquely to return it
        (:data:`GRAZING_DEG`, :func:`_oblique_ranges`); +inf in the outline and beyond reach.
    """

    viewpoint: FloatArray
    frame: FloatArray
    origin: FloatArray
    cell: float
    mask: BoolArray
    near: FloatArray
    oblique: FloatArray

    def locate(self, points: FloatArray) -> tuple[IndexArray, FloatArray]:
        """
        Return each point's cell (row, column; -1, -1 outside the raster or behind the sensor).

        :param points: (N, 3) points.
        :return: the cells (N, 2) and the points' ranges from the viewpoint (N,), metres.
        """
        rows, cols = self.mask.shape
        return _locate(self, points, rows, cols)

    def hidden(self, points: FloatArray, tolerance: float) -> BoolArray:
        """
        Tell which points the sensor could not have seen.

        A point is hidden when it falls in the object's outline and lies more than `tolerance`
        (metres) behind the nearest observed range there, or when it falls outside the outline
        but within reach of a surface too oblique to the sensor's rays to be seen
        (:data:`GRAZING_DEG`).
        """
        return _hidden(
            np.ascontiguousarray(points, dtype=np.float64),
            self.viewpoint,
            self.frame,
            self.origin,
            self.cell,
            self.mask,
            self.near,
            self.oblique,
            tolerance,
        )


@nb.njit(
    'float64[:, :](boolean[:, :], float64[:, :], float64, float64, int64)', cache=True, nogil=True
)
def _oblique_ranges(
    mask: BoolArray, near: FloatArray, cell: float, slope: float, radius: int
) -> FloatArray:
    """
    Return, per cell outside the outline, the least range of a point there that the view allows.

    A surface the sensor sees more obliquely than :data:`GRAZING_DEG` returns nothing, so the
    object may go on past its observed outline along one. A point at range r, d cells from an
    outline cell of nearest range r0, may lie on such a surface from there when its distance
    across the rays, d * cell * r, is at most ``slope * (r - r0)``: when
    r >= r0 / (1 - d * cell / slope). The least such r over the outline cells within `radius`
    cells; +inf in the outline and out of reach.
    """
    rows, cols = mask.shape
    out = np.full((rows, cols), np.inf)
    # The share of the reach per offset (a, b) - (i, j): the same expression, once per offset.
    width = 2 * radius + 1
    shares = np.empty((width, width))
    for da in range(-radius, radius + 1):
        for db in range(-radius, radius + 1):
            shares[da + radius, db + radius] = math.sqrt(float(da**2 + db**2)) * cell / slope
    for i in range(rows):
        for j in range(cols):
            if not mask[i, j] or not near[i, j] < np.inf:
                continue
            edge = False
            for a, b in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)):
                if a < 0 or b < 0 or a >= rows or b >= cols or not mask[a, b]:
                    edge = True
            if not edge:
                continue
            for a in range(max(i - radius, 0), min(i + radius + 1, rows)):
                for b in range(max(j - radius, 0), min(j + radius + 1, cols)):
                    if mask[a, b]:
                        continue
                    share = shares[a - i + radius, b - j + radius]
                    if share < 1.0:
                        out[a, b] = min(out[a, b], near[i, j] / (1.0 - share))
    return out


@nb.njit(cache=True, nogil=True, inline='always')
def pixel(
    dx: float, dy: float, dz: float, frame: FloatArray, origin: FloatArray, cell: float
) -> tuple[int, int]:
    """
    Return the raster cell (row, column) of the point at (dx, dy, dz) from the viewpoint.

    (-1, -1) when the point is not in front of the sensor; callers check the raster's bounds.
    """
    depth = frame[2, 0] * dx + frame[2, 1] * dy + frame[2, 2] * dz
    if depth <= 0.0:
        return -1, -1
    u = (frame[0, 0] * dx + frame[0, 1] * dy + frame[0, 2] * dz) / depth
    v = (frame[1, 0] * dx + frame[1, 1] * dy + frame[1, 2] * dz) / depth
    return math.floor((u - origin[0]) / cell), math.floor((v - origin[1]) / cell)


@nb.njit(
    'boolean[:](float64[:, :], float64[:], float64[:, :], float64[:], float64, boolean[:, :], '
    'float64[:, :], float64[:, :], float64)',
    cache=True,
    nogil=True,
)
def _hidden(
    points: FloatArray,
    viewpoint: FloatArray,
    frame: FloatArray,
    origin: FloatArray,
    cell: float,
    mask: BoolArray,
    near: FloatArray,
    oblique: FloatArray,
    tolerance: float,
) -> BoolArray:
    """Kernel of :meth:`ViewRaster.hidden`."""
    rows, cols = mask.shape
    out = np.zeros(points.shape[0], dtype=np.bool_)
    for i in range(points.shape[0]):
        dx = points[i, 0] - viewpoint[0]
        dy = points[i, 1] - viewpoint[1]
        dz = points[i, 2] - viewpoint[2]
        row, col = pixel(dx, dy, dz, frame, origin, cell)
        if 0 <= row < rows and 0 <= col < cols:
            distance = math.sqrt(dx * dx + dy * dy + dz * dz)
            if mask[row, col]:
                out[i] = distance > near[row, col] + tolerance
            else:
                out[i] = distance >= oblique[row, col]
    return out


@nb.njit(
    'Tuple((int64[:, :], float64[:]))(float64[:, :], float64[:], float64[:, :], float64[:], '
    'float64, int64, int64)',
    cache=True,
    nogil=True,
)
def _cells(
    points: FloatArray,
    viewpoint: FloatArray,
    frame: FloatArray,
    origin: FloatArray,
    cell: float,
    rows: int,
    cols: int,
) -> tuple[IndexArray, FloatArray]:
    """Kernel of :meth:`ViewRaster.locate`."""
    count = points.shape[0]
    index = np.full((count, 2), -1, dtype=np.int64)
    ranges = np.empty(count)
    for i in range(count):
        dx = points[i, 0] - viewpoint[0]
        dy = points[i, 1] - viewpoint[1]
        dz = points[i, 2] - viewpoint[2]
        ranges[i] = math.sqrt(dx * dx + dy * dy + dz * dz)
        row, col = pixel(dx, dy, dz, frame, origin, cell)
        if 0 <= row < rows and 0 <= col < cols:
            index[i, 0] = row
            index[i, 1] = col
    return index, ranges


@nb.njit('boolean[:, ::1](boolean[:, ::1], boolean)', cache=True, nogil=True)
def _grown(grid: BoolArray, grow: bool) -> BoolArray:
    """
    Return `grid` dilated (`grow`) or eroded by the four edge neighbours.

    Outside the grid counts as empty: a border cell is never kept by an erosion.
    """
    rows, cols = grid.shape
    out = np.zeros((rows, cols), dtype=np.bool_)
    for r in range(rows):
        for c in range(cols):
            up = grid[r - 1, c] if r > 0 else False
            down = grid[r + 1, c] if r + 1 < rows else False
            left = grid[r, c - 1] if c > 0 else False
            right = grid[r, c + 1] if c + 1 < cols else False
            if grow:
                out[r, c] = grid[r, c] or up or down or left or right
            else:
                out[r, c] = grid[r, c] and up and down and left and right
    return out


@nb.njit(
    'Tuple((boolean[:, ::1], float64[:, ::1]))(int64[:, :], float64[:], int64, int64)',
    cache=True,
    nogil=True,
)
def _outline(
    index: IndexArray, ranges: FloatArray, rows: int, cols: int
) -> tuple[BoolArray, FloatArray]:
    """
    Return the raster's mask and nearest ranges from the points' cells (-1: outside).

    The mask is the covered cells closed twice (two dilations, two erosions by the edge
    neighbours), then dilated once; the nearest range of a cell is the least range of the
    points in it and its eight neighbours (+inf where there are none).
    """
    covered = np.zeros((rows, cols), dtype=np.bool_)
    least = np.full((rows, cols), np.inf)
    for i in range(index.shape[0]):
        row = index[i, 0]
        if row < 0:
            continue
        col = index[i, 1]
        covered[row, col] = True
        least[row, col] = min(least[row, col], ranges[i])
    mask = _grown(_grown(covered, True), True)
    mask = _grown(_grown(_grown(mask, False), False), True)
    near = np.empty((rows, cols))
    for r in range(rows):
        for c in range(cols):
            value = np.inf
            for dr in range(max(r - 1, 0), min(r + 2, rows)):
                for dc in range(max(c - 1, 0), min(c + 2, cols)):
                    value = min(value, least[dr, dc])
            near[r, c] = value
    return mask, near


def view_raster(points: ArrayLike, viewpoint: ArrayLike, spacing: float) -> ViewRaster:
    """
    Rasterise `points` as seen from `viewpoint`, in cells 1.5 point spacings wide.

    :param points: (N, 3) observed points, N >= 1, metres, all in front of the viewpoint.
    :param viewpoint: (3,) sensor position in the points' frame.
    :param spacing: distance between neighbouring points (the voxel size), metres, > 0.
    :raises ValueError: when the points surround the viewpoint (no viewing direction).
    """
    grid = raster_grid(points, viewpoint, spacing)
    index, ranges = grid.cells(grid.points)
    mask, near = _outline(index, ranges, grid.rows, grid.cols)
    oblique = _oblique_ranges(mask, near, grid.cell, GRAZING_SLOPE, grid.margin)
    return ViewRaster(grid.viewpoint, grid.frame, grid.origin, grid.cell, mask, near, oblique)


@dataclass(frozen=True, eq=False)
class RasterGrid:
    """
    The cells of a view before anything is drawn in them (:func:`raster_grid`).

    :ivar points: (N, 3) the points the grid was made for, float64.
    :ivar viewpoint: (3,) the sensor position.
    :ivar frame: (3, 3) rows: the image's two axes and the viewing direction.
    :ivar origin: (2,) the tangent-plane coordinates of cell (0, 0)'s corner.
    :ivar cell: the cell's width in the tangent plane (radians, about).
    :ivar rows: the grid's rows.
    :ivar cols: the grid's columns.
    :ivar margin: cells of room around the points' outline.
    """

    points: FloatArray
    viewpoint: FloatArray
    frame: FloatArray
    origin: FloatArray
    cell: float
    rows: int
    cols: int
    margin: int

    def cells(self, points: FloatArray) -> tuple[IndexArray, FloatArray]:
        """Return each point's (row, col), (-1, -1) outside, and its range (:meth:`locate`)."""
        return _locate(self, points, self.rows, self.cols)


def _locate(
    view: ViewRaster | RasterGrid, points: FloatArray, rows: int, cols: int
) -> tuple[IndexArray, FloatArray]:
    """Return :func:`_cells` of `points` in `view`'s grid of `rows` x `cols` cells."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    return _cells(pts, view.viewpoint, view.frame, view.origin, view.cell, rows, cols)


def raster_grid(points: ArrayLike, viewpoint: ArrayLike, spacing: float) -> RasterGrid:
    """
    Return the cells :func:`view_raster` draws `points` in (its arguments; nothing drawn).

    For a caller that needs only which cell each point falls in (:meth:`RasterGrid.cells`, the
    same cells as :meth:`ViewRaster.locate` of the raster of the same points).
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    eye = np.asarray(viewpoint, dtype=np.float64)
    axis = pts.mean(axis=0) - eye
    length = float(np.linalg.norm(axis))
    if not length > 0.0:
        raise ValueError('the points surround the viewpoint: there is no viewing direction')
    axis /= length
    side, second = perpendicular_axes(axis)
    frame = np.stack([side, second, axis])
    offsets = pts - eye
    relative = offsets @ frame.T
    ahead = relative[:, 2] > 0.0
    if not np.any(ahead):
        raise ValueError('no point lies in front of the viewpoint')
    tangent = relative[ahead, :2] / relative[ahead, 2:3]
    distances = np.linalg.norm(offsets, axis=1)
    distance = float(np.median(distances))
    widest = float(np.max(column_span(tangent)))
    cell = max(CELLS_PER_SPACING * spacing / distance, widest / MAX_RASTER_SIDE)
    # Room around the outline for the band a surface seen too obliquely may hide: its reach
    # across the rays for a depth of twice the object's size (a mirror image lies at most that
    # far behind the nearest point).
    size = float(np.max(column_span(pts)))
    nearest = float(np.min(distances))
    reach = GRAZING_SLOPE * 2.0 * size / (max(nearest, 1e-9) * cell)
    margin = max(4, min(MAX_GRAZING_CELLS, math.ceil(reach)))
    origin = column_min(tangent) - margin * cell
    shape = np.ceil((column_max(tangent) - origin) / cell).astype(np.int64) + margin + 1
    return RasterGrid(pts, eye, frame, origin, cell, int(shape[0]), int(shape[1]), margin)


def behind_others(points: FloatArray, raster: ViewRaster, gap: float) -> BoolArray:
    """
    Tell which points lie behind another surface along their ray.

    A point is behind another surface when it lies more than `gap` (metres) behind the previous
    point of its raster cell, or behind such a point. A single view has one surface along each
    ray (a slanted one spreads its points in range, but without gaps); a model, merged views or
    a wrong viewpoint put several surfaces on one ray.
    """
    cells, ranges = raster.locate(points)
    rows, cols = raster.mask.shape
    return _behind(cells, ranges, rows, cols, gap)


@nb.njit('boolean[:](int64[:, :], float64[:], int64, int64, float64)', cache=True, nogil=True)
def _behind(cells: IndexArray, ranges: FloatArray, rows: int, cols: int, gap: float) -> BoolArray:
    """
    Kernel of :func:`behind_others`: per raster cell, the points at or past the first gap.

    A cell's ranges in ascending order (an insertion sort: a cell holds a few points); the first
    range more than `gap` past the one before it starts the hidden surfaces, and every point of
    the cell at that range or farther is behind (equal ranges make no gap, so which of them
    comes first does not matter). Points outside the raster are not behind.
    """
    count = cells.shape[0]
    start = np.zeros(rows * cols + 1, dtype=np.int64)
    for i in range(count):
        if cells[i, 0] >= 0:
            start[cells[i, 0] * cols + cells[i, 1] + 1] += 1
    for key in range(rows * cols):
        start[key + 1] += start[key]
    fill = start[:-1].copy()
    members = np.empty(start[rows * cols], dtype=np.int64)
    for i in range(count):
        if cells[i, 0] >= 0:
            key = cells[i, 0] * cols + cells[i, 1]
            members[fill[key]] = i
            fill[key] += 1
    behind = np.zeros(count, dtype=np.bool_)
    ordered = np.empty(members.shape[0])
    for key in range(rows * cols):
        first, last = start[key], start[key + 1]
        if last - first < 2:
            continue
        for k in range(first, last):
            value = ranges[members[k]]
            at = k
            while at > first and ordered[at - 1] > value:
                ordered[at] = ordered[at - 1]
                at -= 1
            ordered[at] = value
        for k in range(first + 1, last):
            if ordered[k] - ordered[k - 1] > gap:
                for m in range(first, last):
                    behind[members[m]] = ranges[members[m]] >= ordered[k]
                break
    return behind


def warm_up() -> None:
    """Run every kernel of this module once on a tiny view (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(np.linspace(-0.05, 0.05, 6), np.linspace(0.0, 0.1, 6)), -1)
    points = np.column_stack([grid.reshape(-1, 2), np.full(36, 0.8)])
    raster = view_raster(points, np.zeros(3), 0.02)
    raster.hidden(points + [0.0, 0.0, 0.1], 0.02)
    behind_others(points, raster, 0.06)
