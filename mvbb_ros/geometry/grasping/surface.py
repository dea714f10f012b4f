"""
One object's surface as the grasp check sees it: occupancy-grid boundary cells with normals.

:func:`surface_model` bins an object's points (the observed ones, then the estimate of the
hidden side, :class:`~mvbb_ros.geometry.views.completion.CompletedView`) in cubic cells, closes
small holes and keeps the cells with an empty face neighbour, each as the centroid of its points;
the normals are the PCA of the surface points nearby (:func:`_pca_normals`, a numba kernel that
finds neighbours with :mod:`mvbb_ros.geometry.views.cells`). Observed cells weigh more than
estimated ones. The rules: ``docs/grasp_rules.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from mvbb_ros.arrays import column_min, column_span, FloatArray
from mvbb_ros.geometry.views.cells import cell_grid, cell_start, column_keys
import numba as nb
import numpy as np
from numpy.typing import ArrayLike

#: An estimated (not observed) point counts this much towards a pad's support.
ESTIMATED_WEIGHT = 0.25
#: Normals: PCA of the surface points within this many grid cells.
NORMAL_CELLS = 2.0
#: Normals of sparse points take a wider neighbourhood until it holds this many points.
MIN_NEIGHBOURS = 8
#: The largest occupancy grid (cells); coarser cells beyond.
MAX_GRID_CELLS = 4_000_000
#: The widest neighbourhood of a normal, in cells one radius wide.
MAX_REACH = 4
#: Points whose neighbours' surface variation (smallest PCA eigenvalue over the trace; 0 on a
#: plane) exceeds this, in their neighbourhood and in one twice as wide, have no normal: where
#: three faces meet and on the sharpest edges (a cube's corners 0.11-0.22, its edges 0.07-0.16;
#: a 2 cm sphere at 5 mm cells 0.015 at most). A blend of the faces' normals made a pinch at the
#: L shape's inner corner look antipodal (2 cm wide on a 5 cm thick object). Sensor noise varies
#: less in the wider neighbourhood, an edge does not: with one scale a plane with 1.5 mm of noise
#: lost 65 % of its normals at a 5 mm radius, and 4 of the 29 real scans had no grasp (2
#: without the rule); with both, 0.05 % and 3. 0.05 (every edge) cost Figure 6's flask its best
#: grasp (85 %).
EDGE_VARIATION = 0.12
#: Without a table, an object's floor (the support it stands on) is the height along up below
#: which this share of its observed points lies: its observed base, robust to the sensor's
#: noise (the lowest point alone lies a few noise widths below the surface it belongs to).
FLOOR_QUANTILE = 0.01


@dataclass(frozen=True, eq=False)
class SurfaceModel:
    """
    One object's surface as the refinement sees it: the boundary of its occupancy grid.

    :ivar points: (K, 3) the centroid of each boundary cell's points.
    :ivar normals: (K, 3) unit surface normals (PCA of the neighbours; sign arbitrary; zero
        where too few neighbours and on edges, :data:`EDGE_VARIATION`).
    :ivar weights: (K,) 1 for a cell with an observed point, :data:`ESTIMATED_WEIGHT` otherwise.
    :ivar cell: the grid's cell size.
    :ivar floor: the height along `up` of the support the object stands on (the table when
        known, else the observed base, :data:`FLOOR_QUANTILE`); -inf when up is unknown.
    :ivar center: (3,) the mean of the observed points.
    """

    points: FloatArray
    normals: FloatArray
    weights: FloatArray
    cell: float
    floor: float
    center: FloatArray


@nb.njit(cache=True, nogil=True)
def _smallest_eigenvector(
    a00: float, a01: float, a02: float, a11: float, a12: float, a22: float
) -> tuple[float, float, float, float]:
    """Return the smallest eigenvalue's unit eigenvector of a symmetric 3 x 3 matrix, then it."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1
    p = math.sqrt(p2 / 6.0)
    if p <= 1e-300:
        return 0.0, 0.0, 0.0, q
    b00, b11, b22 = (a00 - q) / p, (a11 - q) / p, (a22 - q) / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    det = (
        b00 * (b11 * b22 - b12 * b12)
        - b01 * (b01 * b22 - b12 * b02)
        + b02 * (b01 * b12 - b11 * b02)
    )
    r = min(1.0, max(-1.0, det / 2.0))
    phi = math.acos(r) / 3.0
    smallest = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    r0 = (a00 - smallest, a01, a02)
    r1 = (a01, a11 - smallest, a12)
    r2 = (a02, a12, a22 - smallest)
    best = (0.0, 0.0, 0.0)
    best_norm = 0.0
    for u, v in ((r0, r1), (r0, r2), (r1, r2)):
        x = u[1] * v[2] - u[2] * v[1]
        y = u[2] * v[0] - u[0] * v[2]
        z = u[0] * v[1] - u[1] * v[0]
        norm = math.sqrt(x * x + y * y + z * z)
        if norm > best_norm:
            best_norm = norm
            best = (x, y, z)
    if best_norm <= 1e-300:
        return 0.0, 0.0, 0.0, smallest
    return best[0] / best_norm, best[1] / best_norm, best[2] / best_norm, smallest


