"""
Every point against a searched frame (numba): the leak check and repair, and the final box.

The orientation search (:mod:`mvbb_ros.geometry.boxfit.search`) sees a hull only: of every point,
or of a large cloud's grid coreset (:func:`mvbb_ros.geometry.boxfit.hull.column_extremes_kernel`).
:mod:`mvbb_ros.geometry.boxfit.fit` then looks at every point again, one pass per frame:

* :func:`add_leaks`: the frame searched on a coreset's hull is re-checked against every point.
  The coreset keeps each column's extremes along three axes only, so in a tilted frame points
  between them can stick out; those out by more than :data:`LEAK_TOLERANCE` join the hull, and
  the frame is walked again on the new hull, at most :data:`LEAK_ROUNDS` times.
* :func:`final_box`: each searched frame's box grown around every point; the smallest of these,
  the PCA box and the axis-aligned box is the fit, so it always encloses every point. Extents
  below :data:`ZERO_EXTENT` of the largest are reported as exactly 0.
"""

from __future__ import annotations

from mvbb_ros.geometry.boxfit import hull as hull_module
from mvbb_ros.geometry.boxfit.frames import matmul
from mvbb_ros.geometry.boxfit.search import settle
from mvbb_ros.geometry.boxfit.turn import frame_volume, new_work
import numba as nb
import numpy as np

#: Relative margin (of the box's extent) by which a point may stick out of the box of a
#: coreset's hull before it joins the hull (:func:`add_leaks`).
LEAK_TOLERANCE = 1e-3
#: Most rounds of :func:`add_leaks`.
LEAK_ROUNDS = 3
#: Relative extent (of the largest) below which a box extent is reported as 0.
ZERO_EXTENT = 1e-12


@nb.njit
def _leaks(local: np.ndarray, vertices: np.ndarray, frame: np.ndarray) -> tuple:
    """
    Return the points that stick out of the box of `vertices` in `frame` by more than a margin.

    The margin is :data:`LEAK_TOLERANCE` of the box's extent along each axis. One pass over
    the points, which also gives their box in the frame.

    :return: the indices of the points sticking out, and the box of every point in the frame
        (2, 3): lower corner, upper corner.
    """
    low = np.empty(3)
    high = np.empty(3)
    for k in range(3):
        low[k] = np.inf
        high[k] = -np.inf
        for i in range(vertices.shape[0]):
            h = frame[0, k] * vertices[i, 0] + frame[1, k] * vertices[i, 1]
            h += frame[2, k] * vertices[i, 2]
            low[k] = min(low[k], h)
            high[k] = max(high[k], h)
        margin = LEAK_TOLERANCE * (high[k] - low[k])
        low[k] -= margin
        high[k] += margin
    f00, f01, f02 = frame[0, 0], frame[0, 1], frame[0, 2]
    f10, f11, f12 = frame[1, 0], frame[1, 1], frame[1, 2]
    f20, f21, f22 = frame[2, 0], frame[2, 1], frame[2, 2]
    out = np.empty(local.shape[0], dtype=np.int64)
    size = 0
    l0 = l1 = l2 = np.inf
    h0 = h1 = h2 = -np.inf
    for i in range(local.shape[0]):
        x = local[i, 0]
        y = local[i, 1]
        z = local[i, 2]
        v0 = x * f00 + y * f10 + z * f20
        v1 = x * f01 + y * f11 + z * f21
        v2 = x * f02 + y * f12 + z * f22
        l0, h0 = min(l0, v0), max(h0, v0)
        l1, h1 = min(l1, v1), max(h1, v1)
        l2, h2 = min(l2, v2), max(h2, v2)
        if v0 < low[0] or v0 > high[0] or v1 < low[1] or v1 > high[1]:
            out[size] = i
            size += 1
        elif v2 < low[2] or v2 > high[2]:
            out[size] = i
            size += 1
    bounds = np.empty((2, 3))
    bounds[0, 0], bounds[0, 1], bounds[0, 2] = l0, l1, l2
    bounds[1, 0], bounds[1, 1], bounds[1, 2] = h0, h1, h2
    return out[:size], bounds


