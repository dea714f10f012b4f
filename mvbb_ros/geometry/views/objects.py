"""
Objects in one cloud: a "segmented" cloud may still hold several objects, or one in pieces.

:func:`separate_objects` groups points into Euclidean clusters (points closer than
`tolerance` are one object), then joins the pieces of an object that something in front of it
cut apart: two clusters are one object when they come within :data:`PIECE_GAP_FACTOR` times
the tolerance of each other and overlap or touch in the sensor's view (one piece partly hides,
or continues, the other). Side-by-side objects with background between them in the view stay
apart. The rule and its measurements are in ``docs/single_views.md``.

On a table (a support plane given), two pieces that each rest on it with their own footprint
are two objects, however close: each stands on the table by itself (:func:`own_footprints`).
A piece of one object cut off by self-occlusion (a handle, a rim, a bowl's inside) either does
not reach down to the table or rests on it within the other piece's footprint.
"""

from __future__ import annotations

import itertools

from mvbb_ros.arrays import FloatArray, IndexArray, perpendicular_axes
from mvbb_ros.geometry.views.cells import cell_grid, cell_start, column_keys, search_tree
from mvbb_ros.geometry.views.raster import raster_grid
import numba as nb
import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree, ConvexHull, QhullError

#: Two clusters closer than this many cluster tolerances, touching in the view, are one object.
#: Measured on the shared real scans: pieces of one object separated by self-occlusion or an
#: occluder lie 3.4 to 4.4 cm apart at the 2 cm tolerance (``docs/single_views.md``).
PIECE_GAP_FACTOR = 2.5
#: A piece rests on the support plane when at least ``min_points`` of its points lie in a band
#: this deep (metres) at the bottom of what was kept above the table (``clearance`` above it):
#: its contact with the table.
CONTACT_BAND_M = 0.01


def _convex_outline(flat: FloatArray) -> FloatArray:
    """Return the convex hull of `flat` (N >= 3, 2) as its corners, in order."""
    try:
        return flat[ConvexHull(flat).vertices]
    except QhullError:  # all on a line: a thin hull around it
        return flat[ConvexHull(flat, qhull_options='QJ').vertices]


def _separated(first: FloatArray, second: FloatArray) -> bool:
    """
    Tell whether two convex polygons (K, 2) are disjoint: some axis separates their shadows.

    The axes are the edges' normals (enough for two proper polygons) and the edges themselves
    (for a polygon thinned to a segment, whose ends have no edge of their own).
    """
    for polygon in (first, second):
        edges = np.roll(polygon, -1, axis=0) - polygon
        edges = edges[np.linalg.norm(edges, axis=1) > 0.0]
        for axis in np.concatenate([np.column_stack([edges[:, 1], -edges[:, 0]]), edges]):
            if (first @ axis).max() < (second @ axis).min():
                return True
            if (second @ axis).max() < (first @ axis).min():
                return True
    return False


def own_footprints(
    first: FloatArray,
    second: FloatArray,
    support: FloatArray,
    min_points: int,
    clearance: float = 0.0,
) -> bool:
    """
    Tell whether two pieces (N, 3) each rest on the support plane with a footprint of its own.

    A piece rests on the plane ``support`` = (a, b, c, d), (a, b, c) a unit normal pointing up,
    when at least `min_points` of its points lie at most `clearance` + :data:`CONTACT_BAND_M`
    above it (`clearance`: the height, metres, below which the table's own points were
    dropped); its footprint is the convex hull of those points in the plane. Two resting pieces
    whose footprints do not overlap are two objects standing side by side.
    """
    normal, offset = support[:3], float(support[3])
    axes = np.stack(perpendicular_axes(normal))
    footprints = []
    for piece in (first, second):
        contact = piece[piece @ normal + offset <= clearance + CONTACT_BAND_M]
        if len(contact) < max(min_points, 3):
            return False
        footprints.append(_convex_outline(contact @ axes.T))
    return _separated(*footprints)


@nb.njit(cache=True, nogil=True)
def _root(parent: IndexArray, node: int) -> int:
    """Find `node`'s set in the union-find forest, halving the path on the way."""
    while parent[node] != node:
        parent[node] = parent[parent[node]]
        node = parent[node]
    return node


#: Cells are this fraction of the tolerance wide: any two points of one cell are closer than
#: the tolerance (the cell's diagonal is shorter), so a cell's points join without a test.
_CELL_FRACTION = (1.0 - 1e-9) / np.sqrt(3.0)

#: How many cells a pair of points within the tolerance can lie apart along an axis.
_CELL_REACH = 2


