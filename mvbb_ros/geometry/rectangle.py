"""
Minimum-area enclosing rectangle of planar points, by vectorised rotating calipers.

Freeman and Shapira (1975): a minimum-area enclosing rectangle has one side collinear with an
edge of the convex hull. Rotating calipers (Toussaint 1983) visit the hull edges in order and
keep the four supporting vertices. Here the supporting vertices of every edge are found at once:
the edge angles of a convex polygon, taken counter-clockwise, increase over one turn (summed
from the turns between consecutive edges, so rounding cannot make them decrease), and the
vertex extreme in a direction is a binary search (``numpy.searchsorted``) on them. Cost: O(n log
m) for the hull of ``m`` of ``n`` points, then O(m log m).

:func:`min_area_rectangle` serves one planar cloud; :func:`min_area_rectangles` serves many
convex polygons in one call, which is how :mod:`mvbb_ros.geometry.fit` turns a box to its best
rotation about many axes at once (the rectangle of each projected hull silhouette).
"""

from __future__ import annotations

from dataclasses import dataclass

from mvbb_ros.arrays import FloatArray, IndexArray
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

_TWO_PI = 2.0 * np.pi
#: Relative singular value below which planar points are treated as collinear (or coincident).
_RANK_TOLERANCE = 1e-12


@dataclass(frozen=True, eq=False)
class Rectangle:
    """
    An oriented rectangle in the plane.

    :param center: (2,) centre.
    :param axes: (2, 2) rotation (det +1); column k is the unit direction of side k.
    :param extents: (2,) full side lengths along the two axes (>= 0).
    """

    center: FloatArray
    axes: FloatArray
    extents: FloatArray

    @property
    def area(self) -> float:
        """Area (product of the extents), in squared units of the points."""
        return float(self.extents[0] * self.extents[1])

    def corners(self) -> FloatArray:
        """Return the corner points, counter-clockwise, as a (4, 2) array."""
        signs = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        return self.center + (signs * self.extents / 2.0) @ self.axes.T


def _as_points_2d(points: ArrayLike) -> FloatArray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f'expected planar points of shape (N, 2), got shape {pts.shape}')
    if len(pts) == 0:
        raise ValueError('expected at least one planar point, got an empty array')
    if not np.all(np.isfinite(pts)):
        raise ValueError('planar points must be finite, got NaN or inf')
    return pts


def convex_hull_2d(points: ArrayLike) -> IndexArray:
    """
    Return the indices of the convex hull vertices of planar points, counter-clockwise.

    Degenerate input does not raise: coincident points give one index, collinear points the two
    extreme ones.

    :param points: (N, 2) points, N >= 1.
    :return: (m,) indices into `points`; m >= 3 for a proper polygon.
    """
    pts = _as_points_2d(points)
    centered = pts - pts.mean(axis=0)
    scale = float(np.max(np.abs(centered)))
    if scale == 0.0:
        return np.zeros(1, dtype=np.intp)
    centered /= scale
    _, singular, vt = np.linalg.svd(centered, full_matrices=False)
    if len(pts) >= 3 and singular[1] > _RANK_TOLERANCE * singular[0]:
        for options in ('', 'QJ'):
            try:
                return np.asarray(ConvexHull(centered, qhull_options=options).vertices, np.intp)
            except QhullError:
                continue
    # Collinear (or Qhull gave up on a sliver): the two ends along the principal direction.
    along = centered @ vt[0]
    ends = np.array([np.argmin(along), np.argmax(along)], dtype=np.intp)
    return ends[:1] if ends[0] == ends[1] else ends


