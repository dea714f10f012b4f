"""
The table's extent in its plane: the largest connected patch of a plane's inliers, its outline.

The scene stage (:mod:`mvbb_ros.pipeline.scene`) keeps of a fitted plane's inliers the largest
8-connected patch on a grid in the plane (:func:`largest_patch`: the table, not every point at
table height in the room), takes the convex hull of the patch's points projected into the plane
as the table's outline (:func:`outline_2d`), and keeps what stands inside it
(:func:`inside_outline`). The grid and the hull's culling are compiled (numba); the labels are
scipy's, the hull Qhull's.
"""

from __future__ import annotations

from typing import Any

from mvbb_ros.arrays import BoolArray, FloatArray, IndexArray
from numba import njit
import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError


def largest_patch(flat: FloatArray, cell: float) -> IndexArray:
    """Return the indices of the points of the largest 8-connected patch of `flat` (N, 2)."""
    cells, occupied = _grid_cells(np.ascontiguousarray(flat, dtype=np.float64), float(cell))
    labels, _ = ndimage.label(occupied, structure=np.ones((3, 3), dtype=bool))
    return _largest_label(np.ascontiguousarray(labels, dtype=np.int32), cells)


@njit('Tuple((int64[:, ::1], boolean[:, ::1]))(float64[:, ::1], float64)', cache=True, nogil=True)
def _grid_cells(flat: FloatArray, cell: float) -> tuple[IndexArray, BoolArray]:
    """Return each point's cell on a grid `cell` wide from the lowest corner, and the occupied."""
    count = flat.shape[0]
    low_x, low_y = np.inf, np.inf
    for i in range(count):
        low_x, low_y = min(low_x, flat[i, 0]), min(low_y, flat[i, 1])
    cells = np.empty((count, 2), dtype=np.int64)
    high_x, high_y = 0, 0
    for i in range(count):
        cells[i, 0] = np.int64((flat[i, 0] - low_x) / cell)  # truncated, as numpy's astype
        cells[i, 1] = np.int64((flat[i, 1] - low_y) / cell)
        high_x, high_y = max(high_x, cells[i, 0]), max(high_y, cells[i, 1])
    occupied = np.zeros((high_x + 1, high_y + 1), dtype=np.bool_)
    for i in range(count):
        occupied[cells[i, 0], cells[i, 1]] = True
    return cells, occupied


@njit('int64[::1](int32[:, ::1], int64[:, ::1])', cache=True, nogil=True)
def _largest_label(labels: Any, cells: IndexArray) -> IndexArray:
    """Return the indices of the points in the cells of the label with the most points."""
    count = cells.shape[0]
    sizes = np.zeros(labels.max() + 1, dtype=np.int64)
    for i in range(count):
        sizes[labels[cells[i, 0], cells[i, 1]]] += 1
    sizes[0] = 0
    largest = np.argmax(sizes)  # the first of the largest, as numpy's
    kept = np.empty(sizes[largest], dtype=np.int64)
    found = 0
    for i in range(count):
        if labels[cells[i, 0], cells[i, 1]] == largest:
            kept[found] = i
            found += 1
    return kept


@njit('boolean[::1](float64[:, ::1])', cache=True, nogil=True)
def _off_octagon(flat: FloatArray) -> BoolArray:
    """
    Tell which of `flat` (N, 2) are not well inside the octagon of its extreme points.

    The extreme points in 8 directions (every 45 degrees, counter-clockwise) are hull
    vertices; what lies inside their polygon is no hull vertex. A point counts as inside only
    when it is clearly so (by far more than rounding), so the hull of the points kept is the
    hull of all.
    """
    count = flat.shape[0]
    extreme = np.zeros(8, dtype=np.int64)
    best = np.full(8, -np.inf)
    scale = 0.0
    for i in range(count):
        x, y = flat[i, 0], flat[i, 1]
        scale = max(scale, abs(x), abs(y))
        along = (x, x + y, y, y - x, -x, -x - y, -y, x - y)
        for k in range(8):
            if along[k] > best[k]:
                best[k], extreme[k] = along[k], i
    keep = np.ones(count, dtype=np.bool_)
    edges = 0
    for k in range(8):
        if extreme[k] != extreme[(k + 1) % 8]:
            edges += 1
    if edges < 3:
        return keep
    for i in range(count):
        x, y = flat[i, 0], flat[i, 1]
        inside = True
        for k in range(8):
            a, b = extreme[k], extreme[(k + 1) % 8]
            ex, ey = flat[b, 0] - flat[a, 0], flat[b, 1] - flat[a, 1]
            if ex == 0.0 and ey == 0.0:
                continue
            side = ex * (y - flat[a, 1]) - ey * (x - flat[a, 0])
            if side <= 1e-9 * scale * max(abs(ex), abs(ey)):
                inside = False
                break
        keep[i] = not inside
    return keep


def outline_2d(flat: FloatArray) -> FloatArray:
    """
    Return the convex hull of `flat` (N, 2), counter-clockwise; empty when degenerate.

    Qhull gets only the points off the octagon of the extreme points (:func:`_off_octagon`):
    the same hull, the same vertices in the same order, from a fraction of a table's points.
    """
    if len(flat) < 3:
        return np.empty((0, 2))
    flat = flat[_off_octagon(np.ascontiguousarray(flat, dtype=np.float64))]
    try:
        hull = ConvexHull(flat)
    except QhullError:
        return np.empty((0, 2))
    return flat[hull.vertices]  # counter-clockwise for 2D input


def half_planes(outline: FloatArray) -> tuple[FloatArray, FloatArray]:
    """
    Return the half-planes of the convex, counter-clockwise `outline` (K, 2), K >= 3.

    Each edge's unit outward normal (K, 2) and limit (K,): a point ``q`` is inside when
    ``outward @ q <= limits`` for every edge.
    """
    edges = np.roll(outline, -1, axis=0) - outline
    outward = np.column_stack([edges[:, 1], -edges[:, 0]])
    outward /= np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-300)
    return outward, np.einsum('ij,ij->i', outward, outline)


def inside_outline(flat: FloatArray, outline: FloatArray, margin: float) -> BoolArray:
    """Tell which of `flat` (N, 2) lie at least `margin` inside the convex `outline` (K, 2)."""
    if len(outline) < 3:
        return np.ones(len(flat), dtype=bool)
    outward, limits = half_planes(outline)
    limits = limits - margin
    inside = np.ones(len(flat), dtype=bool)
    for k in range(len(outline)):
        inside &= flat @ outward[k] <= limits[k]
    return inside


def warm_up() -> None:
    """Run every kernel of this module once (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5)), -1).reshape(-1, 2)
    largest_patch(grid, 0.3)
    outline_2d(grid)
