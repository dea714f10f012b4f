"""
The proving ground's benchmark (issue 36): contenders' grasps tried in a physics trial.

    .venv/bin/python benchmarks/physics.py --quick      # 50 views with cgn, 100 without
    .venv/bin/python benchmarks/physics.py --set validation --objects 100 --views 3
    .venv/bin/python benchmarks/physics.py --set shared --views 10 --hand wide
    .venv/bin/python benchmarks/physics.py --meshes my_objects/ --units mm --views 5
    .venv/bin/python benchmarks/physics.py --quick --json out/physics.json --pictures out/physics

What runs: each object (pybullet_data's random objects, split by name into a development set
000-499 and a validation set 500-999 that no rule or constant is tuned on; the shared meshes; or
every PLY/OBJ/STL of a folder) rests on the table where the physics engine settled it
(:func:`mvbb_ros.evaluation.physics.trial.settle`). The project's depth camera renders single
views of it from seeded random viewpoints (:mod:`mvbb_ros.evaluation.physics.views`). Each
contender gets the same view and proposes grasp poses, best first:

* ``node``: the node's pipeline with its defaults (``PipelineSettings()``), the view's up
  direction passed as ``up_direction`` (what a robot with TF knows: the benchmark of
  ``benchmarks/views.py`` calls it ``node+up``) and the hand's opening as ``gripper_max_width``;
* ``paper``: the paper's algorithm (``PipelineSettings.paper()``: face-centre grasps, no up
  direction) with the hand's opening, tried as the paper executed it in GraspIt! (the hand moves
  along the face's approach line until it touches the object, backs off a little and closes:
  the trial's ``approach='until_contact'``, :data:`TRIAL_APPROACH`);
* ``primitive``: the cloud's minimum box grasped from above across its narrowest side
  (:mod:`mvbb_ros.evaluation.physics.primitive`, the rule of ROS's ``simple_grasping``);
* ``cgn``: Contact-GraspNet in its own virtual environment, fed the z-up world-frame scene and the
  object's points (skipped with a message when its environment is missing).

A contender's first five grasps are tried in the physics trial, best first, until one holds
(:func:`mvbb_ros.evaluation.physics.trial.try_grasp`: the hand fully open, approach, close, lift,
shake). Top-1: the first grasp holds; top-5: one of the first five does; a view without grasps
fails both. The
table gives both with 95 % Wilson intervals per set and contender, and the contender's time per
view (proposing only, not the trial). The same grasps are judged by the project's analytic pad
judge (:func:`mvbb_ros.evaluation.grasp_judge.judge_grasps`, pads of the hand's opening, the table
as support): agreement with the trial and a confusion table.

Node grasps are tried at their fingertip point: the published pose's origin moved ``depth`` along
the approach (``docs/grasp_rules.md``), the point where the node means the fingertips to stop.
Every contender but ``paper`` is tried with the trial's default approach (the fingers close at
the given pose).

``--pose-error MM,DEG`` tries each grasp as a robot with that pose error would: the pose is
turned about its origin by a random rotation vector and shifted by a random offset (normal, the
given standard deviations per axis), drawn from the seed, the object and the view, so every
contender's k-th grasp of a view meets the same error (:func:`pose_errors`).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
import contextlib
import dataclasses
from dataclasses import dataclass, field
import json
import math
from pathlib import Path
import subprocess
import sys
import time
from typing import Any

from mvbb_ros.evaluation.shared_data import shared_data_folder

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = shared_data_folder()

#: Grasps tried per view and contender ("one of the top five").
TOP_K = 5
#: Every contender, in table order.
CONTENDERS = ('node', 'node_scene', 'node_lighter', 'paper', 'primitive', 'cgn')
#: Contenders run only when named in ``--contenders``.
ON_REQUEST = ('node_lighter',)
#: The object sets by name (``--meshes DIR`` adds one named after the folder).
SETS = ('development', 'validation', 'shared')
#: Quick mode: objects per random set and views per object (about 100 views), and the views
#: per object when Contact-GraspNet runs (seconds a view on a CPU: 50 views, under 10 minutes).
QUICK_OBJECTS, QUICK_VIEWS, QUICK_VIEWS_CGN = 25, 4, 2
#: Full mode: objects per random set and views per object (300 views a set).
FULL_OBJECTS, FULL_VIEWS = 100, 3
#: Failures drawn in the montage.
MONTAGE_PANELS = 24
#: Stage name of a view where the contender proposed nothing.
NO_GRASP = 'no grasp'
#: Contenders whose poses name only an approach line, and the trial's approach for them (the
#: others: the trial's default, ``'to_pose'``). The paper executed a face hypothesis in GraspIt!
#: by approaching along the face normal until contact, retreating a small distance and closing
#: (Huebner et al. 2008, section IV).
TRIAL_APPROACH = {'paper': 'until_contact'}
#: Contenders whose failures ``--pictures`` draws.
PICTURED = ('node', 'paper')


# Contenders ----------------------------------------------------------------------------------


def fingertip_pose(grasp: Any) -> Any:
    """Return a node grasp as a 4x4 pose (cloud frame) at its fingertips' stopping point."""
    from mvbb_ros.evaluation.physics.views import grasp_matrix
    import numpy as np

    approach = np.asarray(grasp.approach, dtype=np.float64)
    tip = np.asarray(grasp.position, dtype=np.float64) + float(grasp.depth) * approach
    return grasp_matrix(tip, approach, grasp.closing)