@nb.njit(cache=True, nogil=True)
def _moments(
    points: FloatArray,
    cells: np.ndarray,
    span: np.ndarray,
    ordered: FloatArray,
    sorted_keys: np.ndarray,
    starts: np.ndarray,
    i: int,
    reach: int,
    radius: float,
) -> tuple[int, float, float, float, float, float, float, float, float, float]:
    """
    Return the count, sums and second-moment sums of the offsets within `radius` of point i.

    `ordered` are the points in the order of `sorted_keys` (a cell's points one after the
    other in memory); `starts` the first place of each cell key in it (:func:`_key_starts`), or
    empty (then a binary search finds it). Every point of the cells is added, weighted 1 inside
    the radius and 0 outside: whether a point is inside comes in short runs, and a branch on it
    mispredicted (the sums are the same bit for bit: adding a zero to a sum that is never -0
    changes nothing).
    """
    squared = radius * radius
    n = 0
    sx = sy = sz = 0.0
    sxx = sxy = sxz = syy = syz = szz = 0.0
    count = points.shape[0]
    px, py, pz = points[i, 0], points[i, 1], points[i, 2]
    for dx in range(-reach, reach + 1):
        for dy in range(-reach, reach + 1):
            first, last = column_keys(cells[i, 0] + dx, cells[i, 1] + dy, cells[i, 2], reach, span)
            if starts.shape[0]:
                start = starts[first]
                end = starts[last + 1]
            else:
                start = cell_start(sorted_keys, first)
                end = start
                while end < count and sorted_keys[end] <= last:
                    end += 1
            for k in range(start, end):
                x = ordered[k, 0] - px
                y = ordered[k, 1] - py
                z = ordered[k, 2] - pz
                inside = x * x + y * y + z * z <= squared
                weight = 1.0 if inside else 0.0
                n += 1 if inside else 0
                wx, wy, wz = weight * x, weight * y, weight * z
                sx += wx
                sy += wy
                sz += wz
                sxx += wx * x
                sxy += wx * y
                sxz += wx * z
                syy += wy * y
                syz += wy * z
                szz += wz * z
    return n, sx, sy, sz, sxx, sxy, sxz, syy, syz, szz


@nb.njit(cache=True, nogil=True)
def _covariance_eigen(
    n: int,
    sx: float,
    sy: float,
    sz: float,
    sxx: float,
    sxy: float,
    sxz: float,
    syy: float,
    syz: float,
    szz: float,
) -> tuple[float, float, float, float]:
    """Return the smallest eigenvector of these sums' covariance, and its share of the trace."""
    mx, my, mz = sx / n, sy / n, sz / n
    cxx, cyy, czz = sxx / n - mx * mx, syy / n - my * my, szz / n - mz * mz
    nx, ny, nz, smallest = _smallest_eigenvector(
        cxx, sxy / n - mx * my, sxz / n - mx * mz, cyy, syz / n - my * mz, czz
    )
    trace = cxx + cyy + czz
    return nx, ny, nz, smallest / trace if trace > 0.0 else 0.0


#: The most cells of a grid whose keys' first places :func:`_pca_normals` lists (8 bytes each);
#: larger grids look each cell up by a binary search in the sorted keys.
MAX_LISTED_CELLS = 2_000_000


@nb.njit(cache=True, nogil=True)
def _key_starts(sorted_keys: np.ndarray, cells: int) -> np.ndarray:
    """Return, for each key 0 .. `cells`, the first place in `sorted_keys` not below it."""
    starts = np.empty(cells + 1, dtype=np.int64)
    place = 0
    count = sorted_keys.shape[0]
    for key in range(cells + 1):
        while place < count and sorted_keys[place] < key:
            place += 1
        starts[key] = place
    return starts


