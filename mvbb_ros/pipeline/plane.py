"""
The scene stage's plane fit: the plane that most points lie near, by RANSAC and least squares.

:func:`fit_plane` scores random triples of a fixed-seed sample of the points, each on that
sample (:func:`_best_plane`: a likely winner counted first, every other triple dropped as soon
as it cannot win), and refits the best triple's plane by least squares on its inliers among all
points, then on the refit's inliers, until a refit hardly turns it. With ``up`` known, only
planes within :data:`MAX_TILT_DEG` of it are tried. Pure numpy and numba: the fit is cheap on a
sample, and keeps Open3D out of the node's start (``docs/performance.md`` compares it with
Open3D's ``segment_plane``).
"""

from __future__ import annotations

import math
from typing import Any

from mvbb_ros.arrays import FloatArray, IndexArray
from mvbb_ros.geometry.views.cells import key_order
from numba import njit, types
import numpy as np

#: Random triples tried, and the most points they are scored on.
RANSAC_HYPOTHESES = 1024
RANSAC_SAMPLE = 2048
#: The sample is scored in blocks of this many points: a triple that can no longer beat the
#: best one stops being scored.
RANSAC_BLOCK = 256
#: The least-squares refits use at most this many inliers (evenly strided).
REFIT_POINTS = 16384
#: Most least-squares refits of the best triple's plane, each on the inliers of the one before,
#: until a refit turns the normal less than :data:`REFIT_TURN_DEG`: a triple that slices a table
#: at a slant across something standing on it (a plane 10-14 degrees off the table, 15 % of the
#: points within 1 cm of it) turns to the table itself in three rounds, and a table's own plane
#: stops after two.
REFIT_ROUNDS = 4
REFIT_TURN_DEG = 0.05
#: With an up direction, only planes tilted at most this far from it are tried, and a refitted
#: plane tilted further is no support (degrees): a table is level, and a face of a segmented
#: object that passes the other tests is usually not.
MAX_TILT_DEG = 15.0