@nb.njit(cache=True, nogil=True)
def _join_if_close(
    points: FloatArray,
    parent: IndexArray,
    order: IndexArray,
    start: int,
    end: int,
    other: int,
    other_end: int,
    squared: float,
) -> None:
    """Join two cells' clusters when some pair of their points is within the tolerance."""
    for a in range(start, end):
        i = order[a]
        for b in range(other, other_end):
            j = order[b]
            distance = 0.0
            for axis in range(3):
                delta = points[i, axis] - points[j, axis]
                distance += delta * delta
            if distance <= squared:
                mine, theirs = _root(parent, i), _root(parent, j)
                if mine != theirs:
                    parent[max(mine, theirs)] = min(mine, theirs)
                return


@nb.njit('int64[:](float64[:, :], float64)', cache=True, nogil=True)
def _cluster_labels(points: FloatArray, tolerance: float) -> IndexArray:
    """
    Label the Euclidean clusters of `points` at `tolerance` (labels 0 .. k-1, by first point).

    Points are binned in cubic cells whose diagonal is shorter than the tolerance
    (:mod:`mvbb_ros.geometry.views.cells`): a cell's points are one cluster at once, and two
    cells up to two apart join when any pair of their points is within the tolerance (the search
    stops at the first). Near-linear in the points however dense the cloud: the work grows with the
    occupied cells, not with the points per cell squared.
    """
    count = points.shape[0]
    cells, span, order, sorted_keys = cell_grid(points, tolerance * _CELL_FRACTION, _CELL_REACH)
    parent = np.arange(count)
    squared = tolerance * tolerance
    start = 0
    while start < count:
        key = sorted_keys[start]
        end = start
        while end < count and sorted_keys[end] == key:
            end += 1
        first = order[start]
        for k in range(start + 1, end):  # one cell: one cluster
            mine, theirs = _root(parent, first), _root(parent, order[k])
            if mine != theirs:
                parent[max(mine, theirs)] = min(mine, theirs)
        x, y, z = cells[first, 0], cells[first, 1], cells[first, 2]
        for dx in range(-_CELL_REACH, _CELL_REACH + 1):
            for dy in range(-_CELL_REACH, _CELL_REACH + 1):
                low, high = column_keys(x + dx, y + dy, z, _CELL_REACH, span)
                other = cell_start(sorted_keys, max(low, key + 1))  # each pair of cells once
                while other < count and sorted_keys[other] <= high:
                    other_key = sorted_keys[other]
                    other_end = other
                    while other_end < count and sorted_keys[other_end] == other_key:
                        other_end += 1
                    if _root(parent, first) != _root(parent, order[other]):
                        _join_if_close(
                            points, parent, order, start, end, other, other_end, squared
                        )
                    other = other_end
        start = end
    labels = np.empty(count, dtype=np.int64)
    names = np.full(count, -1, dtype=np.int64)
    next_label = 0
    for i in range(count):
        root = _root(parent, i)
        if names[root] < 0:
            names[root] = next_label
            next_label += 1
        labels[i] = names[root]
    return labels


def separate_objects(
    points: ArrayLike,
    tolerance: float,
    *,
    viewpoint: ArrayLike = (0.0, 0.0, 0.0),
    spacing: float,
    min_points: int = 1,
    support: ArrayLike | None = None,
    clearance: float = 0.0,
) -> list[IndexArray]:
    """
    Split a cloud into objects.

    :param points: (N, 3) points, metres.
    :param tolerance: points closer than this (metres) belong to one object; 0 keeps the whole
        cloud as one object.
    :param viewpoint: (3,) sensor position in the points' frame.
    :param spacing: point spacing (the voxel size), metres: the view's resolution.
    :param min_points: clusters with fewer points are left out (noise).
    :param support: (a, b, c, d) of the plane ``a x + b y + c z + d = 0`` the objects stand on,
        (a, b, c) pointing up, or None: pieces resting on it side by side are not joined.
    :param clearance: with `support`, the height above it (metres) below which the points were
        dropped as the table's (the scene stage's ``support_distance``).
    :return: each object's point indices (sorted), largest object first (ties: the one with
        the lower first index).
    """
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if not pts.flags.writeable:  # the compiled kernel's signature takes writable arrays
        pts = pts.copy()
    if tolerance <= 0.0 or len(pts) < 2:
        return [np.arange(len(pts), dtype=np.intp)] if len(pts) >= min_points else []
    labels = _cluster_labels(pts, float(tolerance)).astype(np.intp)
    count = int(labels.max()) + 1
    if count > 1:
        labels = _join_pieces(
            pts,
            labels,
            count,
            tolerance,
            np.asarray(viewpoint, dtype=np.float64),
            spacing,
            min_points,
            None if support is None else _unit_plane(support),
            clearance,
        )
    groups = [group for group in _members(labels) if len(group) >= min_points]
    groups.sort(key=lambda group: (-len(group), int(group[0])))
    return groups