@nb.njit('float64[:, :](float64[:, :], float64)', cache=True, nogil=True)
def _pca_normals(points: FloatArray, radius: float) -> FloatArray:
    """
    Return each point's normal: the PCA of its neighbours (zero with too few, or on an edge).

    The neighbours are the points within `radius`, or within 2 or 4 times it when fewer than
    :data:`MIN_NEIGHBOURS` are that close (sparse samples). A point is on an edge when the
    surface variation exceeds :data:`EDGE_VARIATION` both in that neighbourhood and in one twice
    as wide: sensor noise varies less in the wider one, an edge does not. The points are binned
    in cubic cells one radius wide (:func:`~mvbb_ros.geometry.views.cells.cell_grid`) and the cells
    around each point are looked up in the sorted cell keys.
    """
    count = points.shape[0]
    normals = np.zeros((count, 3))
    if count == 0:
        return normals
    cells, span, order, sorted_keys = cell_grid(points, radius, MAX_REACH)
    ordered = np.empty((count, 3))
    for k in range(count):
        for axis in range(3):
            ordered[k, axis] = points[order[k], axis]
    # Each cell's first place: a look-up instead of a binary search (the same places).
    grid_cells = span[0] * span[1] * span[2]
    starts = np.empty(0, dtype=np.int64)
    if grid_cells <= MAX_LISTED_CELLS:
        starts = _key_starts(sorted_keys, grid_cells)
    for i in range(count):
        reach = 1
        moments = _moments(points, cells, span, ordered, sorted_keys, starts, i, reach, radius)
        for wider_reach in (2, MAX_REACH):
            if moments[0] >= MIN_NEIGHBOURS:
                break
            reach = wider_reach
            moments = _moments(
                points, cells, span, ordered, sorted_keys, starts, i, reach, reach * radius
            )
        if moments[0] < 4:
            continue
        nx, ny, nz, variation = _covariance_eigen(*moments)
        if variation > EDGE_VARIATION:
            if reach == MAX_REACH:  # no wider neighbourhood to ask: the same answer
                continue
            wide = min(2 * reach, MAX_REACH)
            wider = _moments(
                points, cells, span, ordered, sorted_keys, starts, i, wide, wide * radius
            )
            if _covariance_eigen(*wider)[3] > EDGE_VARIATION:
                continue
        normals[i, 0] = nx
        normals[i, 1] = ny
        normals[i, 2] = nz
    return normals


@nb.njit('boolean[:, :, ::1](boolean[:, :, ::1])', cache=True, nogil=True)
def _eroded(grid: np.ndarray) -> np.ndarray:
    """Return `grid` eroded by the six face neighbours (border cells are not kept)."""
    nx, ny, nz = grid.shape
    out = np.zeros((nx, ny, nz), dtype=np.bool_)
    for x in range(1, nx - 1):
        for y in range(1, ny - 1):
            for z in range(1, nz - 1):
                out[x, y, z] = (
                    grid[x, y, z]
                    and grid[x - 1, y, z]
                    and grid[x + 1, y, z]
                    and grid[x, y - 1, z]
                    and grid[x, y + 1, z]
                    and grid[x, y, z - 1]
                    and grid[x, y, z + 1]
                )
    return out


