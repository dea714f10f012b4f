"""
Say why a pipeline result has boxes but no grasps: which grasp filter removed the last ones.

`mvbb bag process` prints it in its note column and the node puts it in its diagnostics, so a
cloud whose every face is occluded, too wide for the gripper or approached from below does not
come back silently empty. The counts come from
:func:`~mvbb_ros.geometry.grasping.hypotheses.grasp_filter_counts`, the filters in the order the
grasp stage applies them. No ROS import.
"""

from __future__ import annotations

from dataclasses import asdict

from mvbb_ros.geometry.grasping.hypotheses import grasp_filter_counts, GraspStats
from mvbb_ros.pipeline.result import PipelineResult
from mvbb_ros.pipeline.settings import PipelineSettings


def _filter_steps(
    stats: GraspStats, settings: PipelineSettings, thinnest: float
) -> list[tuple[int, str]]:
    """Return (hypotheses left after the filter, why it removes them), in filter order."""
    grasps = settings.grasps
    up = settings.view.up
    below = (
        f'up_direction {list(up)}'
        if up is not None
        else f'support plane {list(grasps.support_plane or ())}'
    )
    return [
        (stats.after_occlusion, 'occlusion: every face is covered by or touches another box'),
        (
            stats.after_width,
            f'gripper_max_width: every free face needs more than {grasps.gripper_max_width:g} m '
            f'(the thinnest box edge is {thinnest:.3g} m)',
        ),
        (
            stats.after_support,
            f'support: every remaining approach comes from below ({below}) or too close to it'
            + ('' if grasps.far_side else ', or from the far side (far_side_grasps: false)'),
        ),
    ]


def empty_grasps_note(result: PipelineResult, settings: PipelineSettings) -> str:
    """
    Return which filter removed every grasp of a result that has boxes, or '' otherwise.

    :param result: a pipeline result.
    :param settings: the settings it was made with.
    :return: e.g. ``'5 boxes, 0 grasps: gripper_max_width: every free face needs more than
        0.08 m (the thinnest box edge is 0.12 m); hypotheses 120 -> occlusion 64 -> width 0'``;
        '' when the result has grasps, or no boxes (its warning says why).
    """
    if not result.leaves or result.grasps:
        return ''
    stats = grasp_filter_counts(
        result.leaves,
        up=settings.view.up,
        sensor_origin=settings.view.viewpoint,
        object_indices=result.leaf_object_indices,
        **asdict(settings.grasps),
    )
    thinnest = min(float(box.extents.min()) for box in result.leaves)
    counts = (
        f'hypotheses {stats.hypotheses} -> occlusion {stats.after_occlusion} -> width '
        f'{stats.after_width} -> support {stats.after_support}'
    )
    for left, reason in _filter_steps(stats, settings, thinnest):
        if left == 0:
            return f'{stats.boxes} boxes, 0 grasps: {reason}; {counts}'
    refined = result.refinement
    if refined is not None:
        grasps = settings.grasps
        return (
            f'{stats.boxes} boxes, 0 grasps: refinement: none of {refined.candidates} grasp lines '
            f'closes on the points within gripper_max_width {grasps.gripper_max_width:g} m with '
            f'both contacts inside the friction cones (grasp_friction '
            f'{settings.refinement.friction:g}) and its pads clear of the support; {counts}'
        )
    return f'{stats.boxes} boxes, 0 grasps; {counts}'
