"""
Convex hull of a 3D point set, with the adjacency the bounding-box search needs.

The minimum box of a point set is the minimum box of its convex hull, so the search only looks
at hull vertices. Besides vertices and facets, the search needs each hull edge with its two
facets: an edge whose facets face opposite ways along an axis lies on the *silhouette* (shadow
boundary) of the hull seen along that axis, and the silhouette is what projects onto the 2D hull
of the projection (rotating calipers about that axis work on it alone).

Large clouds are first thinned by an exact cull (:func:`interior_cull`). Degenerate input
(coincident, collinear or coplanar points) has no 3D hull: :func:`affine_rank` tells it apart
beforehand. :func:`convex_hull` never lets a Qhull error out: it retries with joggled input and
raises :class:`DegenerateHullError` (a :class:`ValueError`) when even that fails.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import itertools

from mvbb_ros.arrays import BoolArray, FloatArray, IndexArray
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

#: Relative singular value (of the centred points) below which a direction counts as empty.
RANK_TOLERANCE = 1e-10
#: Absolute slack on the sign of (unit normal . unit axis) when testing silhouette edges.
#: Extra edges only add candidates; a missed edge could lose the optimum, so err on inclusion.
SILHOUETTE_TOLERANCE = 1e-9
#: Clouds with at least this many points are culled (:func:`interior_cull`) before Qhull.
CULL_MIN_POINTS = 2048

#: Points per block in the cull, to keep temporaries small.
_CULL_BLOCK = 16384
#: Points whose extremes span the inner polytope (an evenly spread subset of larger clouds).
_CULL_SUBSET = 8192
#: Points probed to decide whether the cull pays, and the kept fraction above which it does not.
_CULL_PROBE = 512
_CULL_WORTHWHILE = 0.6
#: Clouds with at least this many points are culled with all 13 directions, smaller ones with 7.
_CULL_FINE_POINTS = 65536
#: The 13 directions of a cube's corner, face and edge axes (one sign each), in that order.
_CUBE_AXES = np.array(
    [d for d in itertools.product((-1, 0, 1), repeat=3) if d > (0, 0, 0)],
    dtype=np.float64,
)
_CUBE_AXES = _CUBE_AXES[np.argsort(np.count_nonzero(_CUBE_AXES, axis=1) % 3, kind='stable')]
_CULL_DIRECTIONS = _CUBE_AXES / np.linalg.norm(_CUBE_AXES, axis=1)[:, None]


class DegenerateHullError(ValueError):
    """The points span fewer than three dimensions (or Qhull could not build a 3D hull)."""


@dataclass(frozen=True, eq=False)
class Hull:
    """
    Triangulated convex hull of 3D points.

    :param vertices: (H, 3) hull vertex coordinates.
    :param facets: (F, 3) vertex indices of each triangular facet.
    :param normals: (F, 3) outward unit facet normals.
    :param areas: (F,) facet areas.
    :param edges: (E, 2) vertex indices of each hull edge (each edge once).
    :param edge_facets: (E, 2) indices of the two facets that share each edge.

    Derived on construction: ``vertex_rows`` (3, H) and ``normal_rows`` (3, F), the vertex and
    normal coordinates as rows (reductions then run along contiguous memory); ``edge_ends``
    (E, 2, 3), both ends of each edge; ``edge_vectors`` (E, 3), from the first end to the second.
    """

    vertices: FloatArray
    facets: IndexArray
    normals: FloatArray
    areas: FloatArray
    edges: IndexArray
    edge_facets: IndexArray
    vertex_rows: FloatArray = field(init=False, repr=False)
    normal_rows: FloatArray = field(init=False, repr=False)
    edge_ends: FloatArray = field(init=False, repr=False)
    edge_vectors: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        ends = self.vertices[self.edges]
        object.__setattr__(self, 'vertex_rows', np.ascontiguousarray(self.vertices.T))
        object.__setattr__(self, 'normal_rows', np.ascontiguousarray(self.normals.T))
        object.__setattr__(self, 'edge_ends', ends)
        object.__setattr__(self, 'edge_vectors', ends[:, 1] - ends[:, 0])

    def silhouette(self, axes: ArrayLike) -> BoolArray:
        """
        Tell which edges lie on the silhouette of the hull seen along each axis.

        An edge is on the silhouette of axis ``a`` when its two facet normals ``n1, n2`` have
        ``(n1 . a) (n2 . a) <= 0`` and not both ``n . a = 0`` (with
        :data:`SILHOUETTE_TOLERANCE`). Every vertex of the 2D hull of the projection along ``a``
        is an end of such an edge, and every 2D hull edge is the projection of one or lies on
        the projection of one.

        :param axes: (K, 3) unit axes.
        :return: (K, E) mask.
        """
        facing = project(axes, self.normal_rows)
        # Classify each facet as facing forward (+1), backward (-1) or sideways (0) along each
        # axis: the rule above holds exactly when an edge's two facets are classed differently.
        side = (facing > SILHOUETTE_TOLERANCE).view(np.int8) - (
            facing < -SILHOUETTE_TOLERANCE
        ).view(np.int8)
        return side[:, self.edge_facets[:, 0]] != side[:, self.edge_facets[:, 1]]


def project(directions: ArrayLike, rows: FloatArray) -> FloatArray:
    """
    Return the heights (K, N) of points along directions.

    numpy's own einsum loop rather than a BLAS product: with an inner size of 3 these products
    are memory-bound, and multithreaded BLAS makes them many times slower, unpredictably, on a
    busy machine.

    :param directions: (K, 3) directions.
    :param rows: (3, N) point coordinates as rows (x, y, z).
    :return: (K, N) dot products.
    """
    return np.einsum('kd,dn->kn', np.asarray(directions, dtype=np.float64), rows)


def affine_rank(points: ArrayLike) -> tuple[int, FloatArray]:
    """
    Find the dimension of the affine span of `points` and its principal directions.

    :param points: (N, 3) points, N >= 1, best centred and scaled to about unit size.
    :return: the rank (0 to 3) and a right-handed (3, 3) rotation whose columns are the
        principal directions, largest spread first (the PCA axes).
    """
    centered = np.asarray(points, dtype=np.float64)
    centered = centered - centered.mean(axis=0)
    # Fast path: the covariance's eigenvalues are the squared singular values. Squaring halves
    # the usable precision, so near-degenerate clouds take the exact path below.
    variances, vectors = np.linalg.eigh(np.einsum('nd,ne->de', centered, centered))
    variances = variances[::-1]
    vectors = vectors[:, ::-1]
    if variances[2] <= (1e-4) ** 2 * variances[0]:
        # The triangular factor of a QR decomposition has the singular values and right singular
        # vectors of the (N, 3) matrix, without squaring its condition number.
        triangle = np.linalg.qr(centered, mode='r') if len(centered) > 3 else centered
        _, singular, vt = np.linalg.svd(triangle, full_matrices=True)
        variances = np.concatenate([singular, np.zeros(3 - len(singular))]) ** 2
        vectors = vt.T
    spread = np.sqrt(np.maximum(variances, 0.0))
    rank = 0 if spread[0] == 0.0 else int(np.sum(spread > RANK_TOLERANCE * spread[0]))
    rotation = np.array(vectors, dtype=np.float64)
    if np.linalg.det(rotation) < 0.0:
        rotation[:, 2] = -rotation[:, 2]
    return rank, rotation


def interior_cull(points: FloatArray) -> IndexArray:
    """
    Return the indices of the points that may be hull vertices (Akl-Toussaint throw-away).

    The points extreme along fixed directions (the 3 axes and 4 diagonals of a cube, and its 6
    edge axes from 65,536 points on), among an evenly spread subset of 8,192 points, span an
    inner polytope. A point inside it is a convex combination of input points, so it is neither
    a hull vertex nor can it change any bounding box. Cost O(N) with a small constant: one test
    per facet of the inner polytope, in blocks to keep temporaries small. Solid clouds lose most
    of their points, surface scans about half; when a probe of 512 points says more than 60 %
    would stay (flat sides), all points are returned untested.

    :param points: (N, 3) points, best centred and scaled to about unit size.
    :return: sorted indices of the points on or outside the inner polytope.
    """
    # Coordinates as three contiguous rows: projections and reductions then run along rows.
    rows = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)
    count = rows.shape[1]
    directions = _CULL_DIRECTIONS[: 13 if count >= _CULL_FINE_POINTS else 7]
    # The polytope spans the extreme points of an evenly spread subset: still input points, so
    # the cull stays exact, and deciding whether it pays costs next to nothing.
    step = max(1, count // _CULL_SUBSET)
    subset = np.ascontiguousarray(rows[:, ::step])
    heights = project(directions, subset)
    extremes = step * np.unique(np.concatenate([heights.argmin(axis=1), heights.argmax(axis=1)]))
    try:
        inner = ConvexHull(rows[:, extremes].T)
    except QhullError:
        return np.arange(count)
    # Signed heights above the inner facets; points within rounding of the boundary are kept.
    planes = inner.equations
    planes[:, 3] += 1e-12
    # Flat-sided scans keep most points (they lie on the hull's faces): when an evenly spread
    # probe says so, testing them all would cost more than Qhull saves.
    probe = subset[:, :: max(1, subset.shape[1] // _CULL_PROBE)]
    probe_heights = project(planes[:, :3], probe) + planes[:, 3:]
    if np.mean(probe_heights.max(axis=0) > 0.0) > _CULL_WORTHWHILE:
        return np.arange(count)
    keep = np.zeros(count, dtype=bool)
    for begin in range(0, count, _CULL_BLOCK):
        end = begin + _CULL_BLOCK
        heights = project(planes[:, :3], rows[:, begin:end])
        heights += planes[:, 3:]
        keep[begin:end] = heights.max(axis=0) > 0.0
    keep[extremes] = True
    return np.flatnonzero(keep)


def column_extremes(points: ArrayLike, cells: int) -> IndexArray:
    """
    Return the indices of the highest and lowest point of every grid column, along each axis.

    Barequet and Har-Peled's grid coreset: for each coordinate axis, the plane of the other two
    is cut into ``cells x cells`` columns over the points' bounding box, and only the extreme
    points of each column along that axis are kept. Every point is then within one column width
    (1 / `cells` of the box side) of the hull of the kept points, across the column, so a box
    direction found on them is nearly as good as one found on all points; the caller grows its
    box to enclose every point. Cost O(N), a few passes. Best given in the PCA frame, where flat
    scans fill few columns.

    :param points: (N, 3) points, N >= 1.
    :param cells: columns per side, >= 1.
    :return: sorted indices of the kept points (ties at a column's extreme are all kept).
    """
    rows = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)
    low = rows.min(axis=1)
    span = rows.max(axis=1) - low
    # Column index of every point along each axis (the top edge falls in the last column).
    scale = np.divide(cells, span, out=np.zeros(3), where=span > 0.0)
    bins = np.minimum(((rows - low[:, None]) * scale[:, None]).astype(np.intp), cells - 1)
    keep = np.zeros(rows.shape[1], dtype=bool)
    for axis in range(3):
        first, second = (axis + 1) % 3, (axis + 2) % 3
        column = bins[first] * cells + bins[second]
        heights = rows[axis]
        highest = np.full(cells * cells, -np.inf)
        np.maximum.at(highest, column, heights)
        lowest = np.full(cells * cells, np.inf)
        np.minimum.at(lowest, column, heights)
        keep |= heights >= highest[column]
        keep |= heights <= lowest[column]
    return np.flatnonzero(keep)


def convex_hull(points: ArrayLike) -> Hull:
    """
    Compute the convex hull of full-dimensional 3D points, with edge-facet adjacency.

    Large clouds are culled first (:func:`interior_cull`). Qhull runs with its defaults first
    and with joggled input ('QJ') when it reports a precision problem; the vertices are always
    input points, the facets those Qhull found.

    :param points: (N, 3) points spanning three dimensions, best centred and scaled to about
        unit size (Qhull's tolerances are relative, but rounding is not).
    :return: the hull.
    :raises DegenerateHullError: when Qhull cannot build a 3D hull (flat or too few points).
    """
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 4:
        raise DegenerateHullError(f'a 3D hull needs at least 4 points, got {len(pts)}')
    if len(pts) >= CULL_MIN_POINTS:
        kept = interior_cull(pts)
        pts = pts[kept] if len(kept) < len(pts) else pts
    qhull = None
    for options in ('Qt', 'QJ'):
        try:
            qhull = ConvexHull(pts, qhull_options=options)
            break
        except QhullError:
            continue
    if qhull is None:
        raise DegenerateHullError('Qhull could not build a 3D hull: the points are (nearly) flat')
    vertex_ids = np.asarray(qhull.vertices, dtype=np.intp)
    renumber = np.full(len(pts), -1, dtype=np.intp)
    renumber[vertex_ids] = np.arange(len(vertex_ids))
    triangles = renumber[qhull.simplices]
    vertices = pts[vertex_ids]
    corners = vertices[triangles]
    areas = 0.5 * np.linalg.norm(
        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
    )
    # Facet f's neighbour i lies opposite its vertex i: they share the other two vertices.
    facet = np.repeat(np.arange(len(triangles)), 3)
    neighbour = np.asarray(qhull.neighbors, dtype=np.intp).ravel()
    start = triangles[:, [1, 2, 0]].ravel()
    end = triangles[:, [2, 0, 1]].ravel()
    once = facet < neighbour
    return Hull(
        vertices=vertices,
        facets=triangles,
        normals=np.ascontiguousarray(qhull.equations[:, :3]),
        areas=areas,
        edges=np.column_stack([start[once], end[once]]),
        edge_facets=np.column_stack([facet[once], neighbour[once]]),
    )
