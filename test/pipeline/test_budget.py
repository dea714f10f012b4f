"""The frame time budget: lighter settings, in the stated order, after frames that overran."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st
from mvbb_ros.cli.main import build_parser
from mvbb_ros.cli.options import settings_from_args
from mvbb_ros.pipeline.budget import degraded, FrameBudget, MAX_LEVEL, RECOVER_FRACTION
from mvbb_ros.pipeline.process import process_cloud
from mvbb_ros.pipeline.settings import PipelineSettings, settings_from_mapping
from mvbb_ros.ros.encode import create_cloud_xyz
import numpy as np
import pytest
from support.shapes import l_shape_points


def test_the_levels_degrade_in_the_stated_order():
    node = PipelineSettings()  # voxel 0.005 m, 16 objects, 16 boxes
    assert degraded(node, 0) == (node, [])
    expected = [
        (0.01, 16, 16),
        (0.01, 8, 16),
        (0.01, 8, 8),
        (0.02, 8, 8),
        (0.02, 4, 8),
        (0.02, 4, 4),
    ]
    for level, (voxel, objects, boxes) in enumerate(expected, start=1):
        lighter, changes = degraded(node, level)
        got = (lighter.filtering.voxel_size, lighter.view.max_objects)
        assert got + (lighter.decomposition.max_boxes,) == (voxel, objects, boxes), level
        # Small objects keep their own finer voxels, at half (then a quarter of) the cells
        # across: the objects under that many voxels are the same ones as without a budget.
        assert len(changes) == min(level, 3) + 1
        rounds = 1 if level < 4 else 2
        assert lighter.view.object_voxel_cells == node.view.object_voxel_cells >> rounds
        assert f'object_voxel_cells 20 -> {20 >> rounds}' in changes
        extent = lighter.view.object_voxel_cells * lighter.filtering.voxel_size
        assert extent == node.view.object_voxel_cells * node.filtering.voxel_size
        assert lighter.grasps == node.grasps and lighter.refinement == node.refinement
    with pytest.raises(ValueError, match='level'):
        degraded(node, MAX_LEVEL + 1)


def test_unbounded_settings_get_a_bound_from_the_first_level_that_touches_them():
    paper = PipelineSettings.paper()  # no voxel grid, every object, no box bound
    lighter, changes = degraded(paper, 3)
    assert lighter.filtering.voxel_size == 0.01
    assert lighter.view.max_objects == 8 and lighter.decomposition.max_boxes == 8
    assert changes == ['voxel_size 0 -> 0.01 m', 'max_objects 0 -> 8', 'max_boxes 0 -> 8']


def _levels(budget_s: float, times: list[float]) -> list[int]:
    budget = FrameBudget()
    settings = settings_from_mapping({'frame_time_budget': budget_s})
    levels = []
    for seconds in times:
        budget.settings(settings)
        budget.record(seconds)
        levels.append(budget.level)
    return levels


def test_overruns_raise_the_level_and_fast_frames_lower_it():
    times = [2.0, 2.0, 0.8, 0.2, 0.2, 0.2, 0.2] + [5.0] * 9
    assert _levels(1.0, times) == [1, 2, 2, 1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 6, 6, 6]


@given(st.lists(st.floats(0.0, 3.0), max_size=40), st.floats(0.01, 2.0))
def test_the_level_is_a_function_of_the_budget_and_the_frame_times(times, budget_s):
    levels = _levels(budget_s, times)
    assert levels == _levels(budget_s, times)
    previous = 0
    for seconds, level in zip(times, levels, strict=True):
        assert 0 <= level <= MAX_LEVEL
        if seconds > budget_s:
            assert level == min(MAX_LEVEL, previous + 1)
        elif seconds < RECOVER_FRACTION * budget_s:
            assert level == max(0, previous - 1)
        else:
            assert level == previous
        previous = level


def test_off_changes_nothing_and_a_new_budget_starts_again():
    budget = FrameBudget()
    node = PipelineSettings()
    for _ in range(3):
        assert budget.settings(node) == (node, None)
        budget.record(100.0)
    assert budget.level == 0
    tight = settings_from_mapping({'frame_time_budget': 0.001})
    budget.settings(tight)
    budget.record(1.0)
    lighter, note = budget.settings(tight)
    assert budget.level == 1 and lighter.filtering.voxel_size == 0.01
    assert note is not None and note.startswith('frame_time_budget: level 1 of 6')
    looser = settings_from_mapping({'frame_time_budget': 0.002})
    assert budget.settings(looser) == (looser, None), 'a changed budget starts at level 0'


def test_frames_after_an_overrun_run_lighter_and_say_so():
    settings = settings_from_mapping({'frame_time_budget': 1e-6, 'shape_completion': 'none'})
    cloud = create_cloud_xyz(
        np.asarray(l_shape_points(count=3000), dtype=np.float32), frame_id='cam'
    )
    budget = FrameBudget()
    first = process_cloud(cloud, settings, budget=budget)
    second = process_cloud(cloud, settings, budget=budget)
    assert first.budget_note is None and first.leaves
    assert second.budget_note is not None and second.notes[0] == second.budget_note
    assert 'voxel_size 0.005 -> 0.01 m' in second.budget_note
    assert second.counts.downsampled < first.counts.downsampled, 'coarser voxels'
    assert settings.filtering.voxel_size == 0.005, 'the settings in force are never changed'
    again = process_cloud(cloud, settings, budget=FrameBudget())
    assert again.budget_note is None and again.counts == first.counts, 'a fresh stream'


def test_the_budget_is_a_flag_of_mvbb_and_a_parameter_of_the_node():
    arguments = ['bag', 'process', 'in', 'out', '--frame-time-budget', '0.25']
    args = build_parser().parse_args(arguments)
    assert settings_from_args(args).node.frame_time_budget == 0.25
    assert PipelineSettings().value('frame_time_budget') == 0.0
    with pytest.raises(ValueError, match='frame_time_budget'):
        settings_from_mapping({'frame_time_budget': -1.0})
