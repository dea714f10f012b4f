"""
A pad gripper closing on a surface model: does it hold, how well, and how wide.

:func:`evaluate_lines` moves a gripper with two square pads along each candidate line (a point,
an approach and a closing direction) on a
:class:`~mvbb_ros.geometry.grasping.surface.SurfaceModel`: to the first contact and past it by a
finger depth, centred on what the fingers pass. The line holds when no finger meets the object on
the way, both pads touch within the opening, the pads stay above the support, and the line between
the two contacts lies inside both friction cones; its quality in [0, 1] weighs the cone margin, the
pads' support and the fingers' clearance. The inner loop is the numba kernel :func:`_evaluate`; the
rules: ``docs/grasp_rules.md``.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
import math

from mvbb_ros.arrays import FloatArray
from mvbb_ros.common.workers import gather, split_rows, Workers
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
from mvbb_ros.geometry.grasping.surface import surface_model, SurfaceModel
import numba as nb
import numpy as np

#: Quality weights: friction-cone margin, pad support, finger clearance (they sum to 1).
WEIGHT_MARGIN = 0.5
WEIGHT_SUPPORT = 0.3
WEIGHT_CLEARANCE = 0.2
#: With the hand's fingers known (``finger_length``), how deep the pads reach over the object
#: counts too: the weights then (margin, support, clearance, coverage; they sum to 1).
HAND_WEIGHTS = (0.35, 0.2, 0.15, 0.3)
#: Finger clearance counts fully from this many pad sizes on.
CLEARANCE_PADS = 0.5
#: A pad's contact patch: points within this many grid cells of its first touch.
PATCH_CELLS = 0.6
#: A pad's support: points within this many grid cells of its first touch.
SUPPORT_CELLS = 1.5


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
COL_COVERAGE = 17
EVALUATION_COLUMNS = 18

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
    P_REACH_SLACK,
    P_LENGTH,
    P_THICKNESS,
    P_PALM_HALF_DEPTH,
    P_PALM_HALF_WIDTH,
    P_PALM_HEIGHT,
    P_PALM_MARGIN,
    P_MIN_DEPTH,
    P_BEYOND,
    P_W_COVERAGE,
    P_TIP_CLEAR,
    P_FLAT_COS,
    P_VALID_ONLY,
) = range(28)
PARAMETER_COUNT = 28
#: The palm stays this far (metres) behind the nearest point in front of it.
PALM_MARGIN = 0.004
#: Points this many grid cells past the fingertips tell whether a pad lies flat on the object.
BEYOND_CELLS = 1.5
#: A pad lies flat on what it touches only when the points there face it within this angle
#: (degrees; their mean estimated normal).
FLAT_FACING_DEG = 45.0
#: The lenient pass (an object where no line holds otherwise) takes a pad touching only at its
#: tip as flat when the tip is at most this high above the support (metres, with up known).
LENIENT_TIP_HEIGHT = 0.012
#: A depth cut short by the palm or the support must keep this share of the shallowest depth.
MIN_DEPTH_SHARE = 0.5


#: :func:`_place_hand`'s outcomes: placed; no contact within the opening (the depth is skipped);
#: the hand went past the points it was given (try again with the whole band).
HAND_PLACED, HAND_MISSED, HAND_BEYOND_REACH = range(3)
#: How far (in pads) centring may move the first contact before the whole band is searched:
#: the same results whatever it is; 0.5 measured fastest on 300k frames (0.25-1 alike).
REACH_SLACK = 0.5


#: Numba's floating-point flags for a reduction of finite values by their minimum: exact in any
#: order, so the compiler may spread it over vector lanes.
REDUCTION_MATH = {'nnan', 'nsz', 'reassoc'}


@nb.njit(cache=True, nogil=True, fastmath=REDUCTION_MATH)
def _least(values: FloatArray, count: int) -> float:
    """Return the least of the first `count` values (inf when none)."""
    # Four running minima side by side: one would wait on the last at every value.
    least_0 = least_1 = least_2 = least_3 = math.inf
    quads = count // 4 * 4
    for k in range(0, quads, 4):
        least_0 = min(least_0, values[k])
        least_1 = min(least_1, values[k + 1])
        least_2 = min(least_2, values[k + 2])
        least_3 = min(least_3, values[k + 3])
    for k in range(quads, count):
        least_0 = min(least_0, values[k])
    return min(min(least_0, least_1), min(least_2, least_3))


@nb.njit(cache=True, nogil=True, inline='always')
def _beyond_step(
    u: float,
    v: float,
    tip: float,
    limit: float,
    center: float,
    half: float,
    first: float,
    low: float,
    high: float,
    bottom: float,
) -> tuple[float, float, float]:
    """Add one band point (`u` along the approach, `v` along the closing) to the extremes."""
    outside = (u > tip) & (u <= limit)
    low = min(low, v if outside else math.inf)
    high = max(high, v if outside else -math.inf)
    bottom = max(bottom, u if abs(v - center) <= half else first)
    return low, high, bottom


@nb.njit(cache=True, nogil=True)
def _place_hand(
    band_u: FloatArray,
    band_v: FloatArray,
    count: int,
    first_centred: float,
    depth: float,
    half: float,
    pad: float,
    reach: float,
) -> tuple[int, float, float, float, float, float, float, float]:
    """
    Centre the hand on what its fingers pass at one finger depth (at most four rounds).

    `band_u`, `band_v` are the first `count` band points along the approach and the closing
    direction; they must hold every band point up to `reach` along the approach. Returns the
    outcome (``HAND_*``), the first contact, the tips, the hand's centre, what the fingers pass
    (low, high) and what the pads reach (low, high), all along the closing direction.
    """
    inf = math.inf
    center = 0.0
    first = first_centred
    tip = inf
    low = inf
    high = -inf
    pad_low = inf
    pad_high = -inf
    for iteration in range(4):
        if iteration > 0:
            previous = first
            # Selects, not branches: the points come in space order, not along the approach;
            # two running minima side by side.
            first = first_2 = inf
            pairs = count // 2 * 2
            for j in range(0, pairs, 2):
                first = min(first, band_u[j] if abs(band_v[j] - center) <= half else inf)
                u = band_u[j + 1]
                first_2 = min(first_2, u if abs(band_v[j + 1] - center) <= half else inf)
            if pairs < count:
                j = count - 1
                first = min(first, band_u[j] if abs(band_v[j] - center) <= half else inf)
            first = min(first, first_2)
            if first == inf:
                status = HAND_MISSED if reach == inf else HAND_BEYOND_REACH
                return status, first, tip, center, low, high, pad_low, pad_high
            if first == previous:
                # The same tip: the fingers pass what they passed (most hands stop here).
                moved = 0.5 * (low + high) - center
                center += moved
                if abs(moved) <= 1e-12 * (1.0 + half):
                    break
                continue
        tip = first + depth
        if tip > reach:
            return HAND_BEYOND_REACH, first, tip, center, low, high, pad_low, pad_high
        # What the fingers pass and, for the tip the loop ends with, what the pads reach.
        low = inf
        high = -inf
        pad_low = inf
        pad_high = -inf
        for j in range(count):
            u = band_u[j]
            v = band_v[j]
            passed = u <= tip
            reached = passed & (u >= tip - pad)
            low = min(low, v if passed else inf)
            high = max(high, v if passed else -inf)
            pad_low = min(pad_low, v if reached else inf)
            pad_high = max(pad_high, v if reached else -inf)
        moved = 0.5 * (low + high) - center
        center += moved
        if abs(moved) <= 1e-12 * (1.0 + half):
            break
    return HAND_PLACED, first, tip, center, low, high, pad_low, pad_high


@nb.njit(cache=True, nogil=True)
def _facing(normal: FloatArray, side: int, c: FloatArray, sign: float, cos_limit: float) -> bool:
    """Tell whether one pad's summed normal is within the angle of its pad (or unknown)."""
    nx = normal[3 * side]
    ny = normal[3 * side + 1]
    nz = normal[3 * side + 2]
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    if norm <= 1e-12:
        return True  # only edge points: their normals are unknown
    return sign * (nx * c[0] + ny * c[1] + nz * c[2]) >= cos_limit * norm


