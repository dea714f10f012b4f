"""
Grasps checked, refined and scored on the points: the paper's face hypotheses as seeds.

The paper's hypotheses (:func:`~mvbb_ros.geometry.grasping.hypotheses.grasp_hypotheses`) approach a
box face centre; on a curved or partly seen object that centre rarely gives two antipodal contacts.
:func:`refine_grasps` tries each seed, slid over its face and rolled a little, and more
candidates closing along every box axis (approaching along the other axes, from above and from
the sensor), on each object's surface (:mod:`mvbb_ros.geometry.grasping.surface`) with the pad
gripper of :mod:`mvbb_ros.geometry.grasping.contacts`; it keeps the feasible approaches (none from
below, none from the far side), scores what holds by its quality over small pose errors and how
near its contacts' line passes the object's centre, with the task strategy's preference, and drops
repeats. :func:`rescore_grasp` checks a previous frame's grasp
on the new points, for the hysteresis of :func:`refine_grasps`. The rules:
``docs/grasp_rules.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
import math
import weakref

from mvbb_ros.arrays import BoolArray, cross, FloatArray, IndexArray, read_only
from mvbb_ros.common.workers import Workers
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.grasping.contacts import (
    CLEARANCE_PADS,
    COL_CENTER,
    COL_CLEARANCE,
    COL_CONTACTS,
    COL_COVERAGE,
    COL_DEPTH,
    COL_FIRST,
    COL_QUALITY,
    COL_SUPPORT,
    COL_TIP,
    COL_VALID,
    COL_WIDTH,
    evaluate_lines,
    EVALUATION_COLUMNS,
)
from mvbb_ros.geometry.grasping.hypotheses import FAR_SIDE_MARGIN_DEG, Grasp, gripper_quaternions
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
from mvbb_ros.geometry.grasping.surface import SurfaceModel
import numba as nb
import numpy as np

#: Slides of the grasp centre over the face, as fractions of the face's extent across the pads.
SLIDES: tuple[float, ...] = (-0.3, -0.15, 0.0, 0.15, 0.3)
#: Approaches per closing axis, evenly turned about it from the next box axis (4: the faces).
APPROACHES_PER_AXIS = 12
#: Rolls of the closing direction about the approach, degrees.
ROLLS: tuple[float, ...] = (-20.0, 0.0, 20.0)
#: Two grasps are the same (the list keeps the better) within this share of the pad size ...
SAME_PADS = 0.5
#: ... and this angle between their hand frames (a half turn about the approach is the same).
SAME_ANGLE_DEG = 15.0


@nb.njit(
    'boolean[:](float64[:, :], float64[:, :], float64[:, :], float64, float64, int64)',
    cache=True,
    nogil=True,
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


#: The turns of the approaches about each closing axis (cosine, sine), as columns.
_TURNS = np.deg2rad(np.arange(0.0, 360.0, 360.0 / APPROACHES_PER_AXIS))
_TURN_COS = np.array([math.cos(angle) for angle in _TURNS])[:, None]
_TURN_SIN = np.array([math.sin(angle) for angle in _TURNS])[:, None]


def _frames(
    box: Box, up: FloatArray | None, view: FloatArray | None
) -> tuple[FloatArray, FloatArray]:
    """
    Return the (approach, closing) pairs of one box, (P, 3) each: closing along each box axis.

    Approaches: along the other two axes, both senses (the paper's faces), then from above
    (against `up`) and along the viewing direction `view`, each made perpendicular to the
    closing axis (skipped when nearly parallel to it).
    """
    axes = box.rotation.T
    approaches = []
    closings = []
    for k in range(3):
        closing = axes[k]
        first, second = axes[(k + 1) % 3], axes[(k + 2) % 3]
        # Each turn's products and sum, element by element, as one vector at a time would.
        turned = _TURN_COS * first + _TURN_SIN * second
        approaches.append(turned)
        closings.append(np.broadcast_to(closing, turned.shape))
        for direction in (None if up is None else -up, view):
            if direction is None:
                continue
            flat = direction - (direction @ closing) * closing
            norm = float(np.linalg.norm(flat))
            if norm >= 0.3:
                approaches.append((flat / norm)[None, :])
                closings.append(closing[None, :])
    return np.concatenate(approaches), np.concatenate(closings)


def _box_candidates(
    boxes: Sequence[Box], up: FloatArray | None, views: Sequence[FloatArray | None], pad: float
) -> _Candidates:
    """Return every box's candidate lines: frames x rolls x slides across the pads."""
    out = _Candidates()
    rolls = np.deg2rad(np.array(ROLLS))
    slides = np.array(SLIDES)
    for index, box in enumerate(boxes):
        approaches, closings = _frames(box, up, views[index])  # (P, 3)
        sides = cross(approaches, closings)
        # (P, R, 3): each closing rolled about its approach, and the side axis of each roll.
        turned = (
            np.cos(rolls)[None, :, None] * closings[:, None, :]
            + np.sin(rolls)[None, :, None] * sides[:, None, :]
        )
        across = cross(approaches[:, None, :], turned)
        reach = np.abs(across @ box.rotation) @ box.extents  # (P, R) extent across the pads
        offsets = slides * np.maximum(reach - pad, 0.0)[:, :, None]  # (P, R, S)
        origins = box.center + offsets[..., None] * across[:, :, None, :]  # (P, R, S, 3)
        count = origins.shape[1] * origins.shape[2]
        out.add(
            origins.reshape(-1, 3),
            np.repeat(approaches, count, axis=0),
            np.repeat(turned.reshape(-1, 3), len(slides), axis=0),
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


def _faces_and_rolls(
    boxes: Sequence[Box], box_index: IndexArray, approaches: FloatArray, closings: FloatArray
) -> tuple[IndexArray, IndexArray]:
    """Return each line's box face most opposed to its approach and its closing's roll (deg)."""
    faces = np.zeros(len(box_index), dtype=np.intp)
    rolls = np.zeros(len(box_index), dtype=np.intp)
    for number in np.unique(box_index):
        mine = np.flatnonzero(box_index == number)
        box = boxes[int(number)]
        normals = box.face_normals()
        face = np.argmin(approaches[mine] @ normals.T, axis=1)
        edges = box.rotation[:, (face // 2 + 1) % 3].T  # (M, 3)
        turned = cross(-normals[face], edges)
        angle = np.degrees(
            np.arctan2(
                np.einsum('ij,ij->i', closings[mine], turned),
                np.einsum('ij,ij->i', closings[mine], edges),
            )
        )
        faces[mine] = face
        rolls[mine] = np.round(angle).astype(np.intp) % 360
    return faces, rolls


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
    quaternions = read_only(gripper_quaternions(approaches, closings, view.approach_axis))
    faces, rolls = _faces_and_rolls(boxes, box_index, approaches, closings)
    # Whole columns at once; each grasp holds read-only rows of these arrays.
    positions = read_only(
        origins
        + rows[:, COL_CENTER, None] * closings
        + (rows[:, COL_FIRST, None] - view.standoff) * approaches
    )
    approaches, closings = read_only(approaches), read_only(closings)
    widths = np.minimum(rows[:, COL_WIDTH] + settings.width_margin, view.gripper_max_width)
    depths = view.standoff + rows[:, COL_DEPTH]
    return [
        Grasp(
            position=positions[i],
            quaternion=quaternions[i],
            approach=approaches[i],
            closing=closings[i],
            width=width,
            box_index=box,
            face=face,
            roll_deg=roll,
            score=score,
            object_index=number,
            depth=depth,
        )
        for i, (width, box, face, roll, score, number, depth) in enumerate(
            zip(
                widths.tolist(),
                box_index.tolist(),
                faces.tolist(),
                rolls.tolist(),
                scores.tolist(),
                objects.tolist(),
                depths.tolist(),
                strict=True,
            )
        )
    ]


def _holding_boxes(
    points: FloatArray, objects: IndexArray, boxes: Sequence[Box], box_objects: IndexArray
) -> IndexArray:
    """
    Return, per grasp point (G, 3) of object `objects[g]`, the leaf box of that object holding it.

    A grasp's line comes from one box but slides along its approach to the first contact, which
    may lie on another box of the object: the grasp belongs to the box its closing point is in
    (the one it is deepest in where leaves overlap), else to the nearest (distance to the box).
    Ties go to the lower box index.
    """
    fit = np.full((len(points), len(boxes)), -np.inf)
    for index, box in enumerate(boxes):
        mine = np.flatnonzero(objects == box_objects[index])
        if not len(mine):
            continue
        local = np.abs(box.to_local(points[mine]))
        outside = np.linalg.norm(np.maximum(local - box.half_extents, 0.0), axis=1)
        inside = np.min(box.half_extents - local, axis=1)
        fit[mine, index] = np.where(outside > 0.0, -outside, inside)
    return np.argmax(fit, axis=1)


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
    new points; its box is the box of its object that holds its closing point
    (:func:`_holding_boxes`).

    :return: the re-scored grasp, or None when it is not feasible or does not hold any more.
    """
    if not models:
        return None
    if settings.finger_length > 0.0:
        # The described hand keeps the grasp's own depth past the first contact: another of
        # the depths tried would move the fingertips by a centimetre or more.
        kept_depth = max(grasp.depth - view.standoff, 1e-6)
        settings = replace(settings, finger_depth=kept_depth, depth_fractions=(1.0,))
    # A grasp that held may have a pad touch only at its tip, or on points whose estimated
    # normals turned, in this frame's noise.
    held = settings.finger_length > 0.0
    approach = np.asarray(grasp.approach, dtype=np.float64)
    closing = np.asarray(grasp.closing, dtype=np.float64)
    side = cross(approach, closing)
    rolls = np.deg2rad(np.array(RESCORE_ROLLS))
    turned = np.cos(rolls)[:, None] * closing + np.sin(rolls)[:, None] * side
    offsets = np.array(RESCORE_SLIDES) * settings.pad_size
    origins = np.asarray(grasp.position, dtype=np.float64) + np.repeat(
        offsets[None, :, None] * cross(approach, turned)[:, None, :], 1, axis=0
    ).reshape(-1, 3)
    closings = np.repeat(turned, len(offsets), axis=0)
    approaches = np.broadcast_to(approach, closings.shape)
    before = np.asarray(grasp.position, dtype=np.float64) + grasp.depth * approach
    best: tuple[float, int, int, FloatArray] | None = None
    for number, model in enumerate(models):
        if not _feasible(approach[None, :], np.array([number]), models, view)[0]:
            continue
        rows = evaluate_lines(model, origins, approaches, closings, settings, view, held=held)
        tips = (
            origins
            + rows[:, COL_TIP][:, None] * approaches
            + rows[:, COL_CENTER][:, None] * closings
        )
        moved = np.linalg.norm(tips - before, axis=1)
        near = moved <= settings.pad_size
        quality = np.where((rows[:, COL_VALID] > 0.0) & near, rows[:, COL_QUALITY], -1.0)
        if settings.finger_length > 0.0:
            # The described hand keeps the one that moved least (a robot's same grasp).
            quality = np.where(quality >= 0.0, 1.0 - moved / settings.pad_size, -1.0)
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
        row[None, :],
        settings,
        view,
    )[0]
    tip = origin + row[COL_TIP] * approach + row[COL_CENTER] * closing
    box_numbers = np.asarray(box_objects, dtype=np.intp)
    if not np.any(box_numbers == number):
        return None
    box = int(_holding_boxes(tip[None, :], np.array([number]), boxes, box_numbers)[0])
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
#: Weight of the centring (closing line near the object's centre) in a grasp's quality.
CENTRING_WEIGHT = 0.3


def _neighbours(
    origins: FloatArray, approaches: FloatArray, closings: FloatArray, pad: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return each line's four neighbours (slid both ways, rolled both ways), (4 G, 3) each."""
    side = cross(approaches, closings)
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
    rows: FloatArray,
    settings: RefinementSettings,
    view: GraspView,
    pool: Workers | None = None,
) -> FloatArray:
    """
    Return each line's quality over pose errors, weighed with its centring.

    `rows` are the lines' own evaluations (:func:`evaluate_lines`).

    The contact quality is the mean over the line and its neighbours (0 where not held); the
    centring (:func:`_centring`) weighs :data:`CENTRING_WEIGHT`.

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
        neighbours = _neighbours(*lines, settings.pad_size)
        if settings.finger_length > 0.0:
            # The hand's score asks only whether each neighbour holds.
            near = evaluate_lines(model, *neighbours, settings, view, valid_only=True, pool=pool)
            total[mine] = _hand_quality(model, *lines, rows[mine], near, settings.pad_size, view)
            continue
        near = evaluate_lines(model, *neighbours, settings, view, pool=pool)
        quality = np.concatenate([rows[mine, COL_QUALITY], near[:, COL_QUALITY]])
        held = quality.reshape(5, len(mine)).mean(axis=0)
        centring = _centring(model, *lines, rows[mine])
        total[mine] = (1.0 - CENTRING_WEIGHT) * held + CENTRING_WEIGHT * centring
    return total


#: The hand model's score (``finger_length`` set): weights of its features, fitted on the
#: physics trial's development objects only (``docs/grasp_rules.md``), and its centre.
HAND_SCORE_WEIGHTS: dict[str, float] = {
    'support': 0.69,
    'clearance': 0.15,
    'coverage': 0.59,
    'neighbours': 0.97,
    'width': -2.57,
    'offset_side': -0.93,
    'offset_closing': -1.76,
    'closing_rise': -1.70,
}
HAND_SCORE_CENTRE = -0.28


def _hand_quality(
    model: SurfaceModel,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    rows: FloatArray,
    near: FloatArray | None,
    pad: float,
    view: GraspView,
) -> FloatArray:
    """
    Return each line's score in [0, 1] under the described hand: a logistic of its features.

    Features: the pads' support, the fingers' clearance (full from half a pad), the pads'
    coverage of the object along the approach, the share of the four neighbours (a robot's
    pose error, :func:`_neighbours`) that hold, the width over the opening, the object's
    centre's offset from the contacts' midpoint across the pads and along the closing line
    (over the object's reach), and how much the closing direction rises (with `up`).

    `near` None (the neighbours not evaluated) gives an upper bound of the score: the share of
    neighbours that hold at its most favourable (:func:`_pruned_ranking`).
    """
    count = len(origins)
    weights = HAND_SCORE_WEIGHTS
    if near is None:
        valid = np.full(count, 1.0 if weights['neighbours'] >= 0.0 else 0.0)
    else:
        valid = (near[:, COL_VALID] > 0.0).reshape(4, count).mean(axis=0)
    clearance = np.minimum(1.0, rows[:, COL_CLEARANCE] / (CLEARANCE_PADS * pad))
    centroid, reach = _centre_and_reach(model)
    contacts = rows[:, slice(COL_CONTACTS, COL_CONTACTS + 6)].reshape(count, 2, 3)
    middle = contacts.mean(axis=1)
    offset = centroid - middle
    side = cross(approaches, closings)
    # Term by term, not a matrix product: a line's score must not depend on the batch it is in.
    rise = np.zeros(count)
    if view.up is not None:
        rise = np.abs(sum(closings[:, axis] * view.up[axis] for axis in range(3)))
    z = (
        weights['support'] * rows[:, COL_SUPPORT]
        + weights['clearance'] * clearance
        + weights['coverage'] * rows[:, COL_COVERAGE]
        + weights['neighbours'] * valid
        + weights['width'] * rows[:, COL_WIDTH] / view.gripper_max_width
        + weights['offset_side'] * np.abs(np.einsum('ij,ij->i', offset, side)) / reach
        + weights['offset_closing'] * np.abs(np.einsum('ij,ij->i', offset, closings)) / reach
        + weights['closing_rise'] * rise
    )
    return 1.0 / (1.0 + np.exp(-(z - HAND_SCORE_CENTRE)))


#: Each model's centroid and reach, computed once (a cloud's scoring asks for them many times).
_CENTRES: weakref.WeakKeyDictionary[SurfaceModel, tuple[FloatArray, float]] = (
    weakref.WeakKeyDictionary()
)


def _centre_and_reach(model: SurfaceModel) -> tuple[FloatArray, float]:
    """Return the centroid of the model's points and their largest distance from it (> 0)."""
    known = _CENTRES.get(model)
    if known is not None:
        return known
    centroid = read_only(model.points.mean(axis=0))
    reach = max(float(np.linalg.norm(model.points - centroid, axis=1).max()), 1e-12)
    _CENTRES[model] = (centroid, reach)
    return centroid, reach


def _centring(
    model: SurfaceModel,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    rows: FloatArray,
) -> FloatArray:
    """
    Return how near each closing line passes the object's centre, in [0, 1].

    1 - the distance from the centroid of the surface model's points (observed and estimated)
    to the line between the contacts, over the largest distance of a point from that centroid.
    Gravity and a pushing finger twist the object about its centre of mass less the nearer
    the contacts' line passes it (the torques in the grasp's wrench space).
    """
    if not len(model.points):
        return np.zeros(len(origins))
    centroid, reach = _centre_and_reach(model)
    contacts = (
        origins + rows[:, COL_TIP][:, None] * approaches + rows[:, COL_CENTER][:, None] * closings
    )
    offset = centroid - contacts
    across = offset - np.einsum('ij,ij->i', offset, closings)[:, None] * closings
    distance = np.linalg.norm(across, axis=1)
    return np.clip(1.0 - distance / reach, 0.0, 1.0)


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
    *,
    pool: Workers | None = None,
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
    :param pool: the workers the candidate lines are spread over (the same grasps with any),
        or None for the calling thread alone.
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
            lines = (origins[mine], approaches[mine], closings[mine])
            rows[mine] = evaluate_lines(model, *lines, settings, view, pool=pool)
            if not np.any(rows[mine, COL_VALID] > 0.0) and settings.finger_length > 0.0:
                rows[mine] = evaluate_lines(model, *lines, settings, view, lenient=True, pool=pool)
    valid = np.flatnonzero(rows[:, COL_VALID] > 0.0)
    # Where each valid grasp closes, and the box of its object that holds that point.
    closes = (
        origins[valid]
        + rows[valid, COL_TIP][:, None] * approaches[valid]
        + rows[valid, COL_CENTER][:, None] * closings[valid]
    )
    box_index[valid] = _holding_boxes(closes, objects[valid], boxes, objects_of_boxes)
    preference = _box_preferences(boxes, view)[box_index[valid]]
    limit = view.max_grasps if view.max_grasps > 0 else len(valid)
    holding = (objects[valid], origins[valid], approaches[valid], closings[valid], rows[valid])
    if settings.finger_length > 0.0 and view.max_grasps > 0:
        quality, picked, scores = _pruned_ranking(
            models, *holding, closes, preference, settings, view, limit, pool
        )
    else:
        quality = _robust_quality(models, *holding, settings, view, pool)
        picked, scores = _ranking(
            closes,
            approaches[valid],
            closings[valid],
            _score(quality, preference, settings),
            settings,
            limit,
        )
    rows[valid, COL_QUALITY] = quality
    order = valid[picked]
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


def _ranking(
    centers: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    scores: FloatArray,
    settings: RefinementSettings,
    limit: int,
) -> tuple[IndexArray, FloatArray]:
    """
    Return the lines to publish (indices, best first) and their scores.

    The best `limit` + 1 distinct grasps (:func:`_distinct`; one more than published, for the
    previous frame's grasp to replace), ties kept in the lines' order.
    """
    ranked = np.argsort(-scores, kind='stable')
    distinct = _distinct(
        np.ascontiguousarray(centers[ranked]),
        np.ascontiguousarray(approaches[ranked]),
        np.ascontiguousarray(closings[ranked]),
        SAME_PADS * settings.pad_size,
        math.cos(math.radians(SAME_ANGLE_DEG)),
        limit + 1,
    )
    return ranked[distinct], scores[ranked][distinct]


#: The lines whose neighbours :func:`_pruned_ranking` evaluates first, per grasp published.
PRUNE_BATCH = 4
#: Each later batch adds this share of the lines scored so far (at least one ranking's worth):
#: a ranking settled a little after the first batch scores little more than it needs.
PRUNE_GROWTH = 0.25


def _pruned_ranking(
    models: Sequence[SurfaceModel],
    objects: IndexArray,
    origins: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    rows: FloatArray,
    centers: FloatArray,
    preference: FloatArray,
    settings: RefinementSettings,
    view: GraspView,
    limit: int,
    pool: Workers | None = None,
) -> tuple[FloatArray, IndexArray, FloatArray]:
    """
    Return :func:`_ranking` of the hand model's scores, evaluating few lines' neighbours.

    The same grasps and scores as scoring every line (:func:`_robust_quality`), cheaper: each
    line's score with all its neighbours holding bounds its score from above, so the lines are
    scored in the order of their bounds, in batches, until the ranking of the scored lines ends
    above the bound of every line not scored (those can neither enter it nor, coming later,
    remove a grasp from it). The returned quality is NaN for the lines not scored.

    :return: each line's quality, the ranking's line indices and their scores.
    """
    count = len(origins)
    bound = np.zeros(count)
    for number, model in enumerate(models):
        mine = np.flatnonzero(objects == number)
        if len(mine):
            bound[mine] = _hand_quality(
                model,
                origins[mine],
                approaches[mine],
                closings[mine],
                rows[mine],
                None,
                settings.pad_size,
                view,
            )
    # The centring's weight and the preference enter as for the exact score (both monotone).
    bound_scores = _score(bound, preference, settings)
    by_bound = np.argsort(-bound_scores, kind='stable')
    quality = np.full(count, np.nan)
    known = np.zeros(count, dtype=np.bool_)
    size = min(count, PRUNE_BATCH * (limit + 1))
    while True:
        batch = by_bound[:size][~known[by_bound[:size]]]
        lines = (objects[batch], origins[batch], approaches[batch], closings[batch], rows[batch])
        quality[batch] = _robust_quality(models, *lines, settings, view, pool)
        known[batch] = True
        scored = np.flatnonzero(known)  # in the lines' order: ties break as without pruning
        picked, scores = _ranking(
            centers[scored],
            approaches[scored],
            closings[scored],
            _score(quality[scored], preference[scored], settings),
            settings,
            limit,
        )
        if size >= count:
            return quality, scored[picked], scores
        # Strictly above the best bound left, with room for the bound's rounding.
        if len(picked) == limit + 1 and scores[-1] > bound_scores[by_bound[size]] + 1e-12:
            return quality, scored[picked], scores
        size = min(count, size + max(limit + 1, int(PRUNE_GROWTH * size)))


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
    """Run the module's kernel once (see :mod:`mvbb_ros.kernels`)."""
    lines = np.eye(3)
    _distinct(lines, lines, lines, 0.01, 0.9, 3)