def hand_parameters(hand: Any) -> dict[str, float]:
    """Return the node parameters that describe `hand` (its opening, fingers and palm)."""
    return {
        'gripper_max_width': float(hand.max_opening),
        'finger_length': float(hand.finger_depth),
        'finger_pad_size': float(hand.pad_width),
        'finger_thickness': float(hand.finger_thickness),
        'palm_width': float(hand.palm_width),
        'palm_depth': float(hand.palm_depth),
        'palm_height': float(hand.palm_height),
    }


def pipeline_settings(preset: str, hand: Any, up: Sequence[float] | None):
    """
    Return a preset's settings for `hand` (and the up direction when given).

    The node is told the whole hand (:func:`hand_parameters`); the paper only its opening.
    """
    from mvbb_ros.pipeline.settings import PRESETS

    changes: dict[str, Any] = {'gripper_max_width': float(hand.max_opening)}
    if preset == 'node':
        changes.update(hand_parameters(hand))
    if up is not None:
        changes['up_direction'] = [float(v) for v in up]
    return PRESETS[preset].updated(changes)


def node_grasps(view: Any, hand: Any) -> list[Any]:
    """Run the node (defaults, the view's up direction); return world-frame poses, best first."""
    from mvbb_ros.pipeline.process import process_points

    result = process_points(view.points, pipeline_settings('node', hand, view.up))
    return [view.poses_to_world(fingertip_pose(grasp)) for grasp in result.grasps]


def lighter_grasps(view: Any, hand: Any) -> list[Any]:
    """
    Run the node one ``frame_time_budget`` level lighter (as after a frame over the budget).

    The node's settings for the view (:func:`node_grasps`) lightened by the budget's first
    level (:func:`mvbb_ros.pipeline.budget.degraded`: voxels twice as coarse, no finer voxels
    for small objects): what a node that keeps up with a fast stream by its budget proposes.
    """
    from mvbb_ros.pipeline.budget import degraded
    from mvbb_ros.pipeline.process import process_points

    settings, _ = degraded(pipeline_settings('node', hand, view.up), 1)
    result = process_points(view.points, settings)
    return [view.poses_to_world(fingertip_pose(grasp)) for grasp in result.grasps]


def scene_grasps(view: Any, hand: Any) -> list[Any]:
    """
    Run the node on the raw scene (the object and the table around it); world poses.

    The node's scene stage finds the table (``support_plane: auto``), keeps what stands on it
    and takes the up direction and the floor under the object from it; ``up_direction`` is
    still given, as for ``node``.
    """
    from mvbb_ros.pipeline.process import process_points

    result = process_points(view.scene_points, pipeline_settings('node', hand, view.up))
    return [view.poses_to_world(fingertip_pose(grasp)) for grasp in result.grasps]


def paper_grasps(view: Any, hand: Any) -> list[Any]:
    """Return the paper's face-centre grasps (paper preset, no up), world frame, best first."""
    from mvbb_ros.pipeline.process import process_points

    result = process_points(view.points, pipeline_settings('paper', hand, None))
    return [view.poses_to_world(fingertip_pose(grasp)) for grasp in result.grasps]


def primitive_contender(view: Any, hand: Any) -> list[Any]:
    """Return the box grasped from above across its narrowest side, world frame, best first."""
    from mvbb_ros.evaluation.physics.primitive import primitive_grasps

    return primitive_grasps(view.to_world(view.points), hand_opening(hand))


class CgnContender:
    """Contact-GraspNet, started once for the whole run; ``unavailable`` says why it cannot."""

    def __init__(self, python: Path | None = None, threads: int | None = 1) -> None:
        """Start the network (`python`: its environment's Python), or record why it cannot."""
        self.unavailable: str | None = None
        self._stack = contextlib.ExitStack()
        self._net: Any = None
        try:
            from mvbb_ros.evaluation.physics.contact_graspnet import (
                ContactGraspNet,
                ContactGraspNetUnavailable,
            )
        except ImportError as error:
            self.unavailable = f'the Contact-GraspNet wrapper is not in this branch ({error})'
            return
        try:
            self._net = self._stack.enter_context(ContactGraspNet(python, threads=threads))
        except ContactGraspNetUnavailable as error:
            self.unavailable = str(error)

    def __call__(self, view: Any, hand: Any) -> list[Any]:
        """Propose grasps on the view's z-up world-frame scene: world poses, best first."""
        proposals = self._net.grasps(
            view.to_world(view.scene_points).astype('float32'),
            view.to_world(view.points).astype('float32'),
        )
        return [proposal.pose for proposal in proposals]

    def close(self) -> None:
        """Stop the network."""
        self._stack.close()


