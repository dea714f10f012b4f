"""
The refinement's ranking: the best distinct grasps, best first, and when two are the same.

:func:`_ranking` sorts the lines by score and keeps each that is not the same as a better one
(:func:`_distinct`, a numba kernel: centres within :data:`SAME_PADS` of the pad size, hand
frames within :data:`SAME_ANGLE_DEG`);
:func:`_pruned_ranking` gives the same ranking of the hand model's scores while evaluating the
pose-error neighbours of few lines (in batches, in the order of an upper bound of their scores).
:func:`_same` is the rule for two grasps (the previous frame's against the new list). The rules:
``docs/grasp_rules.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

from mvbb_ros.arrays import BoolArray, FloatArray, IndexArray
from mvbb_ros.common.workers import Workers
from mvbb_ros.geometry.grasping.hypotheses import Grasp
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
from mvbb_ros.geometry.grasping.scoring import _hand_quality, _robust_quality, _score
from mvbb_ros.geometry.grasping.surface import SurfaceModel
import numba as nb
import numpy as np

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


def _order(scores: FloatArray, deferred: BoolArray | None) -> IndexArray:
    """Return the lines best first: by score, the `deferred` after all others, ties in order."""
    if deferred is None or not deferred.any():
        return np.argsort(-scores, kind='stable')
    return np.lexsort((-scores, deferred))  # stable: ties keep the lines' order


def _ranking(
    centers: FloatArray,
    approaches: FloatArray,
    closings: FloatArray,
    scores: FloatArray,
    settings: RefinementSettings,
    limit: int,
    deferred: BoolArray | None = None,
) -> tuple[IndexArray, FloatArray]:
    """
    Return the lines to publish (indices, best first) and their scores.

    The best `limit` + 1 distinct grasps (:func:`_distinct`; one more than published, for the
    previous frame's grasp to replace), ties kept in the lines' order; the `deferred` lines
    (on objects cut by the view's edge) after all others.
    """
    ranked = _order(scores, deferred)
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
    deferred: BoolArray | None = None,
) -> tuple[FloatArray, IndexArray, FloatArray]:
    """
    Return :func:`_ranking` of the hand model's scores, evaluating few lines' neighbours.

    The same grasps and scores as scoring every line
    (:func:`~mvbb_ros.geometry.grasping.scoring._robust_quality`), cheaper: each
    line's score with all its neighbours holding bounds its score from above, so the lines are
    scored in the order of their bounds, in batches, until the ranking of the scored lines ends
    above the bound of every line not scored (those can neither enter it nor, coming later,
    remove a grasp from it). The `deferred` lines come after all others, as in
    :func:`_ranking`. The returned quality is NaN for the lines not scored.

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
    by_bound = _order(bound_scores, deferred)
    tiers = np.zeros(count, dtype=np.bool_) if deferred is None else deferred
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
            None if deferred is None else deferred[scored],
        )
        if size >= count:
            return quality, scored[picked], scores
        # Strictly above the best bound left, with room for the bound's rounding (or that
        # line and every line after it deferred, the ranking's last not).
        last, best_left = scored[picked[-1]], by_bound[size]
        if len(picked) == limit + 1 and (
            tiers[last] < tiers[best_left]
            or (tiers[last] == tiers[best_left] and scores[-1] > bound_scores[best_left] + 1e-12)
        ):
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