def _members(labels: IndexArray) -> list[IndexArray]:
    """
    Return each label's point indices (sorted), by increasing label, for labels 0 .. k-1.

    One stable sort of the labels (O(N log N)) instead of one pass over every point per label,
    which made a cloud of thousands of small clusters quadratic.
    """
    order = np.argsort(labels, kind='stable')
    sizes = np.bincount(labels)
    return [group for group in np.split(order, np.cumsum(sizes)[:-1]) if len(group)]


def _unit_plane(support: ArrayLike) -> FloatArray:
    """Return the plane (a, b, c, d) scaled so that (a, b, c) is a unit vector."""
    plane = np.asarray(support, dtype=np.float64).reshape(4)
    return plane / np.linalg.norm(plane[:3])


def _join_pieces(
    points: FloatArray,
    labels: IndexArray,
    count: int,
    tolerance: float,
    viewpoint: FloatArray,
    spacing: float,
    min_points: int,
    support: FloatArray | None = None,
    clearance: float = 0.0,
) -> IndexArray:
    """Relabel clusters that are pieces of one object (close, and touching in the view)."""
    sizes = np.bincount(labels, minlength=count)
    pieces = np.flatnonzero(sizes >= min_points)
    if len(pieces) < 2:
        return labels
    # Only which cell of the view each point falls in: the view's outline is not needed.
    grid = raster_grid(points, viewpoint, spacing)
    cells, _ = grid.cells(points)
    seen = cells[:, 0] >= 0
    shape = (grid.rows, grid.cols)
    # Each piece's outline, grown by two cells, as sorted flat cell numbers; the growing runs
    # on the piece's own window of the raster, so a frame of many pieces stays linear.
    members = dict(zip(np.unique(labels).tolist(), _members(labels), strict=True))
    outlines: dict[int, IndexArray] = {}
    grown: dict[int, IndexArray] = {}
    empty = np.empty(0, dtype=np.intp)
    for label in pieces.tolist():
        mine = members[label][seen[members[label]]]
        if not len(mine):
            outlines[label] = grown[label] = empty
            continue
        rows, cols = cells[mine, 0], cells[mine, 1]
        outlines[label] = np.unique(rows * shape[1] + cols)
        low = np.maximum([rows.min() - 2, cols.min() - 2], 0)
        high = np.minimum([rows.max() + 3, cols.max() + 3], shape)
        window = np.zeros(high - low, dtype=bool)
        window[rows - low[0], cols - low[1]] = True
        window_rows, window_cols = np.nonzero(ndimage.binary_dilation(window, iterations=2))
        grown[label] = (window_rows + low[0]) * shape[1] + window_cols + low[1]
    # Which pieces' outlines each grown outline reaches.
    outline_cells = np.concatenate([outlines[label] for label in pieces.tolist()])
    outline_labels = np.concatenate(
        [np.full(len(outlines[label]), label) for label in pieces.tolist()]
    )
    reaches = {
        label: set(np.unique(outline_labels[np.isin(outline_cells, grown[label])]).tolist())
        for label in pieces.tolist()
    }
    trees: dict[int, cKDTree] = {}

    def tree(label: int) -> cKDTree:  # only the pieces of a pair that touch in the view
        if label not in trees:
            trees[label] = search_tree(points[members[label]])
        return trees[label]

    gap = PIECE_GAP_FACTOR * tolerance
    edges = []
    for first, second in itertools.combinations(pieces.tolist(), 2):
        if second not in reaches[first]:
            continue
        smaller, larger = sorted((first, second), key=lambda label: tree(label).n)
        distance, _ = trees[larger].query(trees[smaller].data, distance_upper_bound=gap)
        if not np.any(np.isfinite(distance)):
            continue
        if support is not None and own_footprints(
            trees[first].data, trees[second].data, support, min_points, clearance
        ):
            continue
        edges.append((first, second))
    if not edges:
        return labels
    pairs = np.array(edges)
    graph = coo_matrix(
        (np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(count, count)
    )
    _, merged = connected_components(graph, directed=False)
    return merged[labels].astype(np.intp)


def warm_up() -> None:
    """Run every kernel of this module once (see :mod:`mvbb_ros.kernels`)."""
    _cluster_labels(np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [1.0, 0.0, 0.0]]), 0.02)