def node_steadiness(view: Any, hand: Any, frames: int, drift: float) -> tuple[int, int]:
    """
    Count the node's steady frame pairs on the same view rendered again with fresh noise.

    The frames (:func:`mvbb_ros.evaluation.physics.views.view_frames`) go through the node one
    after the other, each given the previous frame's top grasp (the node's hysteresis), moved
    into its camera frame when the camera drifts; a pair is steady when both top grasps, in
    the world frame, are the same to a robot (:func:`mvbb_ros.evaluation.grasp_judge.same_grasp`:
    1 cm, 15 degrees). Returns ``(steady pairs, pairs)``.
    """
    from dataclasses import replace
    from types import SimpleNamespace

    from mvbb_ros.evaluation.grasp_judge import steady_pairs
    from mvbb_ros.evaluation.physics.views import invert_pose, view_frames
    from mvbb_ros.pipeline.process import process_points
    import numpy as np

    tops: list[Any] = []
    previous = None
    last_pose = None
    for frame in view_frames(view, frames, drift=drift):
        if previous is not None and last_pose is not None:
            move = invert_pose(frame.camera_pose) @ last_pose  # previous camera -> this camera
            rotation, shift = move[:3, :3], move[:3, 3]
            previous = replace(
                previous,
                position=rotation @ np.asarray(previous.position) + shift,
                approach=rotation @ np.asarray(previous.approach),
                closing=rotation @ np.asarray(previous.closing),
            )
        settings = pipeline_settings('node', hand, frame.up)
        result = process_points(frame.points, settings, previous=previous)
        previous = result.grasps[0] if result.grasps else None
        last_pose = frame.camera_pose
        if previous is None:
            tops.append(None)
            continue
        pose = frame.poses_to_world(fingertip_pose(previous))
        tops.append(
            SimpleNamespace(position=pose[:3, 3], approach=pose[:3, 2], closing=pose[:3, 1])
        )
    return steady_pairs(tops)


#: Contender name -> function (view, hand) -> world-frame 4x4 poses, best first.
PROPOSERS: dict[str, Callable[[Any, Any], list[Any]]] = {
    'node': node_grasps,
    'node_scene': scene_grasps,
    'node_lighter': lighter_grasps,
    'paper': paper_grasps,
    'primitive': primitive_contender,
}


# Objects ---------------------------------------------------------------------------------------


def object_sets(args: argparse.Namespace) -> Iterator[tuple[str, list[Any]]]:
    """Yield (set name, objects) for the sets asked for on the command line."""
    from mvbb_ros.evaluation.physics import objects as physics_objects
    import numpy as np

    for name in args.sets:
        if name == 'shared':
            models = args.data / 'models'
            if not models.is_dir():
                print(f'shared meshes not found: {models} (set MVBB_SHARED_DATA); set skipped')
                continue
            items = list(physics_objects.shared_mesh_objects(args.data))
            if args.objects is not None:
                items = items[: args.objects]
            yield name, items
        else:
            low = 0 if name == 'development' else 500
            count = args.objects if args.objects is not None else args.default_objects
            rng = np.random.default_rng([args.seed, low])
            picked = sorted(
                rng.choice(np.arange(low, low + 500), size=min(count, 500), replace=False)
            )
            yield name, [physics_objects.random_object(int(i), args.seed) for i in picked]
    for folder in args.meshes:
        items = list(physics_objects.mesh_folder_objects(folder, args.units))
        if args.objects is not None:
            items = items[: args.objects]
        yield Path(folder).name or str(folder), items


# Running -------------------------------------------------------------------------------------


@dataclass
class Results:
    """Everything one run measured: per-grasp records and per-view summaries."""

    records: list[dict[str, Any]] = field(default_factory=list)
    views: list[dict[str, Any]] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    failures: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    steadiness: list[dict[str, Any]] = field(default_factory=list)


def pose_errors(
    view: Any, count: int, error: tuple[float, float] | None, seed: int
) -> list[Any] | None:
    """
    Return `count` rigid pose errors (4 x 4) for one view's ranks, or None without `error`.

    `error` is (metres, degrees): the standard deviation of the position error along each axis
    and of the rotation vector's components about the fingertips (a robot's calibration and
    control). Drawn from the seed, the object and the view only, so every contender's k-th
    grasp of a view meets the same error.
    """
    if error is None:
        return None
    import zlib

    import numpy as np
    from scipy.spatial.transform import Rotation

    key = zlib.crc32(f'{view.placed.name}/{view.index}'.encode())
    rng = np.random.default_rng([seed, key])
    errors = []
    for _ in range(count):
        moved = np.eye(4)
        moved[:3, 3] = rng.normal(0.0, error[0], 3)
        turn = rng.normal(0.0, math.radians(error[1]), 3)
        moved[:3, :3] = Rotation.from_rotvec(turn).as_matrix()
        errors.append(moved)
    return errors