@nb.njit
def add_leaks(
    local: np.ndarray,
    vertices: np.ndarray,
    frame: np.ndarray,
    volume: float,
    hull_tolerance: float,
    max_rounds: int,
    walk_steps: int,
    walk_step: float,
    edge_pivots: int,
) -> tuple:
    """
    Re-check a frame searched on a coreset's hull against every point, and re-settle it.

    The points outside the coreset hull's box in the frame (by more than
    :data:`LEAK_TOLERANCE`) join the hull's vertices, which are hulled again, and the frame is
    walked and polished on the new hull (:func:`mvbb_ros.geometry.boxfit.search.settle`); up to
    :data:`LEAK_ROUNDS` times, until no point leaks. The coreset keeps each column's extremes
    along three axes only: in a tilted frame, points between the columns' extremes can stick
    out (a percent of volume on dense range scans with 14 x 14 columns).

    :return: the frame (3, 3), the box of every point in it (2, 3) and whether that box is
        known (the last check found no leak; otherwise the box is zeros).
    """
    for _ in range(LEAK_ROUNDS):
        leaked, bounds = _leaks(local, vertices, frame)
        if leaked.shape[0] == 0:
            return frame, bounds, True
        merged = np.empty((vertices.shape[0] + leaked.shape[0], 3))
        for i in range(vertices.shape[0]):
            for k in range(3):
                merged[i, k] = vertices[i, k]
        for j in range(leaked.shape[0]):
            for k in range(3):
                merged[vertices.shape[0] + j, k] = local[leaked[j], k]
        status, hull_ids, _, normals, _, edges, edge_facets = hull_module.quickhull_kernel(
            merged, hull_tolerance
        )
        if status != hull_module.FULL_RANK:
            break
        vertices = np.empty((hull_ids.shape[0], 3))
        for i in range(hull_ids.shape[0]):
            for k in range(3):
                vertices[i, k] = merged[hull_ids[i], k]
        volume = frame_volume(vertices, frame)
        # The frame is already the search's best: a leak moves it a little, the first axis's
        # walk follows (the later axes' walks, for other basins, were done on the coreset).
        volume, frame = settle(
            vertices,
            new_work(vertices, normals, edges, edge_facets),
            frame,
            volume,
            max_rounds,
            walk_steps,
            walk_step,
            1,
            edge_pivots,
        )
    return frame, np.zeros((2, 3)), False


@nb.njit
def final_box(
    local: np.ndarray,
    origin: np.ndarray,
    scale: float,
    pca: np.ndarray,
    frames: np.ndarray,
    known: np.ndarray,
    known_bounds: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    local_low: np.ndarray,
    local_high: np.ndarray,
) -> tuple:
    """
    Grow each frame's box around every point; return the smallest, or the PCA or axis-aligned box.

    :param local: (N, 3) the points in the PCA frame, centred on `origin`, divided by `scale`.
    :param frames: (K, 3, 3) searched frames in those coordinates.
    :param known: (>= K,) whether the box of every point in frame j is already measured,
        ``known_bounds[j]`` (lower corner, upper corner): that frame's pass is skipped.
    :param low: (3,) the points' lower corner (world), ``high`` the upper one.
    :param local_low: (3,) lower corner in the PCA frame, ``local_high`` the upper one.
    :return: centre, rotation and extents, in world units.
    """
    count = frames.shape[0]
    box_low = np.full((count, 3), np.inf)
    box_high = np.full((count, 3), -np.inf)
    for j in range(count):  # one frame at a time, its bounds in scalars (registers)
        if known[j]:
            for k in range(3):
                box_low[j, k] = known_bounds[j, 0, k]
                box_high[j, k] = known_bounds[j, 1, k]
            continue
        f00, f01, f02 = frames[j, 0, 0], frames[j, 0, 1], frames[j, 0, 2]
        f10, f11, f12 = frames[j, 1, 0], frames[j, 1, 1], frames[j, 1, 2]
        f20, f21, f22 = frames[j, 2, 0], frames[j, 2, 1], frames[j, 2, 2]
        l0 = l1 = l2 = np.inf
        h0 = h1 = h2 = -np.inf
        for i in range(local.shape[0]):
            x = local[i, 0]
            y = local[i, 1]
            z = local[i, 2]
            v0 = x * f00 + y * f10 + z * f20
            v1 = x * f01 + y * f11 + z * f21
            v2 = x * f02 + y * f12 + z * f22
            l0, h0 = min(l0, v0), max(h0, v0)
            l1, h1 = min(l1, v1), max(h1, v1)
            l2, h2 = min(l2, v2), max(h2, v2)
        box_low[j, 0], box_low[j, 1], box_low[j, 2] = l0, l1, l2
        box_high[j, 0], box_high[j, 1], box_high[j, 2] = h0, h1, h2
    # Volumes compared at unit scale (world volumes of huge clouds overflow).
    best = -1
    volume = 1.0
    aabb_volume = 1.0
    for k in range(3):
        volume *= local_high[k] - local_low[k]
        aabb_volume *= (high[k] - low[k]) / scale
    for j in range(count):
        found = 1.0
        for k in range(3):
            found *= box_high[j, k] - box_low[j, k]
        if found <= volume:
            volume = found
            best = j
    extents = np.empty(3)
    center = np.empty(3)
    if aabb_volume < volume:
        rotation = np.eye(3)
        for k in range(3):
            extents[k] = high[k] - low[k]
            center[k] = origin[k]
    else:
        side_low = np.empty(3)
        side_high = np.empty(3)
        if best < 0:
            rotation = pca.copy()
            for k in range(3):
                side_low[k] = local_low[k]
                side_high[k] = local_high[k]
        else:
            rotation = matmul(pca, frames[best])
            for k in range(3):
                side_low[k] = box_low[best, k]
                side_high[k] = box_high[best, k]
        for k in range(3):
            extents[k] = (side_high[k] - side_low[k]) * scale
        for j in range(3):
            offset = 0.0
            for k in range(3):
                offset += rotation[j, k] * 0.5 * (side_low[k] + side_high[k])
            center[j] = origin[j] + scale * offset
    biggest = max(extents[0], extents[1], extents[2])
    for k in range(3):
        if extents[k] <= ZERO_EXTENT * biggest:
            extents[k] = 0.0
    return center, rotation, extents
