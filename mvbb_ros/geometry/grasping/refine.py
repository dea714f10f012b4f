"""
Grasps checked, refined and scored on the points: the paper's face hypotheses as seeds.

The paper's hypotheses (:func:`~mvbb_ros.geometry.grasping.hypotheses.grasp_hypotheses`) approach a
box face centre; on a curved or partly seen object that centre rarely gives two antipodal contacts.
:func:`refine_grasps` tries each seed, slid over its face and rolled a little, and more
candidates closing along every box axis (approaching along the other axes, from above and from
the sensor; :mod:`mvbb_ros.geometry.grasping.candidates`), on each object's surface
(:mod:`mvbb_ros.geometry.grasping.surface`) with the pad gripper of
:mod:`mvbb_ros.geometry.grasping.contacts`; it keeps the feasible approaches (none from below,
none from the far side), scores what holds by its quality over small pose errors and how near its
contacts' line passes the object's centre, with the task strategy's preference
(:mod:`mvbb_ros.geometry.grasping.scoring`), and drops repeats
(:mod:`mvbb_ros.geometry.grasping.ranking`). :func:`rescore_grasp` checks a previous frame's grasp
on the new points, for the hysteresis of :func:`refine_grasps`. The rules:
``docs/grasp_rules.md``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

from mvbb_ros.arrays import cross, FloatArray, IndexArray, read_only
from mvbb_ros.common.workers import Workers
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.grasping.candidates import (
    _box_candidates,
    _Candidates,
    _faces_and_rolls,
    _feasible,
    _seed_candidates,
)
from mvbb_ros.geometry.grasping.contacts import (
    COL_CENTER,
    COL_DEPTH,
    COL_FIRST,
    COL_QUALITY,
    COL_TIP,
    COL_VALID,
    COL_WIDTH,
    evaluate_lines,
    EVALUATION_COLUMNS,
    start_lines,
)
from mvbb_ros.geometry.grasping.hypotheses import Grasp, gripper_quaternions
from mvbb_ros.geometry.grasping.ranking import _pruned_ranking, _ranking, _same
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
from mvbb_ros.geometry.grasping.scoring import _box_preferences, _robust_quality, _score
from mvbb_ros.geometry.grasping.surface import SurfaceModel
import numpy as np


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


@dataclass
class _Lines:
    """Candidate lines that :func:`_feasible` kept, with their box and the object they check."""

    origins: FloatArray
    approaches: FloatArray
    closings: FloatArray
    box_index: IndexArray
    objects: IndexArray

    def per_object(self, models: Sequence[SurfaceModel]) -> list[tuple[IndexArray, SurfaceModel]]:
        """Return, per object with lines, the lines' indices and the object's surface."""
        numbered = ((np.flatnonzero(self.objects == n), model) for n, model in enumerate(models))
        return [(mine, model) for mine, model in numbered if len(mine)]

    def lines(self, mine: IndexArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Return the origins, approaches and closing directions of the lines `mine`."""
        return self.origins[mine], self.approaches[mine], self.closings[mine]


def _feasible_lines(
    candidates: _Candidates,
    objects_of_boxes: IndexArray,
    models: Sequence[SurfaceModel],
    view: GraspView,
) -> _Lines:
    """Return the candidates whose approach :func:`_feasible` allows."""
    origins, approaches, closings, box_index = candidates.arrays()
    objects = objects_of_boxes[box_index]
    keep = _feasible(approaches, objects, models, view)
    return _Lines(origins[keep], approaches[keep], closings[keep], box_index[keep], objects[keep])


def _holding_boxes(
    points: FloatArray, objects: IndexArray, boxes: Sequence[Box], box_objects: IndexArray
) -> IndexArray:
    """
    Return, per grasp point (G, 3) of object `objects[g]`, the leaf box of that object holding it.

    A grasp's line comes from one box but slides along its approach to the first contact, which
    may lie on another box of the object: the grasp belongs to the box its closing point is in
    (the one it is deepest in where leaves overlap), else to the nearest (distance to the box).
    Ties go to the lower box index. The best box so far is kept per point, not a (G, boxes)
    table: a frame of hundreds of objects has hundreds of thousands of grasps and boxes.
    """
    best = np.full(len(points), -np.inf)
    holding = np.zeros(len(points), dtype=np.intp)
    for index, box in enumerate(boxes):
        mine = np.flatnonzero(objects == box_objects[index])
        if not len(mine):
            continue
        local = np.abs(box.to_local(points[mine]))
        outside = np.linalg.norm(np.maximum(local - box.half_extents, 0.0), axis=1)
        inside = np.min(box.half_extents - local, axis=1)
        fit = np.where(outside > 0.0, -outside, inside)
        better = fit > best[mine]  # strictly: an equal fit keeps the lower index
        best[mine[better]] = fit[better]
        holding[mine[better]] = index
    return holding


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