def min_area_rectangles(
    points: ArrayLike, groups: ArrayLike, count: int
) -> tuple[FloatArray, FloatArray]:
    """
    Find the minimum-area enclosing rectangles of many convex polygons at once.

    Each group of points must be in convex position (the vertices of a convex polygon, possibly
    with repeats or extra points on its edges), in any order: the silhouette of a 3D hull seen
    along an axis is. Each group is ordered counter-clockwise by angle about its centroid; the
    edge angles then increase over one turn, so for every edge the vertices extreme along the
    edge and across it are binary searches (one ``searchsorted`` over all groups at once, the
    groups kept apart by offsets of two turns). O(M log M) for M points in all. Points are
    handled as complex numbers x + iy, which keeps the number of array operations small.

    :param points: (M, 2) points, or (M,) complex numbers x + iy.
    :param groups: (M,) group of each point, in ``range(count)``.
    :param count: number of groups.
    :return: areas (count,) and unit directions of the first side (count, 2). A group with fewer
        than two distinct points has area 0 and direction (1, 0); one without points area inf.
    """
    z = np.asarray(points)
    if not np.iscomplexobj(z):
        z = z.reshape(-1, 2).astype(np.float64) @ np.array([1.0, 1.0j])
    group = np.asarray(groups, dtype=np.intp).ravel()
    areas = np.full(count, np.inf)
    sides = np.ones(count, dtype=np.complex128)
    if not len(z):
        return areas, np.column_stack([sides.real, sides.imag])
    sizes = np.bincount(group, minlength=count)
    areas[sizes > 0] = 0.0
    weight = np.maximum(sizes, 1)
    centroid = np.bincount(group, z.real, count) / weight + 1j * (
        np.bincount(group, z.imag, count) / weight
    )
    # Sort by group, then by angle about the group's centroid (in [-pi, pi]: 8 apart is enough).
    order = np.argsort(8.0 * group + np.angle(z - centroid[group]), kind='stable')
    z, group = z[order], group[order]
    # Drop a point equal to its predecessor in the same group, or (cyclically) to its first.
    tolerance = 1e-13 * max(float(np.max(np.abs(z))), 1e-300)
    keep = np.ones(len(z), dtype=bool)
    keep[1:] = (group[1:] != group[:-1]) | (np.abs(z[1:] - z[:-1]) > tolerance)
    sizes = np.bincount(group[keep], minlength=count)
    starts = np.cumsum(sizes) - sizes
    ends = starts + sizes - 1
    z, group = z[keep], group[keep]
    closing = np.zeros(count, dtype=bool)
    several = sizes > 1
    closing[several] = np.abs(z[ends[several]] - z[starts[several]]) <= tolerance
    if closing.any():
        keep = np.ones(len(z), dtype=bool)
        keep[ends[closing]] = False
        z, group = z[keep], group[keep]
        sizes = np.bincount(group, minlength=count)
        starts = np.cumsum(sizes) - sizes
        ends = starts + sizes - 1
    following = np.arange(1, len(z) + 1)
    following[ends[sizes > 0]] = starts[sizes > 0]
    edges = z[following] - z
    lengths = np.abs(edges)
    usable = lengths > 0.0
    unit = edges / np.where(usable, lengths, 1.0)
    # Edge angles as the running sum of the turns between consecutive edges (each in [0, pi]
    # for a convex polygon; rounding on collinear points is clipped), so they never decrease.
    turns = np.clip(np.angle(unit[following] * unit.conj()), 0.0, np.pi)
    before = np.cumsum(turns) - turns
    angles = before - before[starts[group]]
    total = np.bincount(group, turns, count)[group]
    # Vertex j lies between edges j-1 and j and is extreme for the directions whose angle lies
    # between the outward normals (edge angle - pi/2) of those edges: the vertex extreme along
    # angle phi is the first j with edge angle >= phi + pi/2, wrapping to the group's start.
    # One search serves all groups: each is offset by two turns.
    offset = (2.0 * _TWO_PI) * group
    queries = angles[:, None] + (np.pi / 2.0) * np.arange(1, 5)
    queries -= np.where(queries >= total[:, None], total[:, None], 0.0)
    support = np.searchsorted(offset + angles, queries + offset[:, None])
    support = np.where(support > ends[group][:, None], starts[group][:, None], support)
    # Extents along the edge and across it, from the supporting vertices.
    turned = unit.conj()
    along = ((z[support[:, 0]] - z[support[:, 2]]) * turned).real
    across = ((z[support[:, 1]] - z[support[:, 3]]) * turned).imag
    edge_areas = np.abs(along * across)
    edge_areas[~(usable & np.isfinite(edge_areas))] = np.inf
    # The first edge of each group that attains the group's least area.
    least = np.full(count, np.inf)
    least[sizes > 0] = np.minimum.reduceat(edge_areas, starts[sizes > 0])
    attained = np.flatnonzero(edge_areas == least[group])
    first = np.ones(len(attained), dtype=bool)
    first[1:] = group[attained][1:] != group[attained][:-1]
    best = attained[first]
    best = best[usable[best]]
    areas[group[best]] = edge_areas[best]
    sides[group[best]] = unit[best]
    return areas, np.column_stack([sides.real, sides.imag])


def _enclosing(points: FloatArray, direction: ArrayLike) -> Rectangle:
    """Smallest rectangle with its first side along `direction` that encloses `points`."""
    u = np.asarray(direction, dtype=np.float64)
    # Scale first: the squared length of a tiny vector underflows.
    largest = float(np.max(np.abs(u)))
    u = u / largest if largest > 0.0 else np.array([1.0, 0.0])
    u = u / np.hypot(u[0], u[1])
    axes = np.array([[u[0], -u[1]], [u[1], u[0]]])
    origin = points[0]
    local = (points - origin) @ axes
    low = local.min(axis=0)
    high = local.max(axis=0)
    return Rectangle(center=origin + axes @ ((low + high) / 2.0), axes=axes, extents=high - low)


def min_area_rectangle(points: ArrayLike) -> Rectangle:
    """
    Minimum-area rectangle enclosing planar points (exact, up to rounding).

    Coincident points give a zero-size rectangle, collinear points a zero-width one along
    their line. The returned rectangle encloses every input point.

    :param points: (N, 2) points, N >= 1, finite.
    :return: the rectangle, in the units of the points.
    :raises ValueError: on empty, non-finite or wrongly shaped input.
    """
    pts = _as_points_2d(points)
    hull = convex_hull_2d(pts)
    if len(hull) == 1:
        return _enclosing(pts, (1.0, 0.0))
    if len(hull) == 2:
        return _enclosing(pts, pts[hull[1]] - pts[hull[0]])
    polygon = pts[hull] - pts[hull[0]]
    polygon /= np.max(np.abs(polygon))  # the problem is scale-free; keep clear of underflow
    _, directions = min_area_rectangles(polygon, np.zeros(len(polygon), dtype=np.intp), 1)
    return _enclosing(pts, directions[0])