@nb.njit(
    'Tuple((float64[:, :], float64[:]))(float64[:, :], float64[:], float64, int64, int64)',
    cache=True,
    nogil=True,
)
def _surface_cells(
    points: FloatArray, low: FloatArray, cell: float, seen: int, margin: int
) -> tuple[FloatArray, FloatArray]:
    """
    Return the surface cells' centroids and weights (see :func:`surface_model`).

    The points are binned in cubic cells from `low` (at least `margin` >= 2 cells inside the
    grid); the occupancy grid is closed (dilated, then eroded, by the six face neighbours;
    outside the grid counts as empty), and a cell with points is on the surface when it or one
    of its face neighbours is not in the eroded solid. Cells come in C order of their grid
    index; each centroid is the mean of its points taken in their order; the weight is 1 when
    one of the first `seen` points is in the cell, else :data:`ESTIMATED_WEIGHT`.
    """
    count = points.shape[0]
    index = np.empty((count, 3), dtype=np.int64)
    top = np.zeros(3, dtype=np.int64)
    for i in range(count):
        for k in range(3):
            value = np.int64(np.floor((points[i, k] - low[k]) / cell))
            index[i, k] = value
            top[k] = max(top[k], value)
    nx, ny, nz = top[0] + margin + 1, top[1] + margin + 1, top[2] + margin + 1
    occupied = np.zeros((nx, ny, nz), dtype=np.bool_)
    for i in range(count):
        occupied[index[i, 0], index[i, 1], index[i, 2]] = True
    # Closing: dilate by the face neighbours, then erode (outside the grid is empty).
    dilated = occupied.copy()
    for x in range(nx):
        for y in range(ny):
            for z in range(nz):
                if occupied[x, y, z]:
                    if x > 0:
                        dilated[x - 1, y, z] = True
                    if x + 1 < nx:
                        dilated[x + 1, y, z] = True
                    if y > 0:
                        dilated[x, y - 1, z] = True
                    if y + 1 < ny:
                        dilated[x, y + 1, z] = True
                    if z > 0:
                        dilated[x, y, z - 1] = True
                    if z + 1 < nz:
                        dilated[x, y, z + 1] = True
    solid = _eroded(dilated)
    for x in range(nx):
        for y in range(ny):
            for z in range(nz):
                solid[x, y, z] = solid[x, y, z] or occupied[x, y, z]
    inside = _eroded(solid)
    # Surface cells in C order of their grid index, then their points in order.
    ids = np.full((nx, ny, nz), -1, dtype=np.int32)  # at most MAX_GRID_CELLS cells
    cells = 0
    for x in range(nx):
        for y in range(ny):
            for z in range(nz):
                if occupied[x, y, z] and not inside[x, y, z]:
                    ids[x, y, z] = cells
                    cells += 1
    sums = np.zeros((cells, 3))
    counts = np.zeros(cells)
    observed = np.zeros(cells)
    for i in range(count):
        c = ids[index[i, 0], index[i, 1], index[i, 2]]
        if c < 0:
            continue
        for k in range(3):
            sums[c, k] += points[i, k]
        counts[c] += 1.0
        if i < seen:
            observed[c] += 1.0
    weights = np.empty(cells)
    for c in range(cells):
        for k in range(3):
            sums[c, k] /= counts[c]
        weights[c] = 1.0 if observed[c] > 0.0 else ESTIMATED_WEIGHT
    return sums, weights


def surface_model(
    points: ArrayLike,
    *,
    observed: int | None = None,
    cell: float,
    up: ArrayLike | None = None,
    support_floor: float | None = None,
) -> SurfaceModel:
    """
    Return the surface of one object's points: the boundary cells of their occupancy grid.

    The points (observed first, then the estimate of the hidden side, which fills the object's
    inside) are binned in cubic cells; small holes are closed; a cell with points that has an
    empty face neighbour is on the surface, represented by the centroid of its points. Normals
    are the PCA of the surface points within :data:`NORMAL_CELLS` cells.

    :param points: (N, 3) the object's points, N >= 1.
    :param observed: how many of the first points were observed (default all).
    :param cell: the grid's cell size (the point spacing), > 0; coarser for very large objects.
    :param up: the up direction, or None (no floor).
    :param support_floor: with `up`, the height along unit `up` of the table the object rests
        on, when known; else the floor is the observed points' :data:`FLOOR_QUANTILE` height.
    :return: the surface model.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    seen = len(pts) if observed is None else int(observed)
    if not cell > 0.0:
        raise ValueError(f'cell must be > 0, got {cell!r}')
    margin = 2
    span = column_span(pts) if len(pts) else np.zeros(3)
    cells = float(np.prod(span / cell + 2 * margin + 1))
    if cells > MAX_GRID_CELLS:
        cell *= (cells / MAX_GRID_CELLS) ** (1.0 / 3.0)
    low = column_min(pts) - margin * cell
    centroids, weights = _surface_cells(pts, low, float(cell), seen, margin)
    normals = _pca_normals(np.ascontiguousarray(centroids), NORMAL_CELLS * cell)
    if up is None:
        floor = -math.inf
    elif support_floor is None:
        unit_up = np.asarray(up, dtype=np.float64)
        heights = pts[: max(seen, 1)] @ (unit_up / np.linalg.norm(unit_up))
        floor = float(np.quantile(heights, FLOOR_QUANTILE))
    else:
        floor = float(support_floor)
    center = pts[: max(seen, 1)].mean(axis=0)
    return SurfaceModel(centroids, normals, weights, float(cell), floor, center)


def warm_up() -> None:
    """Run the module's kernels once on a small box (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(*[np.linspace(-0.03, 0.03, 7)] * 3, indexing='ij'), -1)
    surface_model(grid.reshape(-1, 3), cell=0.01, up=(0.0, 0.0, 1.0))
