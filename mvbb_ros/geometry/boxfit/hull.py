"""
Convex hull of a 3D point set in compiled code: quickhull with adjacency, and a grid coreset.

The minimum box of a point set is the minimum box of its convex hull, so the box search
(:mod:`mvbb_ros.geometry.boxfit.search`) only looks at hull vertices, facet normals and edges.
:func:`quickhull_kernel` builds a triangulated hull with the neighbour of every facet across each
of its edges (Barber, Dobkin and Huhdanpaa's quickhull: repeatedly add the point farthest above a
facet, replace the facets it sees by a fan to their horizon, and hand the points those facets
held to the new ones).

Robustness comes from these rules rather than from exact arithmetic, because the box search only
needs a hull that is right to rounding (the final box is grown around every input point):

* the first tetrahedron is oriented by one decision, and counts as flat (rank 2) unless each of
  its facets has the opposite corner strictly below it;
* a point counts as outside a facet only when it lies more than ``tolerance`` (relative to the
  cloud's size) above the facet's plane; points within it are treated as inside and dropped;
* the facets a new point sees are found from the facet it lies above, through neighbours it lies
  above or within the tolerance of (so coplanar facets are replaced, not folded);
* before a point is added, those facets must meet the rest of the hull along one simple closed
  horizon, and every new facet must have a normal that faces away from the first tetrahedron's
  centroid. When rounding breaks any of these (nearly coplanar facets seen at a grazing angle),
  the point is dropped instead: the hull stays a closed, outward-facing triangulated surface.

So :func:`quickhull_kernel` never raises and never loops: every step adds or drops one point.
Inputs that span fewer than three dimensions (to the tolerance) return their affine rank instead
of a hull. What rounding can still do: on clouds thinner than about 1e-5 of their size with many
exactly coplanar points, points coplanar with sliver facets may be dropped although they stick
out (measured on fuzzed grids; :mod:`mvbb_ros.geometry.boxfit.fit` searches such clouds on their
plane as well).

:func:`column_extremes_kernel` is Barequet and Har-Peled's grid coreset: the highest and lowest
point of every column of a grid, along each axis. Large clouds are hulled on it (every point is
then within one column width of the coreset's hull, across the column).

Cost: O(N) for the coreset; quickhull O(N log H) expected for N points and H hull vertices
(measured in ``docs/performance.md``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from mvbb_ros.arrays import column_max, column_min, FloatArray, IndexArray
import numba as nb
import numpy as np
from numpy.typing import ArrayLike

#: Height above a facet (relative to the largest coordinate) below which a point is inside.
HULL_TOLERANCE = 1e-11
#: Status of :func:`quickhull_kernel` for a hull (the affine rank, 0 to 2, for flat input).
FULL_RANK = 3
#: Status of :func:`quickhull_kernel` when no consistent hull came out (never seen; a guard).
BROKEN = -1


class Hull(NamedTuple):
    """
    Triangulated convex hull, as plain arrays.

    :param status: 3 for a hull; 0, 1 or 2 when the points span only that many dimensions, -1
        when rounding left no consistent hull (a guard; all other fields are then empty).
    :param vertices: (H,) indices of the hull vertices in the input points.
    :param facets: (F, 3) hull-vertex indices (into ``vertices``) of each facet, counter-clockwise
        seen from outside.
    :param normals: (F, 3) outward unit facet normals.
    :param areas: (F,) facet areas.
    :param edges: (E, 2) hull-vertex indices of each edge, each edge once (E = 3 F / 2).
    :param edge_facets: (E, 2) the two facets that share each edge.
    """

    status: int
    vertices: IndexArray
    facets: IndexArray
    normals: FloatArray
    areas: FloatArray
    edges: IndexArray
    edge_facets: IndexArray


@nb.njit
def _grow_rows(array: np.ndarray, rows: int) -> np.ndarray:
    """Return a copy of a 2D array with room for `rows` rows (the first ones copied)."""
    out = np.empty((rows, array.shape[1]), dtype=array.dtype)
    for i in range(array.shape[0]):
        for k in range(array.shape[1]):
            out[i, k] = array[i, k]
    return out


@nb.njit
def _grow(array: np.ndarray, size: int) -> np.ndarray:
    """Return a copy of a 1D array with room for `size` entries (the first ones copied)."""
    out = np.empty(size, dtype=array.dtype)
    for i in range(array.shape[0]):
        out[i] = array[i]
    return out


@nb.njit
def _plane(points: np.ndarray, a: int, b: int, c: int, out: np.ndarray, row: int) -> bool:
    """
    Write the plane of triangle (a, b, c) into ``out[row]``: unit normal and offset.

    :return: False when the triangle has no normal (its vertices are collinear in floating
        point).
    """
    ux = points[b, 0] - points[a, 0]
    uy = points[b, 1] - points[a, 1]
    uz = points[b, 2] - points[a, 2]
    vx = points[c, 0] - points[a, 0]
    vy = points[c, 1] - points[a, 1]
    vz = points[c, 2] - points[a, 2]
    nx = uy * vz - uz * vy
    ny = uz * vx - ux * vz
    nz = ux * vy - uy * vx
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not norm > 1e-300:
        return False
    nx /= norm
    ny /= norm
    nz /= norm
    out[row, 0] = nx
    out[row, 1] = ny
    out[row, 2] = nz
    # The offset through the centroid rounds more evenly than through one corner.
    out[row, 3] = (
        nx * (points[a, 0] + points[b, 0] + points[c, 0])
        + ny * (points[a, 1] + points[b, 1] + points[c, 1])
        + nz * (points[a, 2] + points[b, 2] + points[c, 2])
    ) / 3.0
    return True


@nb.njit
def _height(points: np.ndarray, q: int, planes: np.ndarray, f: int) -> float:
    """Signed height of point q above the plane of facet f."""
    return (
        planes[f, 0] * points[q, 0]
        + planes[f, 1] * points[q, 1]
        + planes[f, 2] * points[q, 2]
        - planes[f, 3]
    )


@nb.njit
def _initial_simplex(points: np.ndarray, tolerance: float) -> tuple[int, int, int, int, int]:
    """
    Pick four points spanning a tetrahedron that is far from flat.

    :return: the rank found (3 when the tetrahedron exists) and its four point indices.
    """
    count = points.shape[0]
    low = np.zeros(3, dtype=np.int64)
    high = np.zeros(3, dtype=np.int64)
    for i in range(1, count):
        for k in range(3):
            if points[i, k] < points[low[k], k]:
                low[k] = i
            if points[i, k] > points[high[k], k]:
                high[k] = i
    # The two farthest apart among the six extremes.
    first = 0
    second = 0
    best = -1.0
    for s in range(6):
        i = low[s] if s < 3 else high[s - 3]
        for t in range(s + 1, 6):
            j = low[t] if t < 3 else high[t - 3]
            d = 0.0
            for k in range(3):
                d += (points[i, k] - points[j, k]) ** 2
            if d > best:
                best = d
                first = i
                second = j
    if not math.sqrt(best) > tolerance:
        return 0, first, first, first, first
    # The farthest from their line.
    dx = points[second, 0] - points[first, 0]
    dy = points[second, 1] - points[first, 1]
    dz = points[second, 2] - points[first, 2]
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    dx /= length
    dy /= length
    dz /= length
    third = first
    best = -1.0
    for i in range(count):
        if i == first or i == second:
            continue
        px = points[i, 0] - points[first, 0]
        py = points[i, 1] - points[first, 1]
        pz = points[i, 2] - points[first, 2]
        cx = py * dz - pz * dy
        cy = pz * dx - px * dz
        cz = px * dy - py * dx
        d = cx * cx + cy * cy + cz * cz
        if d > best:
            best = d
            third = i
    if not math.sqrt(best) > tolerance:
        return 1, first, second, second, second
    # The farthest from their plane.
    plane = np.empty((1, 4))
    if not _plane(points, first, second, third, plane, 0):
        return 1, first, second, second, second
    fourth = first
    best = -1.0
    for i in range(count):
        if i == first or i == second or i == third:
            continue
        d = abs(_height(points, i, plane, 0))
        if d > best:
            best = d
            fourth = i
    if not best > tolerance:
        return 2, first, second, third, third
    return 3, first, second, third, fourth


@nb.njit
def _empty_hull(status: int) -> tuple:
    return (
        status,
        np.zeros(0, dtype=np.int64),
        np.zeros((0, 3), dtype=np.int64),
        np.zeros((0, 3)),
        np.zeros(0),
        np.zeros((0, 2), dtype=np.int64),
        np.zeros((0, 2), dtype=np.int64),
    )


@nb.njit
def _unlink(head: np.ndarray, following: np.ndarray, facet: int, point: int) -> None:
    """Remove `point` from the outside list of `facet`."""
    previous = -1
    q = head[facet]
    while q >= 0:
        if q == point:
            if previous < 0:
                head[facet] = following[q]
            else:
                following[previous] = following[q]
            return
        previous = q
        q = following[q]


@nb.njit
def _scratch(capacity: int) -> tuple:
    """Return the work arrays of :func:`_expand` for `capacity` facets."""
    return (
        np.empty(capacity, dtype=np.int64),
        np.empty(3 * capacity, dtype=np.int64),
        np.empty(3 * capacity, dtype=np.int64),
        np.empty(3 * capacity, dtype=np.int64),
        np.empty((3 * capacity, 4)),
    )


@nb.njit
def _expand(
    points: np.ndarray,
    eps: float,
    inner_x: float,
    inner_y: float,
    inner_z: float,
    corners: np.ndarray,
    neighbours: np.ndarray,
    planes: np.ndarray,
    alive: np.ndarray,
    head: np.ndarray,
    farthest: np.ndarray,
    top: np.ndarray,
    tested: np.ndarray,
    seen: np.ndarray,
    following: np.ndarray,
    vertex_mark: np.ndarray,
    vertex_edge: np.ndarray,
    visible: np.ndarray,
    horizon_from: np.ndarray,
    horizon_to: np.ndarray,
    horizon_out: np.ndarray,
    new_planes: np.ndarray,
    facets: int,
    current: int,
    stamp: int,
) -> tuple[int, int, int, int]:
    """
    Add the farthest outside point of each facet in turn (quickhull's loop; see the module).

    Works in the arrays it is given and never replaces one (a rebound array costs numba a
    reference count update at every use in the loop, which was nearly half of a hull's time).
    The facet arrays hold ``corners.shape[0]`` facets, `visible` as many, the horizon arrays
    three times as many (a horizon edge is an edge of a seen facet).

    :return: the facet count, the facet to look at next and the visit stamp; then 0 when every
        outside set is empty, or the facet capacity to grow to before calling again.
    """
    while current < facets:
        f = current
        if not alive[f] or head[f] < 0:
            current += 1
            continue
        eye = farthest[f]
        stamp += 1
        # The facets the eye sees: a breadth-first search from f through visible neighbours.
        visible[0] = f
        seen_count = 1
        tested[f] = stamp
        seen[f] = stamp
        i = 0
        while i < seen_count:
            g = visible[i]
            i += 1
            for e in range(3):
                h = neighbours[g, e]
                if tested[h] != stamp:
                    tested[h] = stamp
                    if _height(points, eye, planes, h) > -eps:
                        seen[h] = stamp
                        visible[seen_count] = h
                        seen_count += 1
        # The horizon: edges of seen facets whose neighbour is not seen.
        edges = 0
        for i in range(seen_count):
            g = visible[i]
            for e in range(3):
                h = neighbours[g, e]
                if seen[h] != stamp:
                    horizon_from[edges] = corners[g, e]
                    horizon_to[edges] = corners[g, (e + 1) % 3]
                    horizon_out[edges] = h
                    edges += 1
        # It must be one simple cycle, and every new facet must have a normal.
        usable = edges >= 3
        if usable:
            for e in range(edges):
                v = horizon_from[e]
                if vertex_mark[v] == stamp:
                    usable = False
                    break
                vertex_mark[v] = stamp
                vertex_edge[v] = e
        if usable:
            e = 0
            for step in range(edges):
                v = horizon_to[e]
                if vertex_mark[v] != stamp:
                    usable = False
                    break
                e = vertex_edge[v]
                if e == 0 and step < edges - 1:
                    usable = False
                    break
            if e != 0:
                usable = False
        if usable:
            for e in range(edges):
                if not _plane(points, horizon_from[e], horizon_to[e], eye, new_planes, e):
                    usable = False
                    break
                # The tetrahedron's centroid is inside: a new facet must face away from it.
                height = (
                    new_planes[e, 0] * inner_x
                    + new_planes[e, 1] * inner_y
                    + new_planes[e, 2] * inner_z
                    - new_planes[e, 3]
                )
                if not height < 0.0:
                    usable = False
                    break
        if not usable:
            # Rounding made the seen region ragged: drop the eye (within rounding of the hull).
            _unlink(head, following, f, eye)
            farthest[f] = -1
            top[f] = 0.0
            q = head[f]
            while q >= 0:
                height = _height(points, q, planes, f)
                if farthest[f] < 0 or height > top[f]:
                    top[f] = height
                    farthest[f] = q
                q = following[q]
            continue
        if facets + edges > corners.shape[0]:
            # No room for the fan: the caller grows the arrays and calls again (this facet's
            # search is then repeated, with the same outcome).
            return facets, current, stamp, 2 * (facets + edges)
        # A fan of new facets from the horizon to the eye.
        for e in range(edges):
            n = facets + e
            u = horizon_from[e]
            v = horizon_to[e]
            corners[n, 0] = u
            corners[n, 1] = v
            corners[n, 2] = eye
            for k in range(4):
                planes[n, k] = new_planes[e, k]
            h = horizon_out[e]
            neighbours[n, 0] = h
            for k in range(3):
                if corners[h, k] == v and corners[h, (k + 1) % 3] == u:
                    neighbours[h, k] = n
            after = facets + vertex_edge[v]
            neighbours[n, 1] = after
            neighbours[after, 2] = n
            alive[n] = True
            head[n] = -1
            farthest[n] = -1
            top[n] = 0.0
            tested[n] = 0
            seen[n] = 0
        # Hand the seen facets' points to the new facets (or drop them: they are inside).
        for i in range(seen_count):
            g = visible[i]
            alive[g] = False
            q = head[g]
            head[g] = -1
            while q >= 0:
                following_q = following[q]
                if q != eye:
                    for e in range(edges):
                        n = facets + e
                        height = _height(points, q, planes, n)
                        if height > eps:
                            following[q] = head[n]
                            head[n] = q
                            if farthest[n] < 0 or height > top[n]:
                                top[n] = height
                                farthest[n] = q
                            break
                q = following_q
        facets += edges
    return facets, current, stamp, 0


@nb.njit(cache=True, nogil=True)
def quickhull_kernel(points: np.ndarray, tolerance: float) -> tuple:
    """
    Compute the convex hull of 3D points (see the module notes and :class:`Hull`).

    :param points: (N, 3) C-contiguous points, best centred and scaled to about unit size.
    :param tolerance: height above a facet, relative to the largest absolute coordinate, below
        which a point counts as inside.
    :return: the fields of :class:`Hull`, in order.
    """
    count = points.shape[0]
    if count == 0:
        return _empty_hull(0)
    size = 0.0
    for i in range(count):
        for k in range(3):
            size = max(size, abs(points[i, k]))
    eps = tolerance * size
    rank, a, b, c, d = _initial_simplex(points, eps)
    if rank < 3:
        return _empty_hull(rank)

    # Room for the facets made on the way, dead ones included (a hull of N points makes about
    # 9 sqrt(N), at most 15 sqrt(N) on the parts of the shared scans): growing the arrays
    # repeats a facet's search.
    capacity = max(64, 16 * int(math.sqrt(count)))
    corners = np.empty((capacity, 3), dtype=np.int64)
    neighbours = np.empty((capacity, 3), dtype=np.int64)
    planes = np.empty((capacity, 4))
    alive = np.zeros(capacity, dtype=np.bool_)
    head = np.full(capacity, -1, dtype=np.int64)
    farthest = np.full(capacity, -1, dtype=np.int64)
    top = np.zeros(capacity)
    tested = np.zeros(capacity, dtype=np.int64)
    seen = np.zeros(capacity, dtype=np.int64)
    following = np.full(count, -1, dtype=np.int64)
    vertex_mark = np.zeros(count, dtype=np.int64)
    vertex_edge = np.zeros(count, dtype=np.int64)

    # The tetrahedron, oriented once from the side of its base the fourth corner lies on (one
    # decision, so the four facets always fit together), each facet facing away from the
    # opposite corner.
    base = np.empty((1, 4))
    _plane(points, a, b, c, base, 0)
    if _height(points, d, base, 0) < 0.0:
        b, c = c, b
    tetra = np.array([a, c, b, a, b, d, b, c, d, c, a, d]).reshape(4, 3)
    for f in range(4):
        for k in range(3):
            corners[f, k] = tetra[f, k]
            neighbours[f, k] = -1
        if not _plane(points, corners[f, 0], corners[f, 1], corners[f, 2], planes, f):
            return _empty_hull(2)
        alive[f] = True
    # Each facet must have the opposite corner below it; a sliver too thin for its facets'
    # normals (rounding makes them disagree) counts as flat.
    opposite = np.array([d, c, a, b])
    for f in range(4):
        if not _height(points, opposite[f], planes, f) < 0.0:
            return _empty_hull(2)
    for f in range(4):
        for e in range(3):
            u = corners[f, e]
            v = corners[f, (e + 1) % 3]
            for g in range(4):
                if g != f:
                    for h in range(3):
                        if corners[g, h] == v and corners[g, (h + 1) % 3] == u:
                            neighbours[f, e] = g
    facets = 4
    inner_x = 0.25 * (points[a, 0] + points[b, 0] + points[c, 0] + points[d, 0])
    inner_y = 0.25 * (points[a, 1] + points[b, 1] + points[c, 1] + points[d, 1])
    inner_z = 0.25 * (points[a, 2] + points[b, 2] + points[c, 2] + points[d, 2])
    for q in range(count):
        if q == a or q == b or q == c or q == d:
            continue
        for f in range(4):
            height = _height(points, q, planes, f)
            if height > eps:
                following[q] = head[f]
                head[f] = q
                if height > top[f] or farthest[f] < 0:
                    top[f] = height
                    farthest[f] = q
                break

    scratch = _scratch(capacity)
    stamp = 0
    current = 0
    while True:
        visible, horizon_from, horizon_to, horizon_out, new_planes = scratch
        facets, current, stamp, needed = _expand(
            points,
            eps,
            inner_x,
            inner_y,
            inner_z,
            corners,
            neighbours,
            planes,
            alive,
            head,
            farthest,
            top,
            tested,
            seen,
            following,
            vertex_mark,
            vertex_edge,
            visible,
            horizon_from,
            horizon_to,
            horizon_out,
            new_planes,
            facets,
            current,
            stamp,
        )
        if needed == 0:
            break
        kept = corners.shape[0]
        corners = _grow_rows(corners, needed)
        neighbours = _grow_rows(neighbours, needed)
        planes = _grow_rows(planes, needed)
        alive = _grow(alive, needed)
        head = _grow(head, needed)
        farthest = _grow(farthest, needed)
        top = _grow(top, needed)
        tested = _grow(tested, needed)
        seen = _grow(seen, needed)
        for f in range(kept, needed):
            tested[f] = 0
            seen[f] = 0
        scratch = _scratch(needed)

    # Compact: live facets, their vertices, and each edge once with its two facets.
    facet_id = np.full(facets, -1, dtype=np.int64)
    live = 0
    for f in range(facets):
        if alive[f]:
            facet_id[f] = live
            live += 1
    # The construction keeps a closed surface; should anything have gone wrong all the same,
    # say so rather than return a broken one.
    for f in range(facets):
        if alive[f]:
            for k in range(3):
                g = neighbours[f, k]
                repeated = corners[f, k] == corners[f, (k + 1) % 3]
                if g < 0 or g >= facets or not alive[g] or repeated:
                    return _empty_hull(BROKEN)
    vertex_id = np.full(count, -1, dtype=np.int64)
    vertices = np.empty(count, dtype=np.int64)
    hull_size = 0
    out_facets = np.empty((live, 3), dtype=np.int64)
    normals = np.empty((live, 3))
    areas = np.empty(live)
    edge_ends = np.empty((live * 3 // 2, 2), dtype=np.int64)
    edge_facets = np.empty((live * 3 // 2, 2), dtype=np.int64)
    edge_count = 0
    for f in range(facets):
        if not alive[f]:
            continue
        n = facet_id[f]
        for k in range(3):
            v = corners[f, k]
            if vertex_id[v] < 0:
                vertex_id[v] = hull_size
                vertices[hull_size] = v
                hull_size += 1
            out_facets[n, k] = vertex_id[v]
            normals[n, k] = planes[f, k]
        p0 = corners[f, 0]
        p1 = corners[f, 1]
        p2 = corners[f, 2]
        ux = points[p1, 0] - points[p0, 0]
        uy = points[p1, 1] - points[p0, 1]
        uz = points[p1, 2] - points[p0, 2]
        vx = points[p2, 0] - points[p0, 0]
        vy = points[p2, 1] - points[p0, 1]
        vz = points[p2, 2] - points[p0, 2]
        areas[n] = 0.5 * math.sqrt(
            (uy * vz - uz * vy) ** 2 + (uz * vx - ux * vz) ** 2 + (ux * vy - uy * vx) ** 2
        )
    for f in range(facets):
        if not alive[f]:
            continue
        for k in range(3):
            g = facet_id[neighbours[f, k]]
            if facet_id[f] < g and edge_count < edge_ends.shape[0]:
                edge_ends[edge_count, 0] = vertex_id[corners[f, k]]
                edge_ends[edge_count, 1] = vertex_id[corners[f, (k + 1) % 3]]
                edge_facets[edge_count, 0] = facet_id[f]
                edge_facets[edge_count, 1] = g
                edge_count += 1
    return (
        FULL_RANK,
        vertices[:hull_size].copy(),
        out_facets,
        normals,
        areas,
        edge_ends[:edge_count].copy(),
        edge_facets[:edge_count].copy(),
    )


@nb.njit
def _column(value: float, low: float, span: float, factor: float, cells: int) -> int:
    """
    Return the grid cell (0 to cells - 1) of a coordinate in [low, low + span].

    The offset times ``factor`` (``cells / span``): a multiplication where a division was, the
    coreset's pass is a fifth quicker. That quotient overflows for subnormal spans (a cloud
    1e-313 thick), and inf times 0 is NaN, which has no integer: then the offset is divided by
    the span. The top of the range falls in the last cell; a zero span puts everything in cell 0.
    """
    if not span > 0.0:
        return 0
    if factor < math.inf:
        return min(int((value - low) * factor), cells - 1)
    return min(int((value - low) / span * cells), cells - 1)


@nb.njit(cache=True, nogil=True)
def column_extremes_kernel(
    points: np.ndarray, low: np.ndarray, high: np.ndarray, cells: int
) -> np.ndarray:
    """
    Return the indices of the highest and lowest point of every grid column, along each axis.

    For each coordinate axis the box [low, high] is cut into ``cells x cells`` columns across it
    (:func:`_column`); one point at each end of every non-empty column is kept (the first met on
    ties).

    :param points: (N, 3) points.
    :param low: (3,) lower corner of their bounding box.
    :param high: (3,) upper corner.
    :param cells: columns per side, >= 1.
    :return: the kept indices, each once, grouped by axis and column.
    """
    count = points.shape[0]
    columns = cells * cells
    spans = np.empty(3)
    factors = np.zeros(3)
    for k in range(3):
        spans[k] = high[k] - low[k]
        if spans[k] > 0.0:
            factors[k] = cells / spans[k]
    l0, l1, l2 = low[0], low[1], low[2]
    s0, s1, s2 = spans[0], spans[1], spans[2]
    f0, f1, f2 = factors[0], factors[1], factors[2]
    # Columns across x, then y, then z, one after the other in flat arrays.
    top = np.full(3 * columns, -np.inf)
    bottom = np.full(3 * columns, np.inf)
    top_index = np.full(3 * columns, -1, dtype=np.int64)
    bottom_index = np.full(3 * columns, -1, dtype=np.int64)
    for i in range(count):
        x = points[i, 0]
        y = points[i, 1]
        z = points[i, 2]
        bx = _column(x, l0, s0, f0, cells)
        by = _column(y, l1, s1, f1, cells)
        bz = _column(z, l2, s2, f2, cells)
        column = by * cells + bz
        if x > top[column]:
            top[column] = x
            top_index[column] = i
        if x < bottom[column]:
            bottom[column] = x
            bottom_index[column] = i
        column = columns + bz * cells + bx
        if y > top[column]:
            top[column] = y
            top_index[column] = i
        if y < bottom[column]:
            bottom[column] = y
            bottom_index[column] = i
        column = 2 * columns + bx * cells + by
        if z > top[column]:
            top[column] = z
            top_index[column] = i
        if z < bottom[column]:
            bottom[column] = z
            bottom_index[column] = i
    kept = np.zeros(count, dtype=np.bool_)
    out = np.empty(6 * columns, dtype=np.int64)
    size = 0
    for column in range(3 * columns):
        i = top_index[column]
        if i >= 0 and not kept[i]:
            kept[i] = True
            out[size] = i
            size += 1
        i = bottom_index[column]
        if i >= 0 and not kept[i]:
            kept[i] = True
            out[size] = i
            size += 1
    return out[:size].copy()


def convex_hull(points: ArrayLike, tolerance: float = HULL_TOLERANCE) -> Hull:
    """
    Return the convex hull of 3D points (:class:`Hull`; ``status`` < 3 for flat input).

    :param points: (N, 3) points, best centred and scaled to about unit size.
    :param tolerance: relative height above a facet below which a point counts as inside.
    :return: the hull; its vertices index `points`.
    """
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    return Hull(*quickhull_kernel(pts, float(tolerance)))


def column_extremes(points: ArrayLike, cells: int) -> IndexArray:
    """
    Return the indices of the grid coreset of `points` (:func:`column_extremes_kernel`).

    :param points: (N, 3) points, N >= 1.
    :param cells: columns per side, >= 1.
    :return: the kept indices, sorted.
    """
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    kept = column_extremes_kernel(pts, column_min(pts), column_max(pts), int(cells))
    return np.sort(kept)


def warm_up() -> None:
    """Run every kernel of this module once on tiny inputs (see :mod:`mvbb_ros.kernels`)."""
    corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * 3)).reshape(3, -1).T
    convex_hull(np.vstack([corners, 0.5 * corners]))
    column_extremes(corners, 2)
