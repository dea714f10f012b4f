"""
The best box of a hull about one axis: its silhouette and the rotating calipers (numba).

For a fixed unit axis ``a``, the box of least volume with ``a`` as one of its axes is the hull's
extent along ``a`` times the minimum-area rectangle of its projection along ``a``
(:mod:`mvbb_ros.geometry.boxfit.rectangle`). The outline of that projection is the hull's
*silhouette*: the edges between facets facing along ``a`` and the others, which form one loop.
:func:`rotate_about` finds those edges, links them into the loop, walks it (the outline in
counter-clockwise order, no sort), keeps its convex vertices in one Graham pass and runs the
calipers on them; should rounding break the loop, the 2D hull of every projected vertex is
used instead. A large hull's edges are binned by their facets' normals (:func:`new_work`, once
per hull), and a turn looks only at the cells whose cone of normals crosses the plane across
``a``: about 30 % of the edges on the shared models. :mod:`mvbb_ros.geometry.boxfit.search`
turns a few hundred axes per fit.
"""

from __future__ import annotations

import math

from mvbb_ros.geometry.boxfit.rectangle import calipers_into, hull_2d_kernel
import numba as nb
import numpy as np

#: |unit normal . unit axis| below which a facet counts as seen edge-on along the axis.
SILHOUETTE_TOLERANCE = 1e-9
#: Cube-map cells per face side for binning the hull's edges by their facets' normals
#: (:func:`new_work`): an axis's silhouette edges lie in the cells whose cone of normals
#: crosses the plane across the axis, a band of the 6 x 4 x 4 cells; the others are skipped.
SILHOUETTE_CELLS = 4
#: Edges whose two facets' normals are further apart than this (radians) are kept in a list of
#: their own, checked for every axis: in a cell they would widen its cone.
WIDE_EDGE = math.radians(30.0)
#: Radians added to a cell's cone: far above the rounding of the normals, the axis and the
#: cone itself (about 1e-8), and its sine (1e-6) far above :data:`SILHOUETTE_TOLERANCE`.
CONE_SLACK = 1e-6
#: Edge counts from which hulls are binned; smaller ones keep every edge in one list, whose
#: check costs less than building the cells.
BINNED_EDGES_MIN = 1024


@nb.njit
def cube_cell(x: float, y: float, z: float, cells: int) -> int:
    """
    Return the cube-map cell of a non-zero direction: 6 faces of `cells` x `cells` cells.

    The face is the dominant coordinate's axis and sign; the cell, the other two coordinates
    divided by the dominant one's size, on a `cells` x `cells` grid of [-1, 1]^2.
    """
    dominant = 0
    major = x
    if abs(y) > abs(x):
        dominant = 1
        major = y
    if abs(z) > abs(major):
        dominant = 2
        major = z
    face = 2 * dominant + (1 if major < 0.0 else 0)
    if dominant == 0:
        first, second = y, z
    elif dominant == 1:
        first, second = z, x
    else:
        first, second = x, y
    first /= abs(major)
    second /= abs(major)
    i = min(max(int((first + 1.0) * (cells / 2.0)), 0), cells - 1)
    j = min(max(int((second + 1.0) * (cells / 2.0)), 0), cells - 1)
    return (face * cells + i) * cells + j


@nb.njit
def _convex_loop(x: np.ndarray, y: np.ndarray, size: int, polygon: np.ndarray) -> int:
    """
    Keep the convex vertices of a counter-clockwise loop that is convex up to rounding.

    One Graham pass from the lowest-leftmost vertex (surely convex) drops the vertices that do
    not turn left (collinear runs, rounding dents). O(size).

    :param x: x coordinates of the loop's points, in order.
    :param y: y coordinates.
    :param size: number of points.
    :param polygon: receives the kept positions, counter-clockwise.
    :return: the number of kept vertices.
    """
    start = 0
    for s in range(1, size):
        if x[s] < x[start] or (x[s] == x[start] and y[s] < y[start]):
            start = s
    kept = 0
    for step in range(size + 1):
        i = start + step
        if i >= size:
            i -= size
        while kept >= 2:
            o = polygon[kept - 2]
            a = polygon[kept - 1]
            turn = (x[a] - x[o]) * (y[i] - y[o]) - (y[a] - y[o]) * (x[i] - x[o])
            if turn > 0.0:
                break
            kept -= 1
        polygon[kept] = i
        kept += 1
    # The last kept vertex is the start again.
    return kept - 1