def with_error(pose: Any, error: Any) -> Any:
    """Return `pose` (world) moved by `error`: turned about its own origin, then shifted."""
    moved = pose.copy()
    moved[:3, :3] = error[:3, :3] @ pose[:3, :3]
    moved[:3, 3] = pose[:3, 3] + error[:3, 3]
    return moved


def try_view(
    view: Any,
    set_name: str,
    proposers: Mapping[str, Callable[[Any, Any], list[Any]]],
    hand: Any,
    trial_settings: Any,
    target: Any,
    results: Results,
    errors: list[Any] | None = None,
) -> None:
    """
    Run every contender on one view, try their first grasps, judge them; add the rows.

    `errors` (:func:`pose_errors`, one per rank) move each grasp before its trial: what a robot
    with that pose error would do with it. The records keep the proposed pose.
    """
    from mvbb_ros.evaluation.grasp_judge import judge_grasps, PadGripper, STATUS_NAMES
    from mvbb_ros.evaluation.physics import trial
    import numpy as np

    opening = hand_opening(hand)
    base_settings = trial.DEFAULT_SETTINGS if trial_settings is None else trial_settings
    for name, propose in proposers.items():
        settings = (
            dataclasses.replace(base_settings, approach=TRIAL_APPROACH[name])
            if name in TRIAL_APPROACH
            else base_settings
        )
        start = time.perf_counter()
        proposed = [np.asarray(p, dtype=np.float64) for p in propose(view, hand)]
        poses = proposed[:TOP_K]
        seconds = time.perf_counter() - start
        start = time.perf_counter()
        # Best first, each from the same start with the hand fully open, until one holds: the
        # first success decides top-1 and top-5, the grasps after it cannot change either.
        stages, successes, advances, details = [], [], [], []
        for rank, pose in enumerate(poses):
            tried = pose if errors is None else with_error(pose, errors[rank])
            outcome = trial.try_grasp(view.placed.obj, view.placed.pose, tried, hand, settings)
            stages.append(str(outcome.stage))
            details.append(outcome.detail)
            successes.append(bool(outcome.success))
            advances.append(float(outcome.advance))
            if outcome.success:
                break
        poses = poses[: len(stages)]
        trial_seconds = time.perf_counter() - start
        judged: list[str | None] = [None] * len(poses)
        if poses and target is not None:
            stack = np.array(poses)
            verdicts = judge_grasps(
                target,
                (stack[:, :3, 3], stack[:, :3, 2], stack[:, :3, 1]),
                PadGripper(max_width=opening),
                support=(np.array([0.0, 0.0, 1.0]), 0.0),
            )
            judged = [STATUS_NAMES[int(s)] for s in verdicts.status]
        base = {'set': set_name, 'object': view.placed.name, 'view': view.index, 'contender': name}
        for rank, (pose, stage, success, judge, advance, detail) in enumerate(
            zip(poses, stages, successes, judged, advances, details, strict=True)
        ):
            results.records.append(
                {
                    **base,
                    'rank': rank,
                    'success': success,
                    'stage': stage,
                    'detail': detail,
                    'judge': judge,
                    'pose': [[round(float(v), 6) for v in row] for row in pose],
                    'advance': None if math.isnan(advance) else round(advance, 6),
                }
            )
        row = {
            **base,
            'proposed': len(proposed),
            'tried': len(poses),
            'top1': bool(successes[:1] and successes[0]),
            'top5': any(successes),
            'first_success': successes.index(True) if any(successes) else None,
            'stage': stages[0] if stages else NO_GRASP,
            'seconds': seconds,
            'trial_seconds': trial_seconds,
        }
        results.views.append(row)
        failures = results.failures.setdefault(name, [])
        if name in PICTURED and not row['top1'] and len(failures) < MONTAGE_PANELS:
            drawn = None
            if poses:
                # Where the fingers closed (or, when the trial stopped before, the given pose).
                drawn = poses[0].copy()
                if not math.isnan(advances[0]):
                    drawn[:3, 3] += advances[0] * drawn[:3, 2]
            failures.append({**row, 'view_data': view, 'pose': drawn})


def hand_opening(hand: Any) -> float:
    """Return the hand's largest opening between the fingers, metres."""
    return float(hand.max_opening)


