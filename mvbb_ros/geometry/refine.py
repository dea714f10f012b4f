"""
Grasps checked, refined and scored on the points: the paper's face hypotheses as seeds.

The paper's hypotheses (:func:`~mvbb_ros.geometry.grasps.grasp_hypotheses`) approach a box
face centre; on a curved or partly seen object that centre rarely gives two antipodal contacts.
:func:`refine_grasps` tries each seed, slid over its face and rolled a little, and more
candidates closing along every box axis (approaching along the other axes, from above and from
the sensor), on the object's points: the observed ones and the estimate of the hidden side
(:class:`~mvbb_ros.geometry.completion.CompletedView`), seen as a surface
(:func:`surface_model`: the boundary cells of their occupancy grid, with normals from the PCA
of their neighbours). A candidate is a pad gripper moving along its approach line to the first
contact and past it by a finger depth; it holds when no finger meets the object on the way,
both pads touch within the opening and the line between the two contacts lies inside both
friction cones. Its quality in [0, 1] weighs the friction-cone margin, the pads' support and
the fingers' clearance; the task strategy (largest, smallest, outermost, nearest box) reorders
close qualities. :func:`rescore_grasp` checks a previous frame's grasp on the new points, for
the hysteresis of :func:`refine_grasps`. The exact rules are in ``docs/grasp_rules.md``; the
inner loops are numba kernels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

from mvbb_ros.arrays import BoolArray, FloatArray, IndexArray
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.grasps import (
    ApproachAxis,
    FAR_SIDE_MARGIN_DEG,
    Grasp,
    gripper_quaternions,
    Strategy,
)
import numba as nb
import numpy as np
from numpy.typing import ArrayLike
from scipy import ndimage

#: Defaults (metres): the judge's pads, finger depths past the first contact, width margin.
DEFAULT_PAD_SIZE = 0.02
DEFAULT_FINGER_DEPTH = 0.03
DEFAULT_FRICTION = 0.5
DEFAULT_WIDTH_MARGIN = 0.01
DEFAULT_HYSTERESIS = 0.3
DEFAULT_PREFERENCE = 0.1
#: Finger depths tried, as fractions of the finger depth (the deepest is the finger depth).
DEPTH_FRACTIONS: tuple[float, ...] = (1.0 / 3.0, 2.0 / 3.0, 1.0)
#: Slides of the grasp centre over the face, as fractions of the face's extent across the pads.
SLIDES: tuple[float, ...] = (-0.3, -0.15, 0.0, 0.15, 0.3)
#: Approaches per closing axis, evenly turned about it from the next box axis (4: the faces).
APPROACHES_PER_AXIS = 8
#: Rolls of the closing direction about the approach, degrees.
ROLLS: tuple[float, ...] = (-20.0, 0.0, 20.0)
#: Quality weights: friction-cone margin, pad support, finger clearance (they sum to 1).
WEIGHT_MARGIN = 0.5
WEIGHT_SUPPORT = 0.3
WEIGHT_CLEARANCE = 0.2
#: An estimated (not observed) point counts this much towards a pad's support.
ESTIMATED_WEIGHT = 0.25
#: Finger clearance counts fully from this many pad sizes on.
CLEARANCE_PADS = 0.5
#: A pad's contact patch: points within this many grid cells of its first touch.
PATCH_CELLS = 0.6
#: A pad's support: points within this many grid cells of its first touch.
SUPPORT_CELLS = 1.5
#: Normals: PCA of the surface points within this many grid cells.
NORMAL_CELLS = 2.0
#: Normals of sparse points take a wider neighbourhood until it holds this many points.
MIN_NEIGHBOURS = 8
#: The largest occupancy grid (cells); coarser cells beyond.
MAX_GRID_CELLS = 4_000_000
#: Two grasps are the same (the list keeps the better) within this share of the pad size ...
SAME_PADS = 0.5
#: ... and this angle between their hand frames (a half turn about the approach is the same).
SAME_ANGLE_DEG = 15.0


@dataclass(frozen=True)
class RefinementSettings:
    """
    The settings of the refinement stage (:func:`refine_grasps`); off by default (the paper).

    :ivar enabled: refine and score the hypotheses on the points; off: the paper's hypotheses.
    :ivar friction: Coulomb friction coefficient mu of the pads (the cone's half-angle is
        atan(mu)).
    :ivar pad_size: side of the square finger pads, along the approach and across it.
    :ivar finger_depth: the deepest the fingertips go past the first contact; shallower depths
        (:data:`DEPTH_FRACTIONS`) are tried too.
    :ivar width_margin: added to the opening the object needs, for the published width.
    :ivar hysteresis: the previous frame's top grasp stays on top while its score is within this
        of the best new one.
    :ivar preference: weight of the task strategy in the score (the rest is the quality).
    :ivar depth_fractions: the finger depths tried, as fractions of `finger_depth`.
    """

    enabled: bool = False
    friction: float = DEFAULT_FRICTION
    pad_size: float = DEFAULT_PAD_SIZE
    finger_depth: float = DEFAULT_FINGER_DEPTH
    width_margin: float = DEFAULT_WIDTH_MARGIN
    hysteresis: float = DEFAULT_HYSTERESIS
    preference: float = DEFAULT_PREFERENCE
    depth_fractions: tuple[float, ...] = DEPTH_FRACTIONS

    def __post_init__(self) -> None:
        for name in ('friction', 'width_margin', 'hysteresis'):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f'{name} must be >= 0, got {getattr(self, name)}')
        for name in ('pad_size', 'finger_depth'):
            if not getattr(self, name) > 0.0:
                raise ValueError(f'{name} must be > 0, got {getattr(self, name)}')
        if not self.depth_fractions or min(self.depth_fractions) <= 0.0:
            raise ValueError(f'depth_fractions must be > 0, got {self.depth_fractions}')
        if not 0.0 <= self.preference <= 1.0:
            raise ValueError(f'preference must be in [0, 1], got {self.preference}')


# Surface model -----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SurfaceModel:
    """
    One object's surface as the refinement sees it: the boundary of its occupancy grid.

    :ivar points: (K, 3) the centroid of each boundary cell's points.
    :ivar normals: (K, 3) unit surface normals (PCA of the neighbours; sign arbitrary; zero
        where too few neighbours).
    :ivar weights: (K,) 1 for a cell with an observed point, :data:`ESTIMATED_WEIGHT` otherwise.
    :ivar cell: the grid's cell size.
    :ivar floor: the object's lowest height along `up` (the support it stands on); -inf when up
        is unknown.
    :ivar center: (3,) the mean of the observed points.
    """

    points: FloatArray
    normals: FloatArray
    weights: FloatArray
    cell: float
    floor: float
    center: FloatArray


@nb.njit(cache=True)
def _smallest_eigenvector(
    a00: float, a01: float, a02: float, a11: float, a12: float, a22: float
) -> tuple[float, float, float]:
    """Return the unit eigenvector of the smallest eigenvalue of a symmetric 3 x 3 matrix."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * p1
    p = math.sqrt(p2 / 6.0)
    if p <= 1e-300:
        return 0.0, 0.0, 0.0
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
        return 0.0, 0.0, 0.0
    return best[0] / best_norm, best[1] / best_norm, best[2] / best_norm