def refine_grasps(
    seeds: Sequence[Grasp] | Callable[[], Sequence[Grasp]],
    boxes: Sequence[Box],
    box_objects: Sequence[int],
    models: Sequence[SurfaceModel],
    settings: RefinementSettings,
    view: GraspView,
    previous: Grasp | None = None,
    *,
    pool: Workers | None = None,
    deferred: Sequence[int] = (),
) -> RefinedGrasps:
    """
    Return grasps checked and scored on the points, best first (the rules: docs/grasp_rules.md).

    :param seeds: the paper's hypotheses on `boxes` (:func:`grasp_hypotheses`), or a function
        that makes them: it is called while the pool's helpers check the boxes' own lines.
    :param boxes: every object's leaf boxes (the seeds' ``box_index`` indexes them).
    :param box_objects: the object (index into `models`) of each box.
    :param models: each object's surface (:func:`surface_model`).
    :param settings: the refinement's settings.
    :param view: the gripper, the view and the filters.
    :param previous: the previous frame's top grasp (same frame of reference), or None; it
        stays on top while it holds and scores within ``settings.hysteresis`` of the best.
    :param pool: the workers the candidate lines are spread over (the same grasps with any),
        or None for the calling thread alone.
    :param deferred: objects (indices into `models`) the view's edge cuts: their grasps come
        after all others, and a previous grasp on one does not stay above a whole object's.
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
    # The boxes' own lines first: their check starts on the helpers while the seeds are made.
    generated = _feasible_lines(
        _box_candidates(boxes, view.up, views, settings.pad_size), objects_of_boxes, models, view
    )
    started = [
        (mine, start_lines(model, *generated.lines(mine), settings, view, pool=pool))
        for mine, model in generated.per_object(models)
    ]
    if callable(seeds):
        seeds = seeds()
    own = _feasible_lines(
        _seed_candidates(seeds, boxes, settings.pad_size), objects_of_boxes, models, view
    )
    seed_rows = np.zeros((len(own.origins), EVALUATION_COLUMNS))
    for mine, model in own.per_object(models):
        seed_rows[mine] = evaluate_lines(model, *own.lines(mine), settings, view, pool=pool)
    box_rows = np.zeros((len(generated.origins), EVALUATION_COLUMNS))
    for mine, finish in started:
        box_rows[mine] = finish()
    # The seeds' lines, then the boxes' (the order ties are broken in).
    origins = np.concatenate([own.origins, generated.origins])
    approaches = np.concatenate([own.approaches, generated.approaches])
    closings = np.concatenate([own.closings, generated.closings])
    box_index = np.concatenate([own.box_index, generated.box_index])
    objects = np.concatenate([own.objects, generated.objects])
    rows = np.concatenate([seed_rows, box_rows])
    for number, model in enumerate(models):
        mine = np.flatnonzero(objects == number)
        if len(mine) and not np.any(rows[mine, COL_VALID] > 0.0) and settings.finger_length > 0.0:
            lines = (origins[mine], approaches[mine], closings[mine])
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
    cut = np.isin(objects[valid], np.asarray(deferred, dtype=np.intp)) if deferred else None
    if settings.finger_length > 0.0 and view.max_grasps > 0:
        quality, picked, scores = _pruned_ranking(
            models, *holding, closes, preference, settings, view, limit, pool, cut
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
            cut,
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
        stays = kept is not None
        if kept is not None and grasps:
            # Whole objects' grasps before cut objects' (deferred), then the score's margin.
            kept_cut, best_cut = (g.object_index in deferred for g in (kept, grasps[0]))
            stays = kept_cut < best_cut or (
                kept_cut == best_cut and kept.score + settings.hysteresis >= grasps[0].score
            )
        if kept is not None and stays:
            rest = [g for g in grasps if not _same(g, kept, settings)]
            result.grasps = [kept, *rest]
            result.kept_previous = True
    result.grasps = result.grasps[:limit]
    return result