@nb.njit
def _link(
    tail: int, head: int, following: np.ndarray, silhouette: np.ndarray, size: int, simple: bool
) -> tuple:
    """Link a silhouette edge into the loop; a second edge out of one vertex is not simple."""
    if following[tail] >= 0:
        return size, False
    following[tail] = head
    silhouette[size] = tail
    return size + 1, simple


@nb.njit
def rotate_about(
    vertices: np.ndarray,
    work: tuple,
    ax: float,
    ay: float,
    az: float,
    frame: np.ndarray,
) -> float:
    """
    Find the minimum-volume box of the hull that has unit axis (ax, ay, az).

    The rotation about the axis is the minimum-area rectangle of the hull's projection, whose
    outline is the projection of the silhouette's vertices.

    :param work: the hull's edges and reusable arrays (:func:`new_work`).
    :param frame: (3, 3) receives the box frame; its columns are the axis, the rectangle's first
        side and their cross product.
    :return: the box volume (of the hull vertices).
    """
    following, silhouette, px, py, order, polygon, scratch, places = work[:8]
    side, normals, edges, edge_facets = work[8:12]
    cell_start, edge_vertices, edge_normals, cell_centres, cell_limits = work[12:]
    count = vertices.shape[0]
    low = np.inf
    high = -np.inf
    for i in range(count):
        h = ax * vertices[i, 0] + ay * vertices[i, 1] + az * vertices[i, 2]
        low = min(low, h)
        high = max(high, h)
    # A basis of the plane across the axis, from the coordinate axis most across it.
    if abs(ax) <= abs(ay) and abs(ax) <= abs(az):
        ux, uy, uz = 0.0, az, -ay
    elif abs(ay) <= abs(az):
        ux, uy, uz = -az, 0.0, ax
    else:
        ux, uy, uz = ay, -ax, 0.0
    norm = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux /= norm
    uy /= norm
    uz /= norm
    vx = ay * uz - az * uy
    vy = az * ux - ax * uz
    vz = ax * uy - ay * ux
    # Silhouette: the edges between facets facing forward (n . a > tolerance) and the others,
    # each directed as in its forward facet, form one loop that projects counter-clockwise
    # onto the outline (seen from +a, with (u, v, a) right-handed).
    size = 0
    simple = True
    if cell_limits.shape[0] == 0:
        # A small hull: every facet classed, every edge looked at.
        for f in range(normals.shape[0]):
            d = ax * normals[f, 0] + ay * normals[f, 1] + az * normals[f, 2]
            side[f] = d > SILHOUETTE_TOLERANCE
        for e in range(edges.shape[0]):
            forward = side[edge_facets[e, 0]]
            if forward != side[edge_facets[e, 1]]:
                tail = edges[e, 0] if forward else edges[e, 1]
                head = edges[e, 1] if forward else edges[e, 0]
                size, simple = _link(tail, head, following, silhouette, size, simple)
    for c in range(cell_limits.shape[0]):
        # A binned hull: a cell whose cone of normals lies wholly on one side of the plane
        # across the axis holds no silhouette edge. The same sums as the facets' classes above.
        dot = ax * cell_centres[c, 0] + ay * cell_centres[c, 1] + az * cell_centres[c, 2]
        if abs(dot) > cell_limits[c]:
            continue
        for e in range(cell_start[c], cell_start[c + 1]):
            forward = (
                ax * edge_normals[e, 0] + ay * edge_normals[e, 1] + az * edge_normals[e, 2]
                > SILHOUETTE_TOLERANCE
            )
            back = ax * edge_normals[e, 3] + ay * edge_normals[e, 4] + az * edge_normals[e, 5]
            if forward != (back > SILHOUETTE_TOLERANCE):
                tail = edge_vertices[e, 0] if forward else edge_vertices[e, 1]
                head = edge_vertices[e, 1] if forward else edge_vertices[e, 0]
                size, simple = _link(tail, head, following, silhouette, size, simple)
    corners = 0
    if simple and size >= 3:
        # Walk the loop; it must visit every silhouette edge once.
        v = silhouette[0]
        for s in range(size):
            px[s] = ux * vertices[v, 0] + uy * vertices[v, 1] + uz * vertices[v, 2]
            py[s] = vx * vertices[v, 0] + vy * vertices[v, 1] + vz * vertices[v, 2]
            v = following[v]
            if v < 0 or (v == silhouette[0] and s < size - 1):
                simple = False
                break
        if simple and v == silhouette[0]:
            corners = _convex_loop(px, py, size, polygon)
    for s in range(size):
        following[silhouette[s]] = -1
    if corners < 3:
        # Rounding made the silhouette ragged: the 2D hull of every projected vertex.
        size = count
        for s in range(count):
            px[s] = ux * vertices[s, 0] + uy * vertices[s, 1] + uz * vertices[s, 2]
            py[s] = vx * vertices[s, 0] + vy * vertices[s, 1] + vz * vertices[s, 2]
            order[s] = s
        corners = hull_2d_kernel(px, py, order, size, polygon)
    area, dx, dy = calipers_into(px, py, polygon, corners, scratch, places)
    sx = dx * ux + dy * vx
    sy = dx * uy + dy * vy
    sz = dx * uz + dy * vz
    norm = math.sqrt(sx * sx + sy * sy + sz * sz)
    sx /= norm
    sy /= norm
    sz /= norm
    frame[0, 0] = ax
    frame[1, 0] = ay
    frame[2, 0] = az
    frame[0, 1] = sx
    frame[1, 1] = sy
    frame[2, 1] = sz
    frame[0, 2] = ay * sz - az * sy
    frame[1, 2] = az * sx - ax * sz
    frame[2, 2] = ax * sy - ay * sx
    return (high - low) * area