@nb.njit('float64[:, :](float64[:, :], float64)', cache=True)
def _pca_normals(points: FloatArray, radius: float) -> FloatArray:
    """
    Return each point's normal: the PCA of its neighbours (zero when it has too few).

    The neighbours are the points within `radius`, or within 2 or 4 times it when fewer than
    :data:`MIN_NEIGHBOURS` are that close (sparse samples). The points are binned in cubic cells
    one radius wide and the cells around each point are looked up by binary search in the
    sorted cell keys.
    """
    count = points.shape[0]
    normals = np.zeros((count, 3))
    if count == 0:
        return normals
    low = np.empty(3)
    span = np.empty(3, dtype=np.int64)
    for axis in range(3):
        low[axis] = points[:, axis].min()
        span[axis] = int((points[:, axis].max() - low[axis]) / radius) + 11
    cells = np.empty((count, 3), dtype=np.int64)
    keys = np.empty(count, dtype=np.int64)
    for i in range(count):
        for axis in range(3):
            cells[i, axis] = int((points[i, axis] - low[axis]) / radius) + 5
        keys[i] = (cells[i, 0] * span[1] + cells[i, 1]) * span[2] + cells[i, 2]
    order = np.argsort(keys)
    sorted_keys = keys[order]
    for i in range(count):
        for reach in (1, 2, 4):
            squared = (reach * radius) ** 2
            n = 0
            sx = sy = sz = 0.0
            sxx = sxy = sxz = syy = syz = szz = 0.0
            for dx in range(-reach, reach + 1):
                for dy in range(-reach, reach + 1):
                    for dz in range(-reach, reach + 1):
                        key = ((cells[i, 0] + dx) * span[1] + cells[i, 1] + dy) * span[2] + (
                            cells[i, 2] + dz
                        )
                        start = np.searchsorted(sorted_keys, key)
                        for k in range(start, count):
                            if sorted_keys[k] != key:
                                break
                            j = order[k]
                            x = points[j, 0] - points[i, 0]
                            y = points[j, 1] - points[i, 1]
                            z = points[j, 2] - points[i, 2]
                            if x * x + y * y + z * z > squared:
                                continue
                            n += 1
                            sx += x
                            sy += y
                            sz += z
                            sxx += x * x
                            sxy += x * y
                            sxz += x * z
                            syy += y * y
                            syz += y * z
                            szz += z * z
            if n >= MIN_NEIGHBOURS:
                break
        if n < 4:
            continue
        mx, my, mz = sx / n, sy / n, sz / n
        nx, ny, nz = _smallest_eigenvector(
            sxx / n - mx * mx,
            sxy / n - mx * my,
            sxz / n - mx * mz,
            syy / n - my * my,
            syz / n - my * mz,
            szz / n - mz * mz,
        )
        normals[i, 0] = nx
        normals[i, 1] = ny
        normals[i, 2] = nz
    return normals