def run(
    sets: Iterable[tuple[str, list[Any]]],
    proposers: Mapping[str, Callable[[Any, Any], list[Any]]],
    hand: Any,
    views_per_object: int,
    seed: int,
    *,
    judge: bool = True,
    steady_frames: int = 0,
    drift: float = 0.0,
    trial_settings: Any = None,
    pose_error: tuple[float, float] | None = None,
    log: Callable[[str], None] = print,
    checkpoint: Callable[[Results], None] | None = None,
) -> Results:
    """Settle each object, render its views and try every contender on them."""
    from mvbb_ros.evaluation.mesh import GraspTarget
    from mvbb_ros.evaluation.physics import trial
    from mvbb_ros.evaluation.physics.views import physics_views, PlacedObject

    results = Results()
    for set_name, objects in sets:
        for number, obj in enumerate(objects):
            start = time.perf_counter()
            placed = PlacedObject.place(obj, trial.settle(obj, seed))
            target = GraspTarget(placed.vertices, placed.triangles) if judge else None
            views = 0
            for view in physics_views(placed, views_per_object, seed=seed):
                errors = pose_errors(view, TOP_K, pose_error, seed)
                try_view(view, set_name, proposers, hand, trial_settings, target, results, errors)
                if steady_frames > 1 and 'node' in proposers:
                    same, pairs = node_steadiness(view, hand, steady_frames, drift)
                    results.steadiness.append(
                        {'set': set_name, 'object': placed.name, 'view': view.index}
                        | {'steady': same, 'pairs': pairs}
                    )
                views += 1
            log(
                f'  {set_name} {number + 1}/{len(objects)} {placed.name}: {views} views, '
                f'{time.perf_counter() - start:.1f} s'
            )
            if checkpoint is not None:
                checkpoint(results)
    return results


# Tables ------------------------------------------------------------------------------------------


def wilson(successes: int, trials: int) -> tuple[float, float]:
    """95 % Wilson interval (:func:`mvbb_ros.evaluation.physics.views.wilson_interval`)."""
    from mvbb_ros.evaluation.physics.views import wilson_interval

    return wilson_interval(successes, trials)