def plane_through(points: FloatArray) -> tuple[FloatArray, float]:
    """Return the least-squares plane (unit normal, offset) of `points` (N >= 3)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    return _least_squares(pts, np.arange(len(pts), dtype=np.int64), len(pts))


def fit_plane(
    points: FloatArray,
    distance: float,
    up: FloatArray | None = None,
    seed: int = 0,
) -> tuple[FloatArray, float] | None:
    """
    Return the plane (unit normal, offset) that most of `points` lie within `distance` of.

    RANSAC on a fixed-seed sample (deterministic), refined by least squares on the inliers
    among all points, then on the refined plane's inliers until a refit hardly turns it (at most
    :data:`REFIT_ROUNDS` fits). With `up` (unit), only planes within :data:`MAX_TILT_DEG` of it
    count. None when no plane is found (fewer than 3 points, all collinear, or none near `up`).
    """
    count = len(points)
    if count < 3:
        return None
    rng = np.random.default_rng(seed)
    sample = points[rng.integers(0, count, min(count, RANSAC_SAMPLE))]
    corners = rng.integers(0, len(sample), (RANSAC_HYPOTHESES, 3))
    normals, lengths = _triple_normals(np.ascontiguousarray(sample, dtype=np.float64), corners)
    usable = lengths > 1e-12
    if up is not None:
        cosine = math.cos(math.radians(MAX_TILT_DEG))
        usable &= np.abs(normals @ up) >= cosine * lengths
    if not usable.any():
        return None
    normals = normals[usable] / lengths[usable, None]
    offsets = -np.einsum('ij,ij->i', normals, sample[corners[usable, 0]])
    columns = np.ascontiguousarray(sample.T, dtype=np.float64)
    best = _best_plane(columns, normals, offsets, distance, RANSAC_BLOCK)
    settled = math.cos(math.radians(REFIT_TURN_DEG))
    pts = np.ascontiguousarray(points, dtype=np.float64)
    return _refit(pts, normals[best], float(offsets[best]), distance, REFIT_ROUNDS, settled)


#: The points the plane kernels read (read-only arrays too: a caller's cloud is never copied).
_POINTS = types.Array(types.float64, 2, 'C', readonly=True)


@njit(
    types.Tuple((types.float64[::1], types.float64))(_POINTS, types.int64[::1], types.int64),
    cache=True,
    nogil=True,
)
def _least_squares(points: FloatArray, index: IndexArray, count: int) -> tuple[FloatArray, float]:
    """
    Return the least-squares plane (unit normal, offset) of the points `index[:count]`.

    At most :data:`REFIT_POINTS` of them, evenly strided: the centroid, the scatter matrix about
    it, and its eigenvector of the smallest eigenvalue.
    """
    step = max(1, count // REFIT_POINTS)
    used = 0
    cx = cy = cz = 0.0
    for k in range(0, count, step):
        i = index[k]
        cx += points[i, 0]
        cy += points[i, 1]
        cz += points[i, 2]
        used += 1
    cx, cy, cz = cx / used, cy / used, cz / used
    scatter = np.zeros((3, 3))
    for k in range(0, count, step):
        i = index[k]
        dx, dy, dz = points[i, 0] - cx, points[i, 1] - cy, points[i, 2] - cz
        scatter[0, 0] += dx * dx
        scatter[0, 1] += dx * dy
        scatter[0, 2] += dx * dz
        scatter[1, 1] += dy * dy
        scatter[1, 2] += dy * dz
        scatter[2, 2] += dz * dz
    scatter[1, 0], scatter[2, 0], scatter[2, 1] = scatter[0, 1], scatter[0, 2], scatter[1, 2]
    _, vectors = np.linalg.eigh(scatter)
    normal = np.ascontiguousarray(vectors[:, 0])
    return normal, -(normal[0] * cx + normal[1] * cy + normal[2] * cz)


@njit(
    types.Tuple((types.float64[::1], types.float64))(
        _POINTS, types.float64[::1], types.float64, types.float64, types.int64, types.float64
    ),
    cache=True,
    nogil=True,
)
def _refit(
    points: FloatArray,
    normal: FloatArray,
    offset: float,
    distance: float,
    rounds: int,
    settled: float,
) -> tuple[FloatArray, float]:
    """
    Return the plane refitted on its inliers among `points`, round after round.

    Each round fits :func:`_least_squares` to the points within `distance` of the plane before
    it; at most `rounds` rounds, and none more once a refit turns the normal by less than the
    angle whose cosine is `settled` (or fewer than 3 points are near).
    """
    near = np.empty(points.shape[0], dtype=np.int64)
    for _ in range(rounds):
        a, b, c = normal[0], normal[1], normal[2]
        count = 0
        for i in range(points.shape[0]):
            if abs(a * points[i, 0] + b * points[i, 1] + c * points[i, 2] + offset) <= distance:
                near[count] = i
                count += 1
        if count < 3:
            break
        normal, offset = _least_squares(points, near, count)
        if abs(normal[0] * a + normal[1] * b + normal[2] * c) >= settled:
            break
    return normal, offset


@njit(
    'Tuple((float64[:, ::1], float64[::1]))(float64[:, ::1], int64[:, ::1])',
    cache=True,
    nogil=True,
)
def _triple_normals(points: FloatArray, corners: IndexArray) -> tuple[FloatArray, FloatArray]:
    """
    Return the normals (not unit) of the triangles of `points` at `corners` (H, 3), and lengths.

    The same floats as numpy's: (b - a) x (c - a) as :func:`mvbb_ros.arrays.cross`, and the
    root of the squares added x, y, z (``np.linalg.norm(axis=1)``).
    """
    normals = np.empty((corners.shape[0], 3))
    lengths = np.empty(corners.shape[0])
    for h in range(corners.shape[0]):
        a, b, c = corners[h, 0], corners[h, 1], corners[h, 2]
        u0, u1, u2 = (
            points[b, 0] - points[a, 0],
            points[b, 1] - points[a, 1],
            points[b, 2] - points[a, 2],
        )
        v0, v1, v2 = (
            points[c, 0] - points[a, 0],
            points[c, 1] - points[a, 1],
            points[c, 2] - points[a, 2],
        )
        n0, n1, n2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
        normals[h, 0], normals[h, 1], normals[h, 2] = n0, n1, n2
        lengths[h] = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    return normals, lengths


@njit
def _near(
    xs: Any, ys: Any, zs: Any, plane: Any, offset: float, distance: float, start: int, stop: int
) -> int:
    """Return how many of the points start:stop lie within `distance` of the plane."""
    a, b, c = plane[0], plane[1], plane[2]
    # Slices: indices from 0, which the compiler knows are not negative (the loop vectorises).
    x, y, z = xs[start:stop], ys[start:stop], zs[start:stop]
    near = 0
    for i in range(x.shape[0]):
        if abs(a * x[i] + b * y[i] + c * z[i] + offset) <= distance:
            near += 1
    return near


@njit(
    'int64(float64[:, ::1], float64[:, ::1], float64[::1], float64, int64)',
    cache=True,
    nogil=True,
)
def _best_plane(
    columns: FloatArray, normals: FloatArray, offsets: FloatArray, distance: float, block: int
) -> int:
    """
    Return the first of the planes (normal, offset) with the most points within `distance`.

    The answer of counting every plane's points (``argmax``), cheaper: a likely winner is found
    first (Nister's preemptive scoring: every plane on a block of points, the better half on
    the next block too, and so on) and counted whole; then every other plane is counted block
    by block, and dropped as soon as the points left cannot make it win.

    :param columns: (3, N) the points' x, y and z rows (contiguous: the count vectorises).
    """
    xs, ys, zs = columns[0], columns[1], columns[2]
    count = xs.shape[0]
    planes = normals.shape[0]
    alive = np.arange(planes)
    # Each plane's count on the first `scored` points.
    scores = np.zeros(planes, dtype=np.int64)
    scored = np.zeros(planes, dtype=np.int64)
    start = 0
    while alive.shape[0] > 1 and start < count:
        stop = min(start + block, count)
        for k in range(alive.shape[0]):
            h = alive[k]
            scores[h] += _near(xs, ys, zs, normals[h], offsets[h], distance, start, stop)
            scored[h] = stop
        start = stop
        order = key_order(-scores[alive])  # not numba's sort: see mvbb_ros.geometry.views.cells
        alive = alive[order[: max(1, alive.shape[0] // 2)]]
    best = alive[0]
    top = scores[best] + _near(
        xs, ys, zs, normals[best], offsets[best], distance, scored[best], count
    )
    for h in range(planes):
        if h == best:
            continue
        # To win: more points than the best, or as many and an earlier index.
        need = top if h < best else top + 1
        near = scores[h]
        start = scored[h]
        while start < count and near + count - start >= need:
            stop = min(start + block, count)
            near += _near(xs, ys, zs, normals[h], offsets[h], distance, start, stop)
            start = stop
        if start == count and near >= need:
            best, top = h, near
    return int(best)


def warm_up() -> None:
    """Run every kernel of this module once (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5)), -1).reshape(-1, 2)
    flat = np.column_stack([grid, np.zeros(len(grid))])
    fit_plane(flat, 0.01)