@nb.njit
def new_work(
    vertices: np.ndarray, normals: np.ndarray, edges: np.ndarray, edge_facets: np.ndarray
) -> tuple:
    """
    Return a hull's edges for :func:`rotate_about`, binned when it is large, and its buffers.

    A hull of :data:`BINNED_EDGES_MIN` edges or more has each edge (its two vertices, then the
    normals of the facets on its left and right) in the cube-map cell of the sum of its
    normals (:data:`SILHOUETTE_CELLS`), or in a last list when they are more than
    :data:`WIDE_EDGE` apart. A cell keeps the centre of its normals' cone and the sine of its
    half-angle plus :data:`CONE_SLACK`: when ``|centre . a|`` is above it, every normal of the
    cell is on one side of the plane across ``a`` by more than the silhouette's tolerance, so
    none of its edges is on the silhouette. The last list is always checked; empty cells have
    a limit of -1 (skipped). A smaller hull has no cells: its facets are classed and every edge
    looked at, as binning would cost more than it saves.

    :return: (following, silhouette, x, y, order, polygon, calipers' scratch and places, side,
        normals, edges, edge_facets, cell_start, edge_vertices, edge_normals, cell_centres,
        cell_limits); cell c holds the edges ``cell_start[c]:cell_start[c + 1]`` of
        ``edge_vertices`` and ``edge_normals``.
    """
    vertex_count = vertices.shape[0]
    buffers = (
        np.full(vertex_count, -1, dtype=np.int64),
        np.empty(vertex_count, dtype=np.int64),
        np.empty(vertex_count),
        np.empty(vertex_count),
        np.empty(vertex_count, dtype=np.int64),
        np.empty(vertex_count + 1, dtype=np.int64),
        np.empty((4, max(vertex_count, 1) + 1)),
        np.empty((3, max(vertex_count, 1) + 1), dtype=np.uint64),
    )
    edge_count = edges.shape[0]
    if edge_count < BINNED_EDGES_MIN:
        return buffers + (
            np.zeros(normals.shape[0], dtype=np.bool_),
            normals,
            edges,
            edge_facets,
            np.zeros(1, dtype=np.int64),
            np.zeros((0, 2), dtype=np.int64),
            np.zeros((0, 6)),
            np.zeros((0, 3)),
            np.zeros(0),
        )
    cell_count = 6 * SILHOUETTE_CELLS * SILHOUETTE_CELLS + 1
    last = cell_count - 1
    cell_of = np.full(edge_count, last, dtype=np.int64)
    wide = math.cos(WIDE_EDGE)
    for e in range(edge_count):
        f = edge_facets[e, 0]
        g = edge_facets[e, 1]
        cosine = (
            normals[f, 0] * normals[g, 0]
            + normals[f, 1] * normals[g, 1]
            + normals[f, 2] * normals[g, 2]
        )
        if cosine >= wide:
            cell_of[e] = cube_cell(
                normals[f, 0] + normals[g, 0],
                normals[f, 1] + normals[g, 1],
                normals[f, 2] + normals[g, 2],
                SILHOUETTE_CELLS,
            )
    # A counting sort of the edges by cell (stable).
    cell_start = np.zeros(cell_count + 1, dtype=np.int64)
    for e in range(edge_count):
        cell_start[cell_of[e] + 1] += 1
    for c in range(cell_count):
        cell_start[c + 1] += cell_start[c]
    filled = cell_start[:-1].copy()
    edge_vertices = np.empty((edge_count, 2), dtype=np.int64)
    edge_normals = np.empty((edge_count, 6))
    for e in range(edge_count):
        row = filled[cell_of[e]]
        filled[cell_of[e]] += 1
        edge_vertices[row, 0] = edges[e, 0]
        edge_vertices[row, 1] = edges[e, 1]
        for k in range(3):
            edge_normals[row, k] = normals[edge_facets[e, 0], k]
            edge_normals[row, 3 + k] = normals[edge_facets[e, 1], k]
    cell_centres = np.zeros((cell_count, 3))
    cell_limits = np.full(cell_count, -1.0)
    cell_limits[last] = 2.0
    for c in range(last):
        if cell_start[c] == cell_start[c + 1]:
            continue
        cx = cy = cz = 0.0
        for e in range(cell_start[c], cell_start[c + 1]):
            cx += edge_normals[e, 0] + edge_normals[e, 3]
            cy += edge_normals[e, 1] + edge_normals[e, 4]
            cz += edge_normals[e, 2] + edge_normals[e, 5]
        norm = math.sqrt(cx * cx + cy * cy + cz * cz)
        cx /= norm
        cy /= norm
        cz /= norm
        lowest = 1.0
        for e in range(cell_start[c], cell_start[c + 1]):
            for k in (0, 3):
                cosine = cx * edge_normals[e, k] + cy * edge_normals[e, k + 1]
                lowest = min(lowest, cosine + cz * edge_normals[e, k + 2])
        half_angle = math.acos(max(-1.0, lowest)) + CONE_SLACK
        cell_centres[c, 0] = cx
        cell_centres[c, 1] = cy
        cell_centres[c, 2] = cz
        cell_limits[c] = math.sin(half_angle) if half_angle < 0.5 * math.pi else 2.0
    return buffers + (
        np.zeros(0, dtype=np.bool_),
        normals,
        edges,
        edge_facets,
        cell_start,
        edge_vertices,
        edge_normals,
        cell_centres,
        cell_limits,
    )


@nb.njit
def frame_volume(vertices: np.ndarray, frame: np.ndarray) -> float:
    """Return the volume of the box of the vertices with the frame's axes (columns)."""
    volume = 1.0
    for k in range(3):
        low = np.inf
        high = -np.inf
        for i in range(vertices.shape[0]):
            h = frame[0, k] * vertices[i, 0] + frame[1, k] * vertices[i, 1]
            h += frame[2, k] * vertices[i, 2]
            low = min(low, h)
            high = max(high, h)
        volume *= high - low
    return volume
