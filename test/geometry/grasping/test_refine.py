"""Grasps refined and scored on the points (issue 16): contacts, friction, widths, feasibility."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from mvbb_ros import grasp_hypotheses, PipelineSettings, process_points
from mvbb_ros.evaluation.grasp_judge import same_grasp
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.grasping.contacts import (
    COL_CONTACT_WIDTH,
    COL_MARGIN,
    COL_QUALITY,
    COL_VALID,
    COL_WIDTH,
    evaluate_lines,
)
from mvbb_ros.geometry.grasping.refine import refine_grasps
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
from mvbb_ros.geometry.grasping.surface import surface_model
from mvbb_ros.pipeline.process import GraspMemory
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.data import require_shared_data
from support.shapes import l_shape_points

ON = RefinementSettings(enabled=True)
CELL = 0.004


def box_surface(extents, rotation, center, step=CELL):
    """Return points every `step` on the six faces of a box (metres)."""
    half = np.asarray(extents) / 2.0
    faces = []
    for axis in range(3):
        others = [k for k in range(3) if k != axis]
        grid = np.meshgrid(
            *[np.linspace(-half[k], half[k], max(2, int(2 * half[k] / step) + 1)) for k in others]
        )
        for sign in (-1.0, 1.0):
            face = np.zeros((grid[0].size, 3))
            face[:, others[0]] = grid[0].ravel()
            face[:, others[1]] = grid[1].ravel()
            face[:, axis] = sign * half[axis]
            faces.append(face)
    return np.concatenate(faces) @ np.asarray(rotation).T + center


def _lines(rotation, center, approach_axis, closing_axis, tilt_deg=0.0):
    """Return one line through `center`: approach and closing along box axes, closing tilted."""
    axes = np.asarray(rotation).T
    approach = -axes[approach_axis]
    closing = axes[closing_axis]
    tilt = math.radians(tilt_deg)
    other = np.cross(approach, closing)
    closing = math.cos(tilt) * closing + math.sin(tilt) * other
    return center[None, :], approach[None, :], closing[None, :]


boxes = st.tuples(
    st.floats(0.03, 0.09), st.floats(0.03, 0.09), st.floats(0.03, 0.09), st.integers(0, 2**31 - 1)
)


def wedge_surface(half_angle_deg, height=0.06, length=0.06, step=CELL):
    """Return points on a prism whose cross-section is a triangle, apex up (z), axis along y."""
    beta = math.radians(half_angle_deg)
    half_base = height * math.tan(beta)
    zs = np.linspace(0.0, height, int(height / step) + 1)
    ys = np.linspace(-length / 2.0, length / 2.0, int(length / step) + 1)
    z, y = np.meshgrid(zs, ys)
    x = half_base * (1.0 - z / height)
    faces = [np.column_stack([sign * x.ravel(), y.ravel(), z.ravel()]) for sign in (-1.0, 1.0)]
    xs = np.linspace(-half_base, half_base, int(2 * half_base / step) + 1)
    bx, by = np.meshgrid(xs, ys)
    faces.append(np.column_stack([bx.ravel(), by.ravel(), np.zeros(bx.size)]))
    for end in (-length / 2.0, length / 2.0):
        cz, cx = np.meshgrid(zs, xs)
        inside = np.abs(cx) <= half_base * (1.0 - cz / height)
        faces.append(np.column_stack([cx[inside], np.full(inside.sum(), end), cz[inside]]))
    return np.concatenate(faces)


@settings(max_examples=25, deadline=None)
@given(boxes)
def test_an_antipodal_grasp_across_a_box_holds_with_the_width_of_the_box(box):
    *extents, seed = box
    rotation = Rotation.random(random_state=seed).as_matrix()
    center = np.array([0.1, -0.05, 0.7])
    model = surface_model(box_surface(extents, rotation, center), cell=CELL)
    view = GraspView(gripper_max_width=0.14, standoff=0.05)
    straight = evaluate_lines(model, *_lines(rotation, center, 2, 0), ON, view)[0]
    assert straight[COL_VALID] == 1.0, 'closing across two parallel faces holds'
    # The contact line is nearly along both normals (margin 0.45: within 14.6 degrees). A 2 cm
    # pad on a face 3 cm high sampled every 4 mm averages normals tilted by the face's edges:
    # margin 0.49 (13.4 degrees) at worst with faces of exactly 3 cm, the strategy's bound (0.52
    # in 1,000 boxes with such faces), 0.75 in 1,500 random boxes, 1 degree at the median.
    assert straight[COL_MARGIN] > 0.45, 'the contact line is nearly along both normals'
    # The width the object needs along the closing line: the box's extent (up to a cell).
    assert straight[COL_WIDTH] == pytest.approx(extents[0], abs=1.5 * CELL)
    assert straight[COL_CONTACT_WIDTH] == pytest.approx(extents[0], abs=1.5 * CELL)


@settings(max_examples=20, deadline=None)
@given(st.floats(30.0, 40.0), st.floats(12.0, 20.0), st.integers(0, 2**31 - 1))
def test_a_grasp_that_slips_is_refused_and_one_inside_the_cones_scores_above_it(
    steep, gentle, seed
):
    """
    Closing across a wedge: its faces make the half-angle with the contact line.

    The line and two neighbours slid 5 mm along the wedge (as the refinement slides its lines):
    on the 4 mm staircase of the surface model one line alone misses a gentle wedge's contact
    in about 1 case in 100 (the two pads' contacts land apart along the wedge).
    """
    rotation = Rotation.random(random_state=seed).as_matrix()
    center = np.array([0.0, 0.1, 0.6])
    view = GraspView(gripper_max_width=0.14, standoff=0.05)
    shifts = np.array([-0.005, 0.0, 0.005])[:, None] * rotation[:, 1]
    lines = (center + shifts, np.tile(-rotation[:, 2], (3, 1)), np.tile(rotation[:, 0], (3, 1)))
    rows = []
    for angle in (steep, gentle):
        points = wedge_surface(angle) @ rotation.T + center
        rows.append(evaluate_lines(surface_model(points, cell=CELL), *lines, ON, view))
    slipping, holding = rows
    assert not slipping[:, COL_VALID].any(), f'{steep:.0f} degrees is outside a mu 0.5 cone (26.6)'
    assert holding[:, COL_VALID].any()
    assert holding[:, COL_QUALITY].max() > slipping[:, COL_QUALITY].max()
    wide_cone = RefinementSettings(enabled=True, friction=1.0)  # 45 degrees
    points = wedge_surface(steep) @ rotation.T + center
    assert evaluate_lines(surface_model(points, cell=CELL), *lines, wide_cone, view)[:, 0].any()


def test_an_object_wider_than_the_opening_is_not_grasped_across():
    model = surface_model(box_surface((0.2, 0.05, 0.05), np.eye(3), np.zeros(3)), cell=CELL)
    view = GraspView(gripper_max_width=0.08, standoff=0.05)
    across = evaluate_lines(model, *_lines(np.eye(3), np.zeros(3), 2, 0), ON, view)[0]
    assert not across[COL_VALID], 'the fingers would land on a 20 cm box'
    along = evaluate_lines(model, *_lines(np.eye(3), np.zeros(3), 2, 1), ON, view)[0]
    assert along[COL_VALID] and along[COL_WIDTH] == pytest.approx(0.05, abs=1.5 * CELL)


def _refined(points, *, up=None, viewpoint=None, far_side=True, width=0.14, previous=None):
    from mvbb_ros.geometry.decomposition.tree import decompose

    decomposition = decompose(points, gain_threshold=0.94)
    seeds = grasp_hypotheses(decomposition, gripper_max_width=width)
    view = GraspView(
        gripper_max_width=width,
        standoff=0.05,
        up=None if up is None else np.asarray(up, dtype=float),
        viewpoint=None if viewpoint is None else np.asarray(viewpoint, dtype=float),
        far_side=far_side,
        support_clearance=0.005,
    )
    model = surface_model(points, cell=CELL, up=up)
    leaves = decomposition.leaves
    return refine_grasps(seeds, leaves, [0] * len(leaves), [model], ON, view, previous)


@settings(max_examples=15, deadline=None)
@given(boxes, st.floats(0.0, 2 * math.pi))
def test_refined_grasps_hold_are_scored_in_0_1_and_their_widths_match(box, turn):
    *extents, seed = box
    rotation = Rotation.from_euler('z', turn).as_matrix()
    points = box_surface(extents, rotation, np.array([0.0, 0.0, extents[2] / 2.0]))
    refined = _refined(points, up=(0.0, 0.0, 1.0))
    assert refined.grasps, 'a box on a table can be grasped'
    scores = [g.score for g in refined.grasps]
    assert all(0.0 <= score <= 1.0 for score in scores)
    assert scores == sorted(scores, reverse=True)
    local_extents = np.asarray(extents)
    for grasp in refined.grasps:
        along = np.abs(rotation.T @ grasp.closing)
        needed = float(along @ local_extents)  # the box's extent along the closing line
        assert grasp.width <= needed + ON.width_margin + 2 * CELL
        assert grasp.width >= min(local_extents) - 2 * CELL, 'no width thinner than the object'
        # No approach from below (up known), and the fingertips stay above the table.
        assert grasp.approach[2] <= math.sin(math.radians(45.0)) + 1e-9
        tip = grasp.position + grasp.depth * grasp.approach
        assert tip[2] >= 0.005 - 1e-9


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_of_grasps_that_hold_alike_the_one_nearest_the_centre_ranks_first(seed):
    """Along a bar every closing across it holds alike; the middle one twists it least."""
    rotation = Rotation.random(random_state=seed).as_matrix()
    center = np.array([0.05, -0.1, 0.6])
    points = box_surface((0.24, 0.04, 0.04), rotation, center)
    top = _refined(points).grasps[0]
    closing_point = top.position + top.depth * np.asarray(top.approach)
    along_bar = float((closing_point - center) @ rotation[:, 0])
    assert abs(along_bar) <= 0.01, f'the top grasp closes {along_bar:+.3f} m from the middle'


def test_no_approach_from_the_far_side_unless_allowed():
    rotation = Rotation.from_euler('z', 0.3).as_matrix()
    points = box_surface((0.06, 0.05, 0.12), rotation, np.array([0.0, 0.0, 0.06]))
    viewpoint = np.array([0.8, 0.1, 0.5])
    sight = -viewpoint / np.linalg.norm(viewpoint)
    near = _refined(points, up=(0, 0, 1), viewpoint=viewpoint, far_side=False).grasps
    assert near and all(g.approach @ sight > 0.0 for g in near)
    every = _refined(points, up=(0, 0, 1), viewpoint=viewpoint, far_side=True).grasps
    assert any(g.approach @ sight < -0.1 for g in every), 'the far side has grasps too'


def test_the_previous_top_grasp_stays_within_the_margin_and_is_dropped_when_invalid():
    points = l_shape_points() - [0.1, -0.05, 0.6]
    best = _refined(points)
    assert not best.kept_previous and len(best.grasps) > 3
    # A worse grasp that still holds stays on top with the default margin ...
    runner_up = next(g for g in best.grasps[1:] if not same_grasp(g, best.grasps[0]))
    assert best.grasps[0].score - runner_up.score <= ON.hysteresis
    kept = _refined(points, previous=runner_up)
    assert kept.kept_previous and same_grasp(kept.grasps[0], runner_up)
    assert not any(same_grasp(g, runner_up) for g in kept.grasps[1:]), 'listed once'
    # ... its identity, not its index: the rest keep their order.
    rest = [g for g in best.grasps if not same_grasp(g, runner_up)]
    assert [g.box_index for g in kept.grasps[1:6]] == [g.box_index for g in rest[:5]]
    # A grasp that no longer touches the object (it moved away) gives way to the best.
    moved = _refined(points + [0.5, 0.0, 0.0], previous=best.grasps[0])
    assert not moved.kept_previous


def test_the_pipeline_refines_by_default_and_the_paper_preset_does_not():
    points = l_shape_points()
    paper = process_points(points, PipelineSettings.paper())
    assert paper.refinement is None and 'refine' not in paper.timings_ms
    assert [g.depth for g in paper.grasps] == [0.05] * len(paper.grasps)
    node = process_points(points)
    assert node.refinement is not None and node.refinement.candidates > len(node.grasps) > 0
    assert node.timings_ms['refine'] > 0.0
    # The previous top grasp is a keyword of the one pipeline function.
    again = process_points(points, previous=node.grasps[0])
    assert again.refinement.kept_previous and same_grasp(again.grasps[0], node.grasps[0])


def test_grasp_memory_forgets_across_frames_and_after_an_empty_result():
    node = process_points(l_shape_points())
    memory = GraspMemory()
    assert memory.previous('camera') is None
    memory.remember('camera', node)
    assert memory.previous('camera') is node.grasps[0]
    assert memory.previous('map') is None, 'a grasp in another frame means nothing'
    memory.remember('camera', None)
    assert memory.previous('camera') is None


def test_without_an_estimate_the_boxes_stand_for_the_hidden_side():
    settings = PipelineSettings().updated({'shape_completion': 'none'})
    result = process_points(l_shape_points(), settings)
    assert result.grasps and result.refinement.holding > 0


def test_an_empty_input_gives_no_refined_grasps():
    view = GraspView(gripper_max_width=0.1, standoff=0.05)
    assert refine_grasps([], [], [], [], ON, view).grasps == []
    box = Box(np.zeros(3), np.eye(3), np.full(3, 0.05))
    assert refine_grasps([], [box], [0], [], ON, view).grasps == []


def _assert_on_the_box_that_holds_it(result) -> int:
    """Check each grasp's box holds where it closes (else is the nearest); return how many."""
    leaves, owners = result.leaves, result.leaf_object_indices
    for grasp in result.grasps:
        closes = np.asarray(grasp.position) + grasp.depth * np.asarray(grasp.approach)
        mine = [i for i, owner in enumerate(owners) if owner == grasp.object_index]
        local = {i: np.abs(leaves[i].to_local(closes[None, :])[0]) for i in mine}
        gap = {i: np.linalg.norm(np.maximum(local[i] - leaves[i].half_extents, 0.0)) for i in mine}
        holding = [i for i in mine if gap[i] <= 1e-9]
        if holding:
            assert grasp.box_index in holding, (grasp.box_index, holding)
        else:
            assert gap[grasp.box_index] <= min(gap.values()) + 1e-9, (grasp.box_index, gap)
    return len(result.grasps)


def test_a_grasp_is_on_the_box_that_holds_where_it_closes():
    """
    A line from one box slides along its approach to the first contact, which may be on another.

    The grasp's box (``box_index``, its face, the strategy's preference) is the box of its
    object that holds the point where the fingers close.
    """
    assert _assert_on_the_box_that_holds_it(process_points(l_shape_points())) > 0


def test_on_a_real_scan_the_top_grasp_is_on_the_box_it_closes_in():
    """On this Kinect box the top lines come from a hidden corner's box and close 17 cm away."""
    scan = require_shared_data('scans', 'mosd_learn26_obj2.npy')
    result = process_points(np.load(scan))
    assert _assert_on_the_box_that_holds_it(result) > 0
    top = result.grasps[0]
    assert result.leaf_observed_counts[top.box_index] > 0, 'the top grasp is on a seen box'


def _grasp_rows(result) -> list[tuple[float, ...]]:
    """Each grasp's pose, width, depth and score as plain numbers (exact comparison)."""
    return [
        (*g.position, *g.approach, *g.closing, g.width, g.depth, g.score) for g in result.grasps
    ]


def _assert_bounded_lists_are_its_head(points: np.ndarray, whole, limit: int) -> None:
    """Check that ``max_grasps: limit`` lists the head of `whole`, whatever the batches."""
    from mvbb_ros.geometry.grasping import ranking

    # One ranking's worth more each round, the defaults, and batches that double.
    for batch, growth in ((1, 0.0), (ranking.PRUNE_BATCH, ranking.PRUNE_GROWTH), (1, 1.0)):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(ranking, 'PRUNE_BATCH', batch)
            patch.setattr(ranking, 'PRUNE_GROWTH', growth)
            bounded = process_points(points, PipelineSettings().updated({'max_grasps': limit}))
        assert _grasp_rows(bounded) == _grasp_rows(whole)[:limit]


@settings(max_examples=8, deadline=None)
@given(st.integers(0, 2**16), st.integers(1, 5), st.sampled_from([1, 5, 32]))
def test_a_bounded_grasp_list_is_the_head_of_the_whole_list(seed, count, limit):
    """
    With ``max_grasps`` set only the lines that can reach the list are checked for pose errors.

    The list must be exactly the first ``max_grasps`` of the whole list (poses, widths and scores
    to the bit), whatever the batches the pruning scores its lines in.
    """
    from mvbb_ros.evaluation.synthetic import table_top_frame

    frame = table_top_frame(seed, count).points.reshape(-1, 3)
    points = frame[np.isfinite(frame).all(axis=1)]
    whole = process_points(points, PipelineSettings().updated({'max_grasps': 0}))
    assert len(whole.grasps) > limit, 'the scene must have more grasps than the list keeps'
    _assert_bounded_lists_are_its_head(points, whole, limit)


@pytest.mark.parametrize('limit', [1, 5, 32])
def test_with_a_cut_object_a_bounded_grasp_list_is_the_head_of_the_whole_list(limit):
    """The cut object's lines come after the others' in the pruned ranking too."""
    from mvbb_ros.evaluation.synthetic import cut_table_top_frame

    points, _, _ = cut_table_top_frame(9, 5)
    whole = process_points(points, PipelineSettings().updated({'max_grasps': 0}))
    assert whole.cut_objects and len(whole.grasps) > limit
    cut = [grasp.object_index in whole.cut_objects for grasp in whole.grasps]
    assert cut == sorted(cut) and any(cut), 'the cut object has grasps, after the others'
    _assert_bounded_lists_are_its_head(points, whole, limit)


@pytest.mark.parametrize('count', [1, 2])
def test_seeds_made_while_the_boxes_lines_are_checked_give_the_same_grasps(count):
    """The hypotheses may be made by a function called meanwhile: the grasps are the same."""
    from mvbb_ros.common.workers import workers
    from mvbb_ros.geometry.decomposition.tree import decompose

    points = l_shape_points(seed=3)
    decomposition = decompose(points, gain_threshold=0.94)
    seeds = grasp_hypotheses(decomposition, gripper_max_width=0.14)
    view = GraspView(
        gripper_max_width=0.14,
        standoff=0.05,
        up=np.array([0.0, 0.0, 1.0]),
        support_clearance=0.005,
    )
    model = surface_model(points, cell=CELL, up=(0.0, 0.0, 1.0))
    leaves = decomposition.leaves
    ours = [0] * len(leaves)
    given = refine_grasps(seeds, leaves, ours, [model], ON, view)
    calls = []

    def made():
        calls.append(1)
        return seeds

    pool = None if count == 1 else workers(count)
    later = refine_grasps(made, leaves, ours, [model], ON, view, pool=pool)
    assert calls == [1]
    assert given.grasps and _grasp_rows(later) == _grasp_rows(given)
    assert (later.candidates, later.holding) == (given.candidates, given.holding)


def test_lines_started_on_the_helpers_give_the_rows_of_the_lines_checked_at_once():
    from mvbb_ros.common.workers import workers
    from mvbb_ros.geometry.grasping.contacts import start_lines

    model = surface_model(l_shape_points(seed=5), cell=CELL, up=(0.0, 0.0, 1.0))
    rng = np.random.default_rng(5)
    approaches = Rotation.random(300, random_state=5).as_matrix()
    origins = model.center + rng.normal(0.0, 0.03, (300, 3))
    lines = (origins, approaches[:, :, 2], approaches[:, :, 0])
    view = GraspView(gripper_max_width=0.14, standoff=0.05, up=np.array([0.0, 0.0, 1.0]))
    at_once = evaluate_lines(model, *lines, ON, view)
    assert at_once[:, COL_VALID].any()
    for pool in (None, workers(2), workers(3)):
        finish = start_lines(model, *lines, ON, view, pool=pool)
        assert np.array_equal(finish(), at_once)


@settings(max_examples=80, deadline=None)
@given(
    boxes=st.integers(1, 12),
    objects=st.integers(1, 5),
    count=st.integers(0, 400),
    seed=st.integers(0, 10_000),
)
def test_property_holding_boxes_is_the_argmax_of_every_boxs_fit(boxes, objects, count, seed):
    """The holding box, kept as the best so far per grasp, is the table's argmax (ties: lower)."""
    from mvbb_ros.geometry.grasping.refine import _holding_boxes

    rng = np.random.default_rng(seed)
    made = []
    for _ in range(boxes):
        rotation = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
        if rng.random() < 0.3:
            rotation = np.eye(3)  # axis-aligned boxes on a grid of points: equal fits, ties
        made.append(Box(np.round(rng.uniform(-1, 1, 3), 1), rotation, rng.choice([0.4, 1.0], 3)))
    box_objects = rng.integers(0, objects, boxes)
    points = np.round(rng.uniform(-1.5, 1.5, (count, 3)), 1)
    owners = rng.integers(0, objects + 1, count)  # the last object has no box
    # The reference: every box's fit in one (grasps, boxes) table, -inf for other objects' boxes.
    table = np.full((count, boxes), -np.inf)
    for index, box in enumerate(made):
        mine = np.flatnonzero(owners == box_objects[index])
        local = np.abs(box.to_local(points[mine]))
        outside = np.linalg.norm(np.maximum(local - box.half_extents, 0.0), axis=1)
        inside = np.min(box.half_extents - local, axis=1)
        table[mine, index] = np.where(outside > 0.0, -outside, inside)
    expected = np.argmax(table, axis=1) if boxes else np.zeros(count, dtype=np.intp)
    found = _holding_boxes(points, owners, made, box_objects)
    np.testing.assert_array_equal(found, expected)