def surface_model(
    points: ArrayLike,
    *,
    observed: int | None = None,
    cell: float,
    up: ArrayLike | None = None,
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
    :param up: the up direction, or None: the model's floor is its lowest point along up.
    :return: the surface model.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    seen = len(pts) if observed is None else int(observed)
    if not cell > 0.0:
        raise ValueError(f'cell must be > 0, got {cell!r}')
    margin = 2
    span = np.ptp(pts, axis=0) if len(pts) else np.zeros(3)
    cells = float(np.prod(span / cell + 2 * margin + 1))
    if cells > MAX_GRID_CELLS:
        cell *= (cells / MAX_GRID_CELLS) ** (1.0 / 3.0)
    low = pts.min(axis=0) - margin * cell
    index = np.floor((pts - low) / cell).astype(np.int64)
    shape = tuple(int(v) for v in index.max(axis=0) + margin + 1)
    occupied = np.zeros(shape, dtype=bool)
    occupied[index[:, 0], index[:, 1], index[:, 2]] = True
    solid = ndimage.binary_closing(occupied) | occupied
    inside = ndimage.binary_erosion(solid)
    on_surface = occupied & ~inside
    keep = on_surface[index[:, 0], index[:, 1], index[:, 2]]
    flat = np.ravel_multi_index(tuple(index[keep].T), shape)
    cells_kept, inverse = np.unique(flat, return_inverse=True)
    counts = np.bincount(inverse, minlength=len(cells_kept)).astype(np.float64)
    centroids = (
        np.column_stack(
            [
                np.bincount(inverse, weights=pts[keep, k], minlength=len(cells_kept))
                for k in range(3)
            ]
        )
        / counts[:, None]
    )
    seen_cells = np.bincount(
        inverse, weights=(np.flatnonzero(keep) < seen).astype(np.float64), minlength=len(counts)
    )
    weights = np.where(seen_cells > 0.0, 1.0, ESTIMATED_WEIGHT)
    normals = _pca_normals(np.ascontiguousarray(centroids), NORMAL_CELLS * cell)
    floor = -math.inf
    if up is not None:
        unit_up = np.asarray(up, dtype=np.float64)
        floor = float(np.min(pts @ (unit_up / np.linalg.norm(unit_up))))
    center = pts[: max(seen, 1)].mean(axis=0)
    return SurfaceModel(centroids, normals, weights, float(cell), floor, center)


# Evaluation --------------------------------------------------------------------------------------

#: Columns of :func:`_evaluate`'s output.
(
    COL_VALID,
    COL_QUALITY,
    COL_MARGIN,
    COL_SUPPORT,
    COL_CLEARANCE,
    COL_WIDTH,
    COL_CONTACT_WIDTH,
    COL_FIRST,
    COL_TIP,
    COL_CENTER,
    COL_DEPTH,
) = range(11)
COL_CONTACTS = 11  # 11..16: the two contacts (the pad on +closing first)
EVALUATION_COLUMNS = 17

#: Entries of the kernel's parameter vector.
(
    P_HALF,
    P_PAD,
    P_TOLERANCE,
    P_SUPPORT_TOLERANCE,
    P_CONE,
    P_MIN_CLEAR,
    P_CLEAR_REF,
    P_EXPECTED,
    P_SUPPORT_CLEARANCE,
    P_STANDOFF,
    P_MIN_WIDTH,
    P_FLOOR,
    P_W_MARGIN,
    P_W_SUPPORT,
    P_W_CLEARANCE,
) = range(15)
PARAMETER_COUNT = 15


@nb.njit(
    'float64[:, :](float64[:, :], float64[:, :], float64[:], float64[:, :], float64[:, :], '
    'float64[:, :], float64[:], float64[:], float64[:])',
    cache=True,
)
def _evaluate(
    points: FloatArray,
    normals: FloatArray,
    weights: FloatArray,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    depths: FloatArray,
    params: FloatArray,
    up: FloatArray,
) -> FloatArray:
    """
    Close a pad gripper on the surface points along each candidate line (the rules: module doc).

    Per candidate: the points in the pads' band across the closing direction; per finger depth,
    the hand centred on what the fingers pass, the first contact h in the opening, the tips at
    h + depth, the contacts where the pads first touch, the friction test on the contact line,
    and the quality; the depth of the best quality is kept. Columns: ``COL_*``.
    """
    count = points.shape[0]
    out = np.zeros((origins.shape[0], EVALUATION_COLUMNS))
    band_u = np.empty(count)
    band_v = np.empty(count)
    band_k = np.empty(count, dtype=np.int64)
    half = params[P_HALF]
    pad = params[P_PAD]
    cone = params[P_CONE]
    inf = math.inf
    for i in range(origins.shape[0]):
        o = origins[i]
        a = approaches[i]
        c = closings[i]
        s0 = a[1] * c[2] - a[2] * c[1]
        s1 = a[2] * c[0] - a[0] * c[2]
        s2 = a[0] * c[1] - a[1] * c[0]
        n = 0
        for k in range(count):
            dx = points[k, 0] - o[0]
            dy = points[k, 1] - o[1]
            dz = points[k, 2] - o[2]
            w = dx * s0 + dy * s1 + dz * s2
            if abs(w) > pad / 2.0:
                continue
            band_u[n] = dx * a[0] + dy * a[1] + dz * a[2]
            band_v[n] = dx * c[0] + dy * c[1] + dz * c[2]
            band_k[n] = k
            n += 1
        if n == 0:
            continue
        best = -1.0
        for di in range(depths.shape[0]):
            depth = depths[di]
            center = 0.0
            first = inf
            tip = inf
            low = inf
            high = -inf
            for _ in range(4):
                first = inf
                for j in range(n):
                    if abs(band_v[j] - center) <= half and band_u[j] < first:
                        first = band_u[j]
                if first == inf:
                    break
                tip = first + depth
                low = inf
                high = -inf
                for j in range(n):
                    if band_u[j] <= tip:
                        low = min(low, band_v[j])
                        high = max(high, band_v[j])
                moved = 0.5 * (low + high) - center
                center += moved
                if abs(moved) <= 1e-12 * (1.0 + half):
                    break
            if first == inf:
                continue
            # The fingers pass everything they reach with clearance (else they collide).
            clearance = half - max(high - center, center - low)
            if clearance < params[P_MIN_CLEAR]:
                continue
            # Contacts: where each pad (the finger's last `pad` before the tip) first touches.
            pad_low = inf
            pad_high = -inf
            for j in range(n):
                if tip - pad <= band_u[j] <= tip:
                    pad_low = min(pad_low, band_v[j])
                    pad_high = max(pad_high, band_v[j])
            if pad_high - pad_low < params[P_MIN_WIDTH]:
                continue
            contact = np.zeros(6)
            normal = np.zeros(6)
            patch = np.zeros(2)
            support = np.zeros(2)
            for j in range(n):
                u = band_u[j]
                if u < tip - pad or u > tip:
                    continue
                v = band_v[j]
                k = band_k[j]
                for side in range(2):
                    gap = pad_high - v if side == 0 else v - pad_low
                    if gap <= params[P_SUPPORT_TOLERANCE]:
                        support[side] += weights[k]
                    if gap > params[P_TOLERANCE]:
                        continue
                    sign = 1.0 if side == 0 else -1.0
                    facing = normals[k, 0] * c[0] + normals[k, 1] * c[1] + normals[k, 2] * c[2]
                    flip = sign if facing * sign >= 0.0 else -sign
                    for axis in range(3):
                        contact[3 * side + axis] += points[k, axis]
                        normal[3 * side + axis] += flip * normals[k, axis] * sign
                    patch[side] += 1.0
            for axis in range(6):
                contact[axis] /= patch[axis // 3]
            # The contact line from the - pad's contact to the + pad's.
            lx = contact[0] - contact[3]
            ly = contact[1] - contact[4]
            lz = contact[2] - contact[5]
            length = math.sqrt(lx * lx + ly * ly + lz * lz)
            if length <= 1e-12:
                continue
            worst = 0.0
            for side in range(2):
                nx = normal[3 * side]
                ny = normal[3 * side + 1]
                nz = normal[3 * side + 2]
                norm = math.sqrt(nx * nx + ny * ny + nz * nz)
                if norm <= 1e-12:
                    worst = inf
                    break
                sign = 1.0 if side == 0 else -1.0
                cos = sign * (lx * nx + ly * ny + lz * nz) / (length * norm)
                worst = max(worst, math.acos(min(1.0, max(-1.0, cos))))
            if worst > cone:
                continue
            # The support: pads above the floor at the pre-grasp and the final pose.
            if params[P_FLOOR] > -inf:
                cu = c[0] * up[0] + c[1] * up[1] + c[2] * up[2]
                su = s0 * up[0] + s1 * up[1] + s2 * up[2]
                au = a[0] * up[0] + a[1] * up[1] + a[2] * up[2]
                tip_height = (o[0] + tip * a[0] + center * c[0]) * up[0]
                tip_height += (o[1] + tip * a[1] + center * c[1]) * up[1]
                tip_height += (o[2] + tip * a[2] + center * c[2]) * up[2]
                lowest = -half * abs(cu) - pad / 2.0 * abs(su) + min(0.0, -pad * au)
                final = tip_height + lowest
                before = final - (tip - first + params[P_STANDOFF]) * au
                if min(final, before) < params[P_FLOOR] + params[P_SUPPORT_CLEARANCE]:
                    continue
            margin = 1.0 - worst / cone if cone > 0.0 else 0.0
            held = min(support[0], support[1]) / params[P_EXPECTED]
            quality = (
                params[P_W_MARGIN] * margin
                + params[P_W_SUPPORT] * min(1.0, held)
                + params[P_W_CLEARANCE] * min(1.0, clearance / params[P_CLEAR_REF])
            )
            if quality <= best:
                continue
            best = quality
            row = out[i]
            row[COL_VALID] = 1.0
            row[COL_QUALITY] = quality
            row[COL_MARGIN] = margin
            row[COL_SUPPORT] = min(1.0, held)
            row[COL_CLEARANCE] = clearance
            row[COL_WIDTH] = high - low
            row[COL_CONTACT_WIDTH] = pad_high - pad_low
            row[COL_FIRST] = first
            row[COL_TIP] = tip
            row[COL_CENTER] = center
            row[COL_DEPTH] = depth
            for axis in range(6):
                row[COL_CONTACTS + axis] = contact[axis]
    return out


@nb.njit(
    'boolean[:](float64[:, :], float64[:, :], float64[:, :], float64, float64, int64)',
    cache=True,
)
def _distinct(
    centers: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    distance: float,
    cos_angle: float,
    limit: int,
) -> BoolArray:
    """
    Keep, in order, each grasp that is not the same as one kept before it (at most `limit`).

    The same: centres within `distance`, approaches within the angle, closing lines within it
    (either sense: a half turn about the approach is the same hand).
    """
    count = centers.shape[0]
    keep = np.zeros(count, dtype=np.bool_)
    kept = np.empty(count, dtype=np.int64)
    size = 0
    squared = distance * distance
    for i in range(count):
        if size >= limit:
            break
        same = False
        for m in range(size):
            j = kept[m]
            dx = centers[i, 0] - centers[j, 0]
            dy = centers[i, 1] - centers[j, 1]
            dz = centers[i, 2] - centers[j, 2]
            if dx * dx + dy * dy + dz * dz > squared:
                continue
            along = (
                approaches[i, 0] * approaches[j, 0]
                + approaches[i, 1] * approaches[j, 1]
                + approaches[i, 2] * approaches[j, 2]
            )
            across = (
                closings[i, 0] * closings[j, 0]
                + closings[i, 1] * closings[j, 1]
                + closings[i, 2] * closings[j, 2]
            )
            if along >= cos_angle and abs(across) >= cos_angle:
                same = True
                break
        if not same:
            keep[i] = True
            kept[size] = i
            size += 1
    return keep


# Candidates --------------------------------------------------------------------------------------


@dataclass
class _Candidates:
    """Candidate grasp lines: origin, approach, closing, box, face and roll (seeds: -1 = none)."""

    origins: list[FloatArray] = field(default_factory=list)
    approaches: list[FloatArray] = field(default_factory=list)
    closings: list[FloatArray] = field(default_factory=list)
    boxes: list[IndexArray] = field(default_factory=list)

    def add(
        self, origins: FloatArray, approaches: FloatArray, closings: FloatArray, box: int
    ) -> None:
        """Add rows (broadcast to the origins' count)."""
        count = len(origins)
        self.origins.append(origins)
        self.approaches.append(np.broadcast_to(approaches, (count, 3)))
        self.closings.append(np.broadcast_to(closings, (count, 3)))
        self.boxes.append(np.full(count, box, dtype=np.intp))

    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, IndexArray]:
        """Return (origins, approaches, closings, boxes) as contiguous arrays."""
        if not self.origins:
            empty = np.zeros((0, 3))
            return empty, empty, empty, np.zeros(0, dtype=np.intp)
        return (
            np.ascontiguousarray(np.concatenate(self.origins)),
            np.ascontiguousarray(np.concatenate(self.approaches)),
            np.ascontiguousarray(np.concatenate(self.closings)),
            np.concatenate(self.boxes),
        )


def _unit_rows(vectors: FloatArray) -> FloatArray:
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors / np.where(norms > 0.0, norms, 1.0)


def _frames(box: Box, up: FloatArray | None, view: FloatArray | None) -> list[tuple]:
    """
    Return the (approach, closing) pairs of one box: closing along each box axis.

    Approaches: along the other two axes, both senses (the paper's faces), then from above
    (against `up`) and along the viewing direction `view`, each made perpendicular to the
    closing axis (skipped when nearly parallel to it).
    """
    axes = box.rotation.T
    pairs = []
    for k in range(3):
        closing = axes[k]
        first, second = axes[(k + 1) % 3], axes[(k + 2) % 3]
        for angle in np.deg2rad(np.arange(0.0, 360.0, 360.0 / APPROACHES_PER_AXIS)):
            pairs.append((math.cos(angle) * first + math.sin(angle) * second, closing))
        for direction in (None if up is None else -up, view):
            if direction is None:
                continue
            flat = direction - (direction @ closing) * closing
            norm = float(np.linalg.norm(flat))
            if norm >= 0.3:
                pairs.append((flat / norm, closing))
    return pairs


def _box_candidates(
    boxes: Sequence[Box], up: FloatArray | None, views: Sequence[FloatArray | None], pad: float
) -> _Candidates:
    """Return every box's candidate lines: frames x rolls x slides across the pads."""
    out = _Candidates()
    rolls = np.deg2rad(np.array(ROLLS))
    slides = np.array(SLIDES)
    for index, box in enumerate(boxes):
        for approach, closing in _frames(box, up, views[index]):
            side = np.cross(approach, closing)
            turned = np.cos(rolls)[:, None] * closing + np.sin(rolls)[:, None] * side
            across = np.cross(approach, turned)  # (R, 3) the side axis of each roll
            reach = np.abs(across @ box.rotation) @ box.extents  # extent across the pads
            offsets = slides[None, :] * np.maximum(reach[:, None] - pad, 0.0)
            origins = box.center + offsets[:, :, None] * across[:, None, :]  # (R, S, 3)
            count = origins.shape[1]
            out.add(
                origins.reshape(-1, 3),
                np.broadcast_to(approach, (len(rolls) * count, 3)),
                np.repeat(turned, count, axis=0),
                index,
            )
    return out


def _seed_candidates(seeds: Sequence[Grasp], boxes: Sequence[Box], pad: float) -> _Candidates:
    """Return the seeds' own lines (through their face centres), one sense per closing line."""
    out = _Candidates()
    for seed in seeds:
        if seed.roll_deg >= 180:  # the half turn closes on the same line
            continue
        box = boxes[seed.box_index]
        out.add(box.center[None, :], seed.approach, seed.closing, seed.box_index)
    return out


# The stage ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class GraspView:
    """
    What the refinement knows of the view and the gripper beyond its settings.

    :ivar gripper_max_width: the gripper's opening.
    :ivar standoff: pre-grasp distance before the first contact.
    :ivar approach_axis: the gripper pose convention (``docs/grasp_rules.md``).
    :ivar strategy: the task strategy whose preference reorders close scores.
    :ivar up: unit up direction, or None.
    :ivar viewpoint: (3,) the sensor position, or None when the points are no single view.
    :ivar far_side: allow approaches from the far side of the object (seen from the viewpoint).
    :ivar max_approach_elevation_deg: approaches rising more than this above the horizontal
        are removed (with `up`).
    :ivar support_clearance: the pads stay this far above the object's lowest point (with `up`).
    :ivar max_grasps: at most this many grasps (0: all distinct ones).
    """

    gripper_max_width: float
    standoff: float
    approach_axis: ApproachAxis = 'z'
    strategy: Strategy = 'largest'
    up: FloatArray | None = None
    viewpoint: FloatArray | None = None
    far_side: bool = True
    max_approach_elevation_deg: float = 45.0
    support_clearance: float = 0.0
    max_grasps: int = 0


@dataclass
class RefinedGrasps:
    """
    The refinement's answer for one cloud.

    :ivar grasps: the grasps, best first (the first is the one to execute).
    :ivar candidates: how many candidate lines were tried.
    :ivar holding: how many of them close on the points with friction.
    :ivar kept_previous: whether the previous frame's top grasp stayed on top (hysteresis).
    """

    grasps: list[Grasp]
    candidates: int = 0
    holding: int = 0
    kept_previous: bool = False


def _parameters(
    settings: RefinementSettings, view: GraspView, cell: float, floor: float
) -> FloatArray:
    pad = settings.pad_size
    params = np.zeros(PARAMETER_COUNT)
    params[P_HALF] = view.gripper_max_width / 2.0
    params[P_PAD] = pad
    params[P_TOLERANCE] = PATCH_CELLS * cell
    params[P_SUPPORT_TOLERANCE] = SUPPORT_CELLS * cell
    params[P_CONE] = math.atan(settings.friction)
    params[P_MIN_CLEAR] = 0.0
    params[P_CLEAR_REF] = CLEARANCE_PADS * pad
    params[P_EXPECTED] = max(1.0, (pad / cell) ** 2 / 2.0)
    params[P_SUPPORT_CLEARANCE] = view.support_clearance
    params[P_STANDOFF] = view.standoff
    params[P_MIN_WIDTH] = cell
    params[P_FLOOR] = floor if view.up is not None else -math.inf
    params[P_W_MARGIN] = WEIGHT_MARGIN
    params[P_W_SUPPORT] = WEIGHT_SUPPORT
    params[P_W_CLEARANCE] = WEIGHT_CLEARANCE
    return params


def evaluate_lines(
    model: SurfaceModel,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    settings: RefinementSettings,
    view: GraspView,
) -> FloatArray:
    """
    Close the pad gripper along candidate lines on one surface model.

    :param model: the object's surface.
    :param origins: (C, 3) a point on each line.
    :param approaches: (C, 3) unit approach directions.
    :param closings: (C, 3) unit closing directions, perpendicular to the approaches.
    :param settings: the pads, friction and finger depth.
    :param view: the gripper's opening, standoff and the support.
    :return: (C, :data:`EVALUATION_COLUMNS`) rows (columns ``COL_*``; invalid rows are 0).
    """
    depths = settings.finger_depth * np.array(settings.depth_fractions, dtype=np.float64)
    up = np.zeros(3) if view.up is None else np.asarray(view.up, dtype=np.float64)
    return _evaluate(
        model.points,
        model.normals,
        model.weights,
        np.array(origins, dtype=np.float64, order='C'),
        np.array(approaches, dtype=np.float64, order='C'),
        np.array(closings, dtype=np.float64, order='C'),
        depths,
        _parameters(settings, view, model.cell, model.floor),
        up,
    )


def _feasible(
    approaches: FloatArray, objects: IndexArray, models: Sequence[SurfaceModel], view: GraspView
) -> BoolArray:
    """Tell which approaches are allowed: not from below (with up), not from the far side."""
    keep = np.ones(len(approaches), dtype=bool)
    if view.up is not None:
        limit = math.sin(math.radians(view.max_approach_elevation_deg))
        keep &= approaches @ view.up <= limit + 1e-12
    if not view.far_side and view.viewpoint is not None:
        centers = np.array([model.center for model in models])[objects]
        sight = _unit_rows(centers - view.viewpoint)
        margin = math.sin(math.radians(FAR_SIDE_MARGIN_DEG))
        keep &= np.einsum('ij,ij->i', approaches, sight) >= margin
    return keep


def _face_and_roll(box: Box, approach: FloatArray, closing: FloatArray) -> tuple[int, int]:
    """Return the box face most opposed to `approach` and the closing's roll from its edge."""
    normals = box.face_normals()
    face = int(np.argmin(normals @ approach))
    axis = face // 2
    edge = box.rotation[:, (axis + 1) % 3]
    approach_face = -normals[face]
    turned = np.cross(approach_face, edge)
    angle = math.degrees(math.atan2(float(closing @ turned), float(closing @ edge)))
    return face, int(round(angle)) % 360


def _grasps(
    rows: FloatArray,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    boxes: Sequence[Box],
    box_index: IndexArray,
    objects: IndexArray,
    scores: FloatArray,
    settings: RefinementSettings,
    view: GraspView,
) -> list[Grasp]:
    """Return the grasps of evaluated rows (valid ones), in the given order."""
    quaternions = gripper_quaternions(approaches, closings, view.approach_axis)
    out = []
    for i in range(len(rows)):
        row = rows[i]
        position = (
            origins[i]
            + row[COL_CENTER] * closings[i]
            + (row[COL_FIRST] - view.standoff) * approaches[i]
        )
        box = int(box_index[i])
        face, roll = _face_and_roll(boxes[box], approaches[i], closings[i])
        width = min(row[COL_WIDTH] + settings.width_margin, view.gripper_max_width)
        out.append(
            Grasp(
                position=_frozen(position),
                quaternion=_frozen(quaternions[i]),
                approach=_frozen(approaches[i]),
                closing=_frozen(closings[i]),
                width=float(width),
                box_index=box,
                face=face,
                roll_deg=roll,
                score=float(scores[i]),
                object_index=int(objects[i]),
                depth=float(view.standoff + row[COL_DEPTH]),
            )
        )
    return out


def _frozen(values: ArrayLike) -> FloatArray:
    out = np.array(values, dtype=np.float64)
    out.setflags(write=False)
    return out


def _box_preferences(boxes: Sequence[Box], view: GraspView) -> FloatArray:
    """
    Return each box's preference in [0, 1] under the task strategy, as a ratio to the best box.

    Largest: its volume over the largest; smallest: the smallest volume over its own;
    outermost: its centre's distance from the boxes' volume-weighted centroid over the
    largest such distance; nearest: the nearest box centre's distance from the viewpoint over
    its own. Ratios (unlike the paper's min-max ranking) change little when the boxes change a
    little from frame to frame.
    """
    if not boxes:
        return np.zeros(0)
    volumes = np.array([box.volume for box in boxes])
    centers = np.array([box.center for box in boxes])
    tiny = 1e-300
    if view.strategy == 'largest':
        ratio = volumes / max(float(volumes.max()), tiny)
    elif view.strategy == 'smallest':
        ratio = float(volumes.min()) / np.maximum(volumes, tiny)
    elif view.strategy == 'outermost':
        weights = volumes if volumes.sum() > 0.0 else np.ones(len(boxes))
        centroid = (centers * weights[:, None]).sum(axis=0) / weights.sum()
        distance = np.linalg.norm(centers - centroid, axis=1)
        ratio = distance / max(float(distance.max()), tiny)
    else:
        origin = np.zeros(3) if view.viewpoint is None else view.viewpoint
        distance = np.linalg.norm(centers - origin, axis=1)
        ratio = float(distance.min()) / np.maximum(distance, tiny)
    return np.clip(np.where(np.isfinite(ratio), ratio, 1.0), 0.0, 1.0)


#: The previous grasp is re-scored at these slides across the pads (fractions of the pad size)
#: and rolls (degrees), all within what counts as the same grasp; the best of them is kept.
RESCORE_SLIDES: tuple[float, ...] = (-0.25, -0.125, 0.0, 0.125, 0.25)
RESCORE_ROLLS: tuple[float, ...] = (-10.0, 0.0, 10.0)


def rescore_grasp(
    grasp: Grasp,
    boxes: Sequence[Box],
    box_objects: Sequence[int],
    models: Sequence[SurfaceModel],
    settings: RefinementSettings,
    view: GraspView,
) -> Grasp | None:
    """
    Check a grasp (a previous frame's) on new points: the same grasp, refined a little again.

    The grasp's line is tried as it is and slid across the pads by up to a quarter pad
    (:data:`RESCORE_SLIDES`) and rolled by up to 10 degrees (:data:`RESCORE_ROLLS`), all of which
    a robot takes for the same grasp; each is centred again between what the fingers pass and
    stops again at the new first contact, on every object's surface. Where the fingertips
    close must stay within one pad size of where they closed before (an object that moved
    further is grasped anew). The best that holds is returned with the width and score of the
    new points; its box is the nearest box of its object to its closing point.

    :return: the re-scored grasp, or None when it is not feasible or does not hold any more.
    """
    if not models:
        return None
    approach = np.asarray(grasp.approach, dtype=np.float64)
    closing = np.asarray(grasp.closing, dtype=np.float64)
    side = np.cross(approach, closing)
    rolls = np.deg2rad(np.array(RESCORE_ROLLS))
    turned = np.cos(rolls)[:, None] * closing + np.sin(rolls)[:, None] * side
    offsets = np.array(RESCORE_SLIDES) * settings.pad_size
    origins = np.asarray(grasp.position, dtype=np.float64) + np.repeat(
        offsets[None, :, None] * np.cross(approach, turned)[:, None, :], 1, axis=0
    ).reshape(-1, 3)
    closings = np.repeat(turned, len(offsets), axis=0)
    approaches = np.broadcast_to(approach, closings.shape)
    before = np.asarray(grasp.position, dtype=np.float64) + grasp.depth * approach
    best: tuple[float, int, int, FloatArray] | None = None
    for number, model in enumerate(models):
        if not _feasible(approach[None, :], np.array([number]), models, view)[0]:
            continue
        rows = evaluate_lines(model, origins, approaches, closings, settings, view)
        tips = (
            origins
            + rows[:, COL_TIP][:, None] * approaches
            + rows[:, COL_CENTER][:, None] * closings
        )
        near = np.linalg.norm(tips - before, axis=1) <= settings.pad_size
        quality = np.where((rows[:, COL_VALID] > 0.0) & near, rows[:, COL_QUALITY], -1.0)
        pick = int(np.argmax(quality))
        if quality[pick] >= 0.0 and (best is None or quality[pick] > best[0]):
            best = (float(quality[pick]), number, pick, rows[pick])
    if best is None:
        return None
    _, number, pick, row = best
    origin, closing = origins[pick], closings[pick]
    row = row.copy()
    row[COL_QUALITY] = _robust_quality(
        models,
        np.array([number]),
        origin[None, :],
        approach[None, :],
        closing[None, :],
        settings,
        view,
    )[0]
    tip = origin + row[COL_TIP] * approach + row[COL_CENTER] * closing
    own = [i for i, obj in enumerate(box_objects) if obj == number]
    if not own:
        return None
    box = min(own, key=lambda i: float(np.linalg.norm(boxes[i].center - tip)))
    preference = _box_preferences(boxes, view)[box]
    score = _score(np.array([row[COL_QUALITY]]), np.array([preference]), settings)
    return _grasps(
        row[None, :],
        origin[None, :],
        approach[None, :],
        closing[None, :],
        boxes,
        np.array([box]),
        np.array([number]),
        score,
        settings,
        view,
    )[0]


#: A grasp's quality is the mean over its line and these neighbours (a robot's pose error):
#: slid across the pads by this share of the pad size, and rolled by this angle (degrees).
ROBUST_SLIDE = 0.25
ROBUST_ROLL_DEG = 10.0


def _neighbours(
    origins: FloatArray, approaches: FloatArray, closings: FloatArray, pad: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return each line's four neighbours (slid both ways, rolled both ways), (4 G, 3) each."""
    side = np.cross(approaches, closings)
    roll = math.radians(ROBUST_ROLL_DEG)
    shift = ROBUST_SLIDE * pad * side
    out_origins = np.concatenate([origins + shift, origins - shift, origins, origins])
    rolled = [math.cos(roll) * closings + sign * math.sin(roll) * side for sign in (1.0, -1.0)]
    out_closings = np.concatenate([closings, closings, *rolled])
    return out_origins, np.concatenate([approaches] * 4), out_closings


def _robust_quality(
    models: Sequence[SurfaceModel],
    objects: IndexArray,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    settings: RefinementSettings,
    view: GraspView,
) -> FloatArray:
    """
    Return each line's robust quality: the mean over it and its neighbours (0 where not held).

    The neighbours (:func:`_neighbours`) are what a robot's pose error of a few millimetres and
    degrees makes of the grasp; a grasp at the edge of holding scores less than one in the
    middle of a region that holds, and the score varies less with the sensor's noise.
    """
    total = np.zeros(len(origins))
    for number, model in enumerate(models):
        mine = np.flatnonzero(objects == number)
        if not len(mine):
            continue
        lines = (origins[mine], approaches[mine], closings[mine])
        rows = evaluate_lines(model, *lines, settings, view)
        near = evaluate_lines(model, *_neighbours(*lines, settings.pad_size), settings, view)
        quality = np.concatenate([rows[:, COL_QUALITY], near[:, COL_QUALITY]])
        total[mine] = quality.reshape(5, len(mine)).mean(axis=0)
    return total


def _score(
    quality: FloatArray, preference: FloatArray, settings: RefinementSettings
) -> FloatArray:
    """Return the score in [0, 1]: the quality, with the strategy's preference weighed in."""
    weight = settings.preference
    return np.clip((1.0 - weight) * quality + weight * preference, 0.0, 1.0)


def refine_grasps(
    seeds: Sequence[Grasp],
    boxes: Sequence[Box],
    box_objects: Sequence[int],
    models: Sequence[SurfaceModel],
    settings: RefinementSettings,
    view: GraspView,
    previous: Grasp | None = None,
) -> RefinedGrasps:
    """
    Return grasps checked and scored on the points, best first (the rules: docs/grasp_rules.md).

    :param seeds: the paper's hypotheses on `boxes` (:func:`grasp_hypotheses`).
    :param boxes: every object's leaf boxes (the seeds' ``box_index`` indexes them).
    :param box_objects: the object (index into `models`) of each box.
    :param models: each object's surface (:func:`surface_model`).
    :param settings: the refinement's settings.
    :param view: the gripper, the view and the filters.
    :param previous: the previous frame's top grasp (same frame of reference), or None; it
        stays on top while it holds and scores within ``settings.hysteresis`` of the best.
    :return: the grasps and what was tried.
    """
    if not boxes or not models:
        return RefinedGrasps([])
    objects_of_boxes = np.asarray(box_objects, dtype=np.intp)
    views: list[FloatArray | None] = []
    for number in objects_of_boxes:
        sight = None
        if view.viewpoint is not None:
            sight = models[number].center - view.viewpoint
            norm = float(np.linalg.norm(sight))
            sight = sight / norm if norm > 0.0 else None
        views.append(sight)
    candidates = _seed_candidates(seeds, boxes, settings.pad_size)
    generated = _box_candidates(boxes, view.up, views, settings.pad_size)
    for name in ('origins', 'approaches', 'closings', 'boxes'):
        getattr(candidates, name).extend(getattr(generated, name))
    origins, approaches, closings, box_index = candidates.arrays()
    objects = objects_of_boxes[box_index]
    keep = _feasible(approaches, objects, models, view)
    origins, approaches, closings = origins[keep], approaches[keep], closings[keep]
    box_index, objects = box_index[keep], objects[keep]
    rows = np.zeros((len(origins), EVALUATION_COLUMNS))
    for number, model in enumerate(models):
        mine = np.flatnonzero(objects == number)
        if len(mine):
            rows[mine] = evaluate_lines(
                model, origins[mine], approaches[mine], closings[mine], settings, view
            )
    valid = np.flatnonzero(rows[:, COL_VALID] > 0.0)
    quality = _robust_quality(
        models, objects[valid], origins[valid], approaches[valid], closings[valid], settings, view
    )
    rows[valid, COL_QUALITY] = quality
    preference = _box_preferences(boxes, view)[box_index[valid]]
    scores = _score(quality, preference, settings)
    ranked = np.argsort(-scores, kind='stable')
    order, scores = valid[ranked], scores[ranked]
    centers = (
        origins[order]
        + rows[order, COL_TIP][:, None] * approaches[order]
        + rows[order, COL_CENTER][:, None] * closings[order]
    )
    limit = view.max_grasps if view.max_grasps > 0 else len(order)
    distinct = _distinct(
        np.ascontiguousarray(centers),
        np.ascontiguousarray(approaches[order]),
        np.ascontiguousarray(closings[order]),
        SAME_PADS * settings.pad_size,
        math.cos(math.radians(SAME_ANGLE_DEG)),
        limit + 1,
    )
    order, scores = order[distinct], scores[distinct]
    grasps = _grasps(
        rows[order],
        origins[order],
        approaches[order],
        closings[order],
        boxes,
        box_index[order],
        objects[order],
        scores,
        settings,
        view,
    )
    result = RefinedGrasps(grasps, candidates=len(origins), holding=len(valid))
    if previous is not None:
        kept = rescore_grasp(previous, boxes, box_objects, models, settings, view)
        best = grasps[0].score if grasps else -math.inf
        if kept is not None and kept.score + settings.hysteresis >= best:
            rest = [g for g in grasps if not _same(g, kept, settings)]
            result.grasps = [kept, *rest]
            result.kept_previous = True
    result.grasps = result.grasps[:limit]
    return result


def _same(first: Grasp, second: Grasp, settings: RefinementSettings) -> bool:
    """Tell whether two grasps are the same hand pose (the rule of :func:`_distinct`)."""
    tips = [np.asarray(g.position) + g.depth * np.asarray(g.approach) for g in (first, second)]
    if float(np.linalg.norm(tips[0] - tips[1])) > SAME_PADS * settings.pad_size:
        return False
    cos = math.cos(math.radians(SAME_ANGLE_DEG))
    along = float(np.dot(first.approach, second.approach))
    across = abs(float(np.dot(first.closing, second.closing)))
    return along >= cos and across >= cos


def warm_up() -> None:
    """Run every kernel of this module once on a small box (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(*[np.linspace(-0.03, 0.03, 7)] * 3, indexing='ij'), -1)
    model = surface_model(grid.reshape(-1, 3), cell=0.01, up=(0.0, 0.0, 1.0))
    view = GraspView(gripper_max_width=0.1, standoff=0.05, up=np.array([0.0, 0.0, 1.0]))
    rows = evaluate_lines(
        model,
        np.zeros((1, 3)),
        np.array([[0.0, 0.0, -1.0]]),
        np.array([[1.0, 0.0, 0.0]]),
        RefinementSettings(enabled=True),
        view,
    )
    _distinct(rows[:, :3].copy(), rows[:, :3].copy(), rows[:, :3].copy(), 0.01, 0.9, 1)
