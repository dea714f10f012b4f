"""
A holding line's score: its quality over pose errors, its centring, the strategy's preference.

:func:`_robust_quality` evaluates each line's four neighbours (slid across the pads and rolled
a little: a robot's pose error, :func:`_neighbours`) with
:func:`~mvbb_ros.geometry.grasping.contacts.evaluate_lines` and weighs their mean contact quality
with how near the contacts' line passes the object's centre (:func:`_centring`); with the hand's
fingers known (``finger_length``) it is the hand model's logistic of the line's features
(:func:`_hand_quality`). :func:`_score` weighs in the box's preference under the task strategy
(:func:`_box_preferences`). The rules: ``docs/grasp_rules.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
import math
import weakref

from mvbb_ros.arrays import cross, FloatArray, IndexArray, read_only
from mvbb_ros.common.workers import Workers
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.grasping.contacts import (
    CLEARANCE_PADS,
    COL_CENTER,
    COL_CLEARANCE,
    COL_CONTACTS,
    COL_COVERAGE,
    COL_QUALITY,
    COL_SUPPORT,
    COL_TIP,
    COL_VALID,
    COL_WIDTH,
    evaluate_lines,
)
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
from mvbb_ros.geometry.grasping.surface import SurfaceModel
import numpy as np

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
    neighbours that hold at its most favourable
    (:func:`~mvbb_ros.geometry.grasping.ranking._pruned_ranking`).
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


def _score(
    quality: FloatArray, preference: FloatArray, settings: RefinementSettings
) -> FloatArray:
    """Return the score in [0, 1]: the quality, with the strategy's preference weighed in."""
    weight = settings.preference
    return np.clip((1.0 - weight) * quality + weight * preference, 0.0, 1.0)