def summarize(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Top-1 and top-5 shares with Wilson intervals and the time per view of some view rows."""
    count = len(rows)
    top1 = sum(bool(r['top1']) for r in rows)
    top5 = sum(bool(r['top5']) for r in rows)
    return {
        'views': count,
        'top1': top1 / count if count else None,
        'top1_ci': list(wilson(top1, count)),
        'top5': top5 / count if count else None,
        'top5_ci': list(wilson(top5, count)),
        'no_grasp': sum(r['proposed'] == 0 for r in rows),
        'seconds_per_view': sum(r['seconds'] for r in rows) / count if count else None,
        'trial_seconds_per_view': sum(r['trial_seconds'] for r in rows) / count if count else None,
    }


def _share(value: float | None, interval: Sequence[float]) -> str:
    if value is None:
        return '-'
    return f'{100 * value:.0f} % [{100 * interval[0]:.0f}, {100 * interval[1]:.0f}]'


def success_table(views: Sequence[Mapping[str, Any]], contenders: Sequence[str]) -> str:
    """Markdown table: per set and contender, top-1 and top-5 with 95 % intervals, s / view."""
    header = (
        'set',
        'contender',
        'views',
        'top-1 [95 % CI]',
        'top-5 [95 % CI]',
        'no grasp',
        's / view',
    )
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    for set_name in dict.fromkeys(r['set'] for r in views):
        for name in contenders:
            rows = [r for r in views if r['set'] == set_name and r['contender'] == name]
            if not rows:
                continue
            s = summarize(rows)
            cells = (
                set_name,
                name,
                str(s['views']),
                _share(s['top1'], s['top1_ci']),
                _share(s['top5'], s['top5_ci']),
                str(s['no_grasp']),
                f'{s["seconds_per_view"]:.2f}',
            )
            lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def stage_table(views: Sequence[Mapping[str, Any]], contenders: Sequence[str]) -> str:
    """How each contender's top grasp ended: counts per trial stage."""
    stages = sorted({r['stage'] for r in views})
    lines = ['| contender | ' + ' | '.join(stages) + ' |', '|' + '---|' * (len(stages) + 1)]
    for name in contenders:
        rows = [r for r in views if r['contender'] == name]
        if rows:
            counts = [str(sum(r['stage'] == stage for r in rows)) for stage in stages]
            lines.append(f'| {name} | ' + ' | '.join(counts) + ' |')
    return '\n'.join(lines)


def judge_agreement(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """How often the analytic judge agrees with the trial, and the confusion counts."""
    judged = [r for r in records if r['judge'] is not None]
    confusion = {
        'trial holds, judge holds': sum(r['success'] and r['judge'] == 'holds' for r in judged),
        'trial holds, judge fails': sum(r['success'] and r['judge'] != 'holds' for r in judged),
        'trial fails, judge holds': sum(
            not r['success'] and r['judge'] == 'holds' for r in judged
        ),
        'trial fails, judge fails': sum(
            not r['success'] and r['judge'] != 'holds' for r in judged
        ),
    }
    agree = confusion['trial holds, judge holds'] + confusion['trial fails, judge fails']
    disagreements: dict[str, int] = {}
    for r in judged:
        if r['success'] != (r['judge'] == 'holds'):
            key = f'trial {r["stage"]} / judge {r["judge"]}'
            disagreements[key] = disagreements.get(key, 0) + 1
    return {
        'grasps': len(judged),
        'agreement': agree / len(judged) if judged else None,
        'agreement_ci': list(wilson(agree, len(judged))),
        'confusion': confusion,
        'disagreements': dict(sorted(disagreements.items(), key=lambda kv: -kv[1])),
    }


def judge_table(records: Sequence[Mapping[str, Any]], contenders: Sequence[str]) -> str:
    """Agreement of the analytic judge with the trial, per contender and in all."""
    header = (
        'contender',
        'grasps',
        'agreement [95 % CI]',
        'both hold',
        'trial only',
        'judge only',
        'both fail',
    )
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    for name in [*contenders, 'all']:
        sel = [r for r in records if name == 'all' or r['contender'] == name]
        a = judge_agreement(sel)
        if not a['grasps']:
            continue
        c = a['confusion']
        cells = (
            name,
            str(a['grasps']),
            _share(a['agreement'], a['agreement_ci']),
            str(c['trial holds, judge holds']),
            str(c['trial holds, judge fails']),
            str(c['trial fails, judge holds']),
            str(c['trial fails, judge fails']),
        )
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def report(results: Results, contenders: Sequence[str], meta: Mapping[str, Any]) -> dict[str, Any]:
    """Return the JSON record: totals per contender and set, the judge's agreement, every row."""
    views = results.views
    return {
        **meta,
        'contenders': {
            name: summarize([r for r in views if r['contender'] == name])
            for name in contenders
            if any(r['contender'] == name for r in views)
        },
        'sets': {
            set_name: {
                name: summarize(sel)
                for name in contenders
                if (sel := [r for r in views if r['set'] == set_name and r['contender'] == name])
            }
            for set_name in dict.fromkeys(r['set'] for r in views)
        },
        'judge': {
            name: judge_agreement(
                [r for r in results.records if name == 'all' or r['contender'] == name]
            )
            for name in [*contenders, 'all']
        },
        'skipped': results.skipped,
        'steadiness': steadiness_summary(results.steadiness),
        'views': views,
        'records': results.records,
    }


def steadiness_summary(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Return the node's steady share of frame pairs per set, with its Wilson interval."""
    out: dict[str, Any] = {}
    for set_name in dict.fromkeys(r['set'] for r in rows):
        same = sum(r['steady'] for r in rows if r['set'] == set_name)
        pairs = sum(r['pairs'] for r in rows if r['set'] == set_name)
        out[set_name] = {
            'steady': same / pairs if pairs else None,
            'steady_ci': list(wilson(same, pairs)),
            'pairs': pairs,
        }
    return out


def write_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write the record atomically."""
    from mvbb_ros.common.atomic import atomic_open

    with atomic_open(path) as handle:
        json.dump(data, handle, indent=1)


# Pictures --------------------------------------------------------------------------------------


def gripper_lines(pose: Any, opening: float, finger: float = 0.05) -> list[Any]:
    """Return world-frame polylines of a hand at `pose`: two fingers, the palm, the wrist."""
    from mvbb_ros.evaluation.physics.views import transform_points
    import numpy as np

    half = opening / 2.0
    local = [
        [(0.0, -half, 0.0), (0.0, -half, -finger), (0.0, half, -finger), (0.0, half, 0.0)],
        [(0.0, 0.0, -finger), (0.0, 0.0, -2.0 * finger)],
    ]
    return [transform_points(pose, np.array(line)) for line in local]


def draw_montage(failures: Sequence[Mapping[str, Any]], hand: Any, path: Path) -> int:
    """
    Draw a contender's failed views in a grid; return how many panels.

    Each panel is the view as its camera saw it (pixels): the table grey, the object coloured by
    depth, the contender's top grasp as a hand where its fingers closed (red: the open fingers,
    the palm and the wrist; none when it proposed nothing); the title names the view, the
    object's world box (x, y, z, cm) and the trial's stage.
    """
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from mvbb_ros.common.atomic import atomic_path
    from mvbb_ros.evaluation.camera import camera_intrinsics, DEFAULT_HEIGHT, DEFAULT_WIDTH
    import numpy as np

    shown = list(failures[:MONTAGE_PANELS])
    if not shown:
        return 0
    fx, fy, cx, cy = camera_intrinsics(DEFAULT_WIDTH, DEFAULT_HEIGHT)
    cols = min(6, len(shown))
    rows = math.ceil(len(shown) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 3.0 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis('off')
    for ax, failure in zip(axes.flat, shown, strict=False):
        view = failure['view_data']

        def pixels(camera_points: Any) -> Any:
            p = np.asarray(camera_points, dtype=np.float64).reshape(-1, 3)
            return fx * p[:, 0] / p[:, 2] + cx, fy * p[:, 1] / p[:, 2] + cy

        u, v = pixels(view.scene_points)
        ax.scatter(u, v, s=1.0, c='0.85', linewidths=0)
        u, v = pixels(view.points)
        ax.scatter(u, v, s=3.0, c=view.points[:, 2], cmap='viridis', linewidths=0)
        bounds = [u.min(), u.max(), v.min(), v.max()]
        if failure['pose'] is not None:
            for line in gripper_lines(failure['pose'], hand.max_opening, hand.finger_depth):
                gu, gv = pixels(view.to_camera(line))
                ax.plot(gu, gv, color='red', linewidth=1.5)
                bounds = [
                    min(bounds[0], gu.min()),
                    max(bounds[1], gu.max()),
                    min(bounds[2], gv.min()),
                    max(bounds[3], gv.max()),
                ]
        pad = max(0.15 * max(bounds[1] - bounds[0], bounds[3] - bounds[2]), 15.0)
        ax.set_xlim(bounds[0] - pad, bounds[1] + pad)
        ax.set_ylim(bounds[3] + pad, bounds[2] - pad)
        ax.set_aspect('equal')
        size = ' x '.join(f'{100 * v:.0f}' for v in view.placed.high - view.placed.low)
        ax.set_title(f'{view.name} ({size} cm)\n{failure["stage"]}', fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format='png')
    plt.close(fig)
    return len(shown)


# Command line ------------------------------------------------------------------------------------


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Parse the command line."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument(
        '--set',
        dest='sets',
        default=None,
        help='object sets, comma separated: development, validation, shared '
        '(default: validation, or none when --meshes is given)',
    )
    parser.add_argument(
        '--meshes',
        action='append',
        default=[],
        type=Path,
        metavar='DIR',
        help='a folder of PLY/OBJ/STL meshes (repeatable)',
    )
    parser.add_argument(
        '--units', choices=('m', 'mm', 'cm'), default='m', help='units of the --meshes files'
    )
    parser.add_argument(
        '--objects',
        type=int,
        default=None,
        help=f'objects per set (random sets: {FULL_OBJECTS}, quick {QUICK_OBJECTS})',
    )
    parser.add_argument(
        '--views',
        type=int,
        default=None,
        help=f'views per object ({FULL_VIEWS}; quick {QUICK_VIEWS}, {QUICK_VIEWS_CGN} with cgn)',
    )
    parser.add_argument(
        '--hand',
        choices=('franka', 'wide'),
        default='franka',
        help='franka: 8 cm opening; wide: 14 cm',
    )
    parser.add_argument(
        '--contenders',
        default=','.join(name for name in CONTENDERS if name not in ON_REQUEST),
        help='comma separated, from ' + ', '.join(CONTENDERS),
    )
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument(
        '--quick',
        action='store_true',
        help=f'{QUICK_OBJECTS} objects x {QUICK_VIEWS} views a set ({QUICK_VIEWS_CGN} with cgn)',
    )
    parser.add_argument('--no-judge', action='store_true', help='skip the analytic judge')
    parser.add_argument(
        '--steadiness',
        type=int,
        default=0,
        metavar='FRAMES',
        help="the node's steadiness over this many frames of each view (fresh noise; 0: off)",
    )
    parser.add_argument(
        '--drift',
        type=float,
        default=0.0,
        metavar='METRES',
        help='with --steadiness: the camera moves this far sideways each frame',
    )
    parser.add_argument(
        '--pose-error',
        default=None,
        metavar='MM,DEG',
        help="a robot's pose error: each tried grasp is moved by a random error of this "
        'standard deviation (millimetres along each axis, degrees about each axis); the same '
        'errors for every contender',
    )
    parser.add_argument('--json', type=Path, default=None, metavar='OUT')
    parser.add_argument(
        '--pictures',
        type=Path,
        default=None,
        metavar='DIR',
        help="write montages of the node's and the paper's failures here",
    )
    parser.add_argument(
        '--cgn-python',
        type=Path,
        default=None,
        metavar='PYTHON',
        help="Contact-GraspNet's environment (default: .venv-cgn/bin/python of this checkout)",
    )
    parser.add_argument(
        '--data', type=Path, default=DEFAULT_DATA, help='the shared data folder (for --set shared)'
    )
    args = parser.parse_args(argv)
    if args.sets is None:
        args.sets = [] if args.meshes else ['validation']
    else:
        args.sets = [s.strip() for s in args.sets.split(',') if s.strip()]
    unknown = sorted(set(args.sets) - set(SETS))
    if unknown:
        parser.error(f'unknown set {unknown}; known: {", ".join(SETS)}')
    args.contenders = [c.strip() for c in args.contenders.split(',') if c.strip()]
    unknown = sorted(set(args.contenders) - set(CONTENDERS))
    if unknown:
        parser.error(f'unknown contender {unknown}; known: {", ".join(CONTENDERS)}')
    args.default_objects = QUICK_OBJECTS if args.quick else FULL_OBJECTS
    if args.views is None:
        quick = QUICK_VIEWS_CGN if 'cgn' in args.contenders else QUICK_VIEWS
        args.views = quick if args.quick else FULL_VIEWS
    if args.objects is not None and args.objects < 1 or args.views < 1:
        parser.error('--objects and --views must be >= 1')
    if args.pose_error is not None:
        try:
            millimetres, degrees = (float(v) for v in args.pose_error.split(','))
        except ValueError:
            parser.error(f'--pose-error wants MM,DEG (e.g. 2,3), got {args.pose_error!r}')
        if not (millimetres >= 0.0 and degrees >= 0.0):
            parser.error(f'--pose-error must not be negative, got {args.pose_error!r}')
        args.pose_error = (millimetres / 1000.0, degrees)
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; print the tables; write the JSON and the montage when asked."""
    args = parse_args(argv)
    from mvbb_ros.evaluation.physics.hand import HANDS

    hand = HANDS[args.hand]
    commit = subprocess.run(
        ['git', 'log', '-1', '--format=%h %s'], capture_output=True, text=True, cwd=REPO
    ).stdout.strip()
    print(f'commit: {commit}')
    print(
        f'sets {", ".join(map(str, [*args.sets, *args.meshes]))}; {args.views} views per object; '
        f'hand {args.hand} ({100 * hand_opening(hand):.0f} cm); seed {args.seed}; '
        f'contenders {", ".join(args.contenders)}'
        + (
            ''
            if args.pose_error is None
            else f'; pose error {1000 * args.pose_error[0]:g} mm, {args.pose_error[1]:g} deg'
        )
    )
    proposers: dict[str, Callable[[Any, Any], list[Any]]] = {}
    skipped: dict[str, str] = {}
    cgn: CgnContender | None = None
    for name in args.contenders:
        if name == 'cgn':
            cgn = CgnContender(args.cgn_python)
            if cgn.unavailable is not None:
                skipped['cgn'] = cgn.unavailable
                print(f'contender cgn skipped: {cgn.unavailable}')
                cgn = None
                continue
            proposers['cgn'] = cgn
        else:
            proposers[name] = PROPOSERS[name]
    meta = {
        'commit': commit,
        'command': ' '.join(sys.argv),
        'hand': args.hand,
        'opening': hand_opening(hand),
        'views_per_object': args.views,
        'seed': args.seed,
        'top_k': TOP_K,
        'pose_error': args.pose_error,
    }
    names = list(proposers)

    def checkpoint(results: Results) -> None:
        results.skipped = skipped
        if args.json is not None:
            write_json(args.json, report(results, names, meta))

    start = time.perf_counter()
    try:
        results = run(
            object_sets(args),
            proposers,
            hand,
            args.views,
            args.seed,
            judge=not args.no_judge,
            steady_frames=args.steadiness,
            drift=args.drift,
            pose_error=args.pose_error,
            log=lambda message: print(message, file=sys.stderr, flush=True),
            checkpoint=checkpoint,
        )
    finally:
        if cgn is not None:
            cgn.close()
    results.skipped = skipped
    meta['seconds'] = time.perf_counter() - start
    print()
    print(success_table(results.views, names))
    print('\nHow the top grasp ended (trial stage):\n')
    print(stage_table(results.views, names))
    if not args.no_judge:
        print('\nThe analytic judge against the trial (every tried grasp):\n')
        print(judge_table(results.records, names))
        disagreements = judge_agreement(results.records)['disagreements']
        if disagreements:
            print('disagreements: ' + ', '.join(f'{k}: {v}' for k, v in disagreements.items()))
    for set_name, row in steadiness_summary(results.steadiness).items():
        print(
            f'\nsteadiness ({set_name}, node, {args.steadiness} frames, drift '
            f'{1000 * args.drift:.1f} mm a frame): {_share(row["steady"], row["steady_ci"])} '
            f'of {row["pairs"]} frame pairs'
        )
    print(f'\n{meta["seconds"]:.0f} s')
    if args.json is not None:
        write_json(args.json, report(results, names, meta))
        print(f'wrote {args.json}')
    for name in PICTURED:
        if args.pictures is None or name not in proposers:
            continue
        path = args.pictures / f'{name}_failures_{args.hand}.png'
        panels = draw_montage(results.failures.get(name, []), hand, path)
        print(f'wrote {path} ({panels} failures)' if panels else f'no {name} failures to draw')
    return 0


if __name__ == '__main__':
    sys.exit(main())