@nb.njit(
    'float64[:, :](float64[:, :], float64[:, :], float64[:], float64[:, :], float64[:, :], '
    'float64[:, :], float64[:], float64[:], float64[:])',
    cache=True,
    nogil=True,
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
    xs = np.ascontiguousarray(points[:, 0])
    ys = np.ascontiguousarray(points[:, 1])
    zs = np.ascontiguousarray(points[:, 2])
    across = np.empty(count)
    masked = np.empty(count)
    band_u = np.empty(count)
    band_v = np.empty(count)
    band_k = np.empty(count, dtype=np.int64)
    near_u = np.empty(count)
    near_v = np.empty(count)
    near_k = np.empty(count, dtype=np.int64)
    window = np.empty(count, dtype=np.int64)
    deepest = np.max(depths)
    contact = np.empty(6)
    normal = np.empty(6)
    patch = np.empty(2)
    shallowest = np.empty(2)
    half = params[P_HALF]
    pad = params[P_PAD]
    finger = params[P_LENGTH]
    cone = params[P_CONE]
    inf = math.inf
    for i in range(origins.shape[0]):
        o = origins[i]
        a = approaches[i]
        c = closings[i]
        s0 = a[1] * c[2] - a[2] * c[1]
        s1 = a[2] * c[0] - a[0] * c[2]
        s2 = a[0] * c[1] - a[1] * c[0]
        # The line in locals: the loops below store into arrays the compiler cannot tell apart
        # from the line's, and would read the line again at every point (no vector lanes).
        o0, o1, o2 = o[0], o[1], o[2]
        a0, a1, a2 = a[0], a[1], a[2]
        c0, c1, c2 = c[0], c[1], c[2]
        # The distances across first (a loop the compiler vectorizes), then the band; with a
        # palm, the nearest point in front of it (it stops the fingertips at most the fingers'
        # length past that point): each point's distance in front or inf, then the least.
        palm_first = inf
        if params[P_PALM_HALF_WIDTH] > 0.0:
            palm_x = params[P_PALM_HALF_DEPTH]
            palm_y = params[P_PALM_HALF_WIDTH]
            for k in range(count):
                dx = xs[k] - o0
                dy = ys[k] - o1
                dz = zs[k] - o2
                side = dx * s0 + dy * s1 + dz * s2
                along = dx * a0 + dy * a1 + dz * a2
                closing = dx * c0 + dy * c1 + dz * c2
                across[k] = side
                in_front = (abs(side) <= palm_x) & (abs(closing) <= palm_y)
                masked[k] = along if in_front else inf
            palm_first = _least(masked, count)
        else:
            for k in range(count):
                across[k] = (xs[k] - o0) * s0 + (ys[k] - o1) * s1 + (zs[k] - o2) * s2
        # The band, and the first contact of a hand centred on the line (the same for every
        # finger depth).
        # Compactions here go without branches (a branch on where a point lies mispredicts:
        # the points come in space order): each index is written at the end of the list,
        # which moves on only for a point that belongs.
        n = 0
        for k in range(count):
            band_k[n] = k
            n += abs(across[k]) <= pad / 2.0
        tip_palm = palm_first + params[P_LENGTH] - params[P_PALM_MARGIN]
        for j in range(n):
            k = band_k[j]
            dx = xs[k] - o0
            dy = ys[k] - o1
            dz = zs[k] - o2
            u = dx * a0 + dy * a1 + dz * a2
            v = dx * c0 + dy * c1 + dz * c2
            band_u[j] = u
            band_v[j] = v
            masked[j] = u if abs(v) <= half else inf
        first_centred = _least(masked, n)
        if first_centred == inf:
            continue
        # The hand reaches little of the band: the points up to `reach` along the approach, in
        # band order, are all the loops below need unless centring moves the first contact
        # further than REACH_SLACK pads (then the whole band is used).
        reach = first_centred + deepest + params[P_REACH_SLACK]
        m = 0
        for j in range(n):
            near_u[m] = band_u[j]
            near_v[m] = band_v[j]
            near_k[m] = band_k[j]
            m += band_u[j] <= reach
        best = -inf
        last_tip = inf
        cu = c[0] * up[0] + c[1] * up[1] + c[2] * up[2]
        su = s0 * up[0] + s1 * up[1] + s2 * up[2]
        au = a[0] * up[0] + a[1] * up[1] + a[2] * up[2]
        # The hand's lowest point below its fingertips' centre (along up): the open fingers
        # and the palm behind them.
        finger_low = -(half + params[P_THICKNESS]) * abs(cu) - pad / 2.0 * abs(su)
        finger_low += min(0.0, -finger * au)
        lowest = finger_low
        if params[P_PALM_HALF_WIDTH] > 0.0:
            palm_low = -params[P_PALM_HALF_WIDTH] * abs(cu) - params[P_PALM_HALF_DEPTH] * abs(su)
            palm_low += min(-finger * au, -(finger + params[P_PALM_HEIGHT]) * au)
            lowest = min(lowest, palm_low)
        for di in range(depths.shape[0]):
            depth = depths[di]
            placed = (HAND_MISSED, inf, inf, 0.0, inf, -inf, inf, -inf)
            used_u, used_v, used_k, used = near_u, near_v, near_k, m
            # Placed at this depth, then as deep as the palm and the support allow (twice).
            for _attempt in range(3):
                used_u, used_v, used_k, used = near_u, near_v, near_k, m
                placed = _place_hand(
                    used_u, used_v, used, first_centred, depth, half, finger, reach
                )
                if placed[0] == HAND_BEYOND_REACH:
                    used_u, used_v, used_k, used = band_u, band_v, band_k, n
                    placed = _place_hand(
                        used_u, used_v, used, first_centred, depth, half, finger, inf
                    )
                if placed[0] != HAND_PLACED:
                    break
                limit = tip_palm
                if params[P_FLOOR] > -inf and au < -1e-9:
                    base = (o[0] + placed[3] * c[0]) * up[0]
                    base += (o[1] + placed[3] * c[1]) * up[1]
                    base += (o[2] + placed[3] * c[2]) * up[2]
                    floor = params[P_FLOOR] + params[P_SUPPORT_CLEARANCE]
                    limit = min(limit, (floor - base - lowest) / au)
                excess = placed[2] - limit
                if excess <= 1e-9:
                    break
                depth -= excess
                if depth < params[P_MIN_DEPTH]:
                    placed = (HAND_MISSED, inf, inf, 0.0, inf, -inf, inf, -inf)
                    break
            status, first, tip, center, low, high, pad_low, pad_high = placed
            if status != HAND_PLACED or placed[2] - 1e-9 > limit:
                continue
            if abs(tip - last_tip) <= 1e-9:
                continue  # clamped to the same tip as the previous depth
            last_tip = tip
            # The fingers pass everything they reach with clearance (else they collide).
            clearance = half - max(high - center, center - low)
            if clearance < params[P_MIN_CLEAR]:
                continue
            # Contacts: where each pad (the finger's last `pad` before the tip) first touches.
            if pad_high - pad_low < params[P_MIN_WIDTH]:
                continue
            contact[:] = 0.0
            shallowest[:] = inf
            normal[:] = 0.0
            patch[:] = 0.0
            # The points the pads reach, in band order (so the sums below add in that order).
            reached = 0
            for j in range(used):
                u = used_u[j]
                window[reached] = j
                reached += (u >= tip - finger) & (u <= tip)
            # The supports' sums by selects (adding 0.0 leaves a sum as it is): whether a point
            # lies within the wider support tolerance of a pad is as likely as not, and a branch
            # on it mispredicts. Few points touch a pad: that stays a branch.
            support_plus = 0.0
            support_minus = 0.0
            support_tolerance = params[P_SUPPORT_TOLERANCE]
            touch_tolerance = params[P_TOLERANCE]
            for q in range(reached):
                j = window[q]
                v = used_v[j]
                k = used_k[j]
                gap_plus = pad_high - v
                gap_minus = v - pad_low
                weight = weights[k]
                support_plus += weight if gap_plus <= support_tolerance else 0.0
                support_minus += weight if gap_minus <= support_tolerance else 0.0
                if gap_plus > touch_tolerance and gap_minus > touch_tolerance:
                    continue
                for side in range(2):
                    if (gap_plus if side == 0 else gap_minus) > touch_tolerance:
                        continue
                    sign = 1.0 if side == 0 else -1.0
                    facing = normals[k, 0] * c[0] + normals[k, 1] * c[1] + normals[k, 2] * c[2]
                    flip = sign if facing * sign >= 0.0 else -sign
                    for axis in range(3):
                        contact[3 * side + axis] += points[k, axis]
                        normal[3 * side + axis] += flip * normals[k, axis] * sign
                    patch[side] += 1.0
                    shallowest[side] = min(shallowest[side], used_u[j])
            for axis in range(6):
                contact[axis] /= patch[axis // 3]
            # A pad that touches where the object is widest within its reach (nothing just
            # past the fingertips stands out further on its side) lies flat on it: the contact
            # normal is the pad's, whatever the estimated normals of an edge say. A pad whose
            # tip touches the slope of a bulge beyond it pushes along the surface's normal.
            # Two points a step, each into its own extremes: twice the chains side by side.
            beyond_limit = tip + params[P_BEYOND]
            beyond_low = beyond_low_2 = inf
            beyond_high = beyond_high_2 = -inf
            bottom = bottom_2 = first
            pairs = n // 2 * 2
            for j in range(0, pairs, 2):
                beyond_low, beyond_high, bottom = _beyond_step(
                    band_u[j], band_v[j], tip, beyond_limit, center, half, first,
                    beyond_low, beyond_high, bottom,
                )  # fmt: skip
                beyond_low_2, beyond_high_2, bottom_2 = _beyond_step(
                    band_u[j + 1], band_v[j + 1], tip, beyond_limit, center, half, first,
                    beyond_low_2, beyond_high_2, bottom_2,
                )  # fmt: skip
            for j in range(pairs, n):
                beyond_low, beyond_high, bottom = _beyond_step(
                    band_u[j], band_v[j], tip, beyond_limit, center, half, first,
                    beyond_low, beyond_high, bottom,
                )  # fmt: skip
            beyond_low = min(beyond_low, beyond_low_2)
            beyond_high = max(beyond_high, beyond_high_2)
            bottom = max(bottom, bottom_2)
            # Only where the pad touches above its tip: a touch at the tip alone may be the
            # slope of a bulge the view does not show.
            if params[P_BEYOND] > 0.0:
                above = tip - params[P_BEYOND]
                if params[P_TIP_CLEAR] == inf:
                    above = inf
                elif params[P_TIP_CLEAR] > 0.0 and params[P_FLOOR] > -inf:
                    # The lenient pass: a tip this near the support leaves no room below it
                    # for a bulge, so a touch at the tip lies flat too.
                    height = (o[0] + tip * a[0] + center * c[0]) * up[0]
                    height += (o[1] + tip * a[1] + center * c[1]) * up[1]
                    height += (o[2] + tip * a[2] + center * c[2]) * up[2]
                    if height - params[P_FLOOR] <= params[P_TIP_CLEAR]:
                        above = inf
                # ... and whose points face the pad roughly (a face at a steep angle to the pad
                # is met by the pad's edge, as at a box's edge).
                facing_plus = _facing(normal, 0, c, 1.0, params[P_FLAT_COS])
                facing_minus = _facing(normal, 1, c, -1.0, params[P_FLAT_COS])
                flat_plus = beyond_high <= pad_high + params[P_TOLERANCE] and facing_plus
                if flat_plus and shallowest[0] <= above:
                    for axis in range(3):
                        normal[axis] = c[axis]
                flat_minus = beyond_low >= pad_low - params[P_TOLERANCE] and facing_minus
                if flat_minus and shallowest[1] <= above:
                    for axis in range(3):
                        normal[3 + axis] = -c[axis]
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
                tip_height = (o[0] + tip * a[0] + center * c[0]) * up[0]
                tip_height += (o[1] + tip * a[1] + center * c[1]) * up[1]
                tip_height += (o[2] + tip * a[2] + center * c[2]) * up[2]
                final = tip_height + lowest
                before = final - (tip - first + params[P_STANDOFF]) * au
                if min(final, before) < params[P_FLOOR] + params[P_SUPPORT_CLEARANCE]:
                    continue
            margin = 1.0 - worst / cone if cone > 0.0 else 0.0
            held = min(support_plus, support_minus) / params[P_EXPECTED]
            # Coverage: the share of the object between the fingers (along the approach, up to
            # the fingers' reach) that the pads go down over.
            span = min(bottom - first, finger - params[P_PALM_MARGIN])
            coverage = min(1.0, (tip - first) / span) if span > 1e-12 else 1.0
            quality = (
                params[P_W_MARGIN] * margin
                + params[P_W_SUPPORT] * min(1.0, held)
                + params[P_W_CLEARANCE] * min(1.0, clearance / params[P_CLEAR_REF])
                + params[P_W_COVERAGE] * coverage
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
            row[COL_COVERAGE] = coverage
            if params[P_VALID_ONLY] > 0.0:
                break  # whether the line holds is known: the first depth that holds says it
    return out


def _parameters(
    settings: RefinementSettings,
    view: GraspView,
    cell: float,
    floor: float,
    lenient: bool = False,
    held: bool = False,
    valid_only: bool = False,
) -> FloatArray:
    """Return the kernel's parameter vector (entries ``P_*``) for one surface's cell and floor."""
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
    weights = (WEIGHT_MARGIN, WEIGHT_SUPPORT, WEIGHT_CLEARANCE, 0.0)
    if settings.finger_length > 0.0:
        weights = HAND_WEIGHTS
    params[P_W_MARGIN], params[P_W_SUPPORT], params[P_W_CLEARANCE], params[P_W_COVERAGE] = weights
    params[P_REACH_SLACK] = REACH_SLACK * pad
    params[P_LENGTH] = settings.finger_length if settings.finger_length > 0.0 else pad
    params[P_THICKNESS] = settings.finger_thickness
    params[P_PALM_HALF_DEPTH] = settings.palm_depth / 2.0
    params[P_PALM_HALF_WIDTH] = settings.palm_width / 2.0
    params[P_PALM_HEIGHT] = settings.palm_height
    params[P_PALM_MARGIN] = PALM_MARGIN
    params[P_BEYOND] = BEYOND_CELLS * cell if settings.finger_length > 0.0 else 0.0
    params[P_TIP_CLEAR] = LENIENT_TIP_HEIGHT if lenient else 0.0
    params[P_FLAT_COS] = math.cos(math.radians(FLAT_FACING_DEG))
    if held:
        params[P_TIP_CLEAR] = math.inf  # any tip contact lies flat
        params[P_FLAT_COS] = -1.0  # whatever the points' normals
    # Cut short only with the hand described; the pad model refuses such a depth, as before.
    params[P_MIN_DEPTH] = MIN_DEPTH_SHARE * settings.finger_depth * min(settings.depth_fractions)
    if not settings.finger_length > 0.0:
        params[P_MIN_DEPTH] = math.inf
    params[P_VALID_ONLY] = 1.0 if valid_only else 0.0
    return params


def evaluate_lines(
    model: SurfaceModel,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    settings: RefinementSettings,
    view: GraspView,
    *,
    lenient: bool = False,
    held: bool = False,
    valid_only: bool = False,
    pool: Workers | None = None,
) -> FloatArray:
    """
    Close the pad gripper along candidate lines on one surface model.

    :param model: the object's surface.
    :param origins: (C, 3) a point on each line.
    :param approaches: (C, 3) unit approach directions.
    :param closings: (C, 3) unit closing directions, perpendicular to the approaches.
    :param settings: the pads, friction and finger depth.
    :param view: the gripper's opening, standoff and the support.
    :param lenient: with the hand described and up known, take a pad that touches only at its
        tip as lying flat too when the tip is near the support (:data:`LENIENT_TIP_HEIGHT`; the
        object's fallback when no line holds otherwise).
    :param held: with the hand described, every pad touching where the object is widest in its
        reach lies flat (at the tip too, whatever the points' normals): the check of a grasp
        that held in the previous frame, whose contacts the view's noise moves by a cell.
    :param valid_only: only whether each line holds is asked: a line stops at the first finger
        depth that holds (its ``COL_VALID`` is the same; its other columns are that depth's, not
        the best depth's).
    :param pool: the workers to spread the lines over (the rows are the same with any), or
        None for the calling thread alone.
    :return: (C, :data:`EVALUATION_COLUMNS`) rows (columns ``COL_*``; invalid rows are 0).
    """
    return start_lines(
        model,
        origins,
        approaches,
        closings,
        settings,
        view,
        lenient=lenient,
        held=held,
        valid_only=valid_only,
        pool=pool,
    )()


def start_lines(
    model: SurfaceModel,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    settings: RefinementSettings,
    view: GraspView,
    *,
    lenient: bool = False,
    held: bool = False,
    valid_only: bool = False,
    pool: Workers | None = None,
) -> Callable[[], FloatArray]:
    """
    Start :func:`evaluate_lines` (the same arguments) on the pool's helpers; return its finish.

    The slices of the lines are queued for the helpers at once and the calling thread is free
    until it calls the returned function, which takes the slices no helper has started and
    returns the rows. Without helpers nothing starts: the returned function evaluates them all.
    """
    depths = settings.finger_depth * np.array(settings.depth_fractions, dtype=np.float64)
    up = np.zeros(3) if view.up is None else np.asarray(view.up, dtype=np.float64)
    params = _parameters(settings, view, model.cell, model.floor, lenient, held, valid_only)
    origin_rows = np.array(origins, dtype=np.float64, order='C')
    approach_rows = np.array(approaches, dtype=np.float64, order='C')
    closing_rows = np.array(closings, dtype=np.float64, order='C')

    def rows(part: slice) -> FloatArray:
        return _evaluate(
            model.points,
            model.normals,
            model.weights,
            np.ascontiguousarray(origin_rows[part]),
            np.ascontiguousarray(approach_rows[part]),
            np.ascontiguousarray(closing_rows[part]),
            depths,
            params,
            up,
        )

    parts = split_rows(pool, len(origin_rows))
    if pool is None or len(parts) == 1:
        return lambda: rows(slice(0, len(origin_rows)))
    # Each row depends on its own line only: slices of the lines give the same rows.
    tasks = [pool.submit(partial(rows, part)) for part in parts]
    return lambda: np.concatenate(gather(tasks))


def warm_up() -> None:
    """Run the module's kernel once on a small box (see :mod:`mvbb_ros.kernels`)."""
    grid = np.stack(np.meshgrid(*[np.linspace(-0.03, 0.03, 7)] * 3, indexing='ij'), -1)
    model = surface_model(grid.reshape(-1, 3), cell=0.01, up=(0.0, 0.0, 1.0))
    view = GraspView(gripper_max_width=0.1, standoff=0.05, up=np.array([0.0, 0.0, 1.0]))
    evaluate_lines(
        model,
        np.zeros((1, 3)),
        np.array([[0.0, 0.0, -1.0]]),
        np.array([[1.0, 0.0, 0.0]]),
        RefinementSettings(enabled=True),
        view,
    )
