"""Tests for the fit-and-split decomposition (geometry.decomposition, paper Sec. III-B..D)."""

from __future__ import annotations

import json
import math

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
import mvbb_ros
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.boxfit.fit import fit_part
from mvbb_ros.geometry.decomposition.result import ORDERS, STOP_REASONS
from mvbb_ros.geometry.decomposition.split import cut_mask, score_cuts
from mvbb_ros.geometry.decomposition.tree import RESCORE_MARGIN
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.data import require_shared_data


def assert_valid(result: mvbb_ros.Decomposition, points: np.ndarray) -> None:
    """Check every invariant of a decomposition of `points`."""
    count = len(points)
    config = result.settings
    threshold = config.gain_threshold
    assert result.points.shape == (count, 3)
    assert result.points.dtype == np.float64
    np.testing.assert_array_equal(result.points, np.asarray(points, dtype=np.float64))
    nodes = result.nodes
    assert result.root is nodes[0]
    assert nodes[0].parent is None and nodes[0].depth == 0
    np.testing.assert_array_equal(nodes[0].point_indices, np.arange(count))

    for index, node in enumerate(nodes):
        assert node.index == index
        assert node.stop_reason is None or node.stop_reason in STOP_REASONS
        assert np.all(np.diff(node.point_indices) > 0), 'point indices sorted and unique'
        # Every box contains its points.
        assert np.all(node.box.contains(points[node.point_indices]))
        if node.tested_cut is not None:
            assert node.theta == node.tested_cut.theta
            assert node.gain is not None and node.gain >= 0.0
        if node.children:
            assert node.stop_reason is None and not node.dropped and not node.is_leaf
            assert node.cut is not None and node.cut is node.tested_cut
            assert node.gain < threshold
            assert len(node.children) == 2
            parts = []
            for child_index in node.children:
                child = nodes[child_index]
                assert child_index > index
                assert child.parent == index
                assert child.depth == node.depth + 1
                parts.append(child.point_indices)
            assert [len(part) for part in parts] == [
                node.cut.lower_count,
                node.cut.upper_count,
            ]
            np.testing.assert_array_equal(np.sort(np.concatenate(parts)), node.point_indices)
        else:
            assert node.cut is None
            assert node.stop_reason is not None
        if node.dropped:
            assert node.stop_reason == 'dropped'
            assert node.point_count < config.min_points
            assert not node.children and not node.is_leaf
        if node.is_leaf:
            assert node.point_count >= config.min_points
        if node.stop_reason == 'gain':
            assert node.gain >= threshold
        if node.stop_reason == 'noise':
            assert (
                max(node.tested_cut.lower_count, node.tested_cut.upper_count) < config.min_points
            )
        if node.stop_reason == 'no_cut':
            assert node.tested_cut is None and node.gain is None

    leaf_nodes = [node for node in nodes if node.is_leaf]
    assert result.leaf_nodes == leaf_nodes
    assert [id(box) for box in result.leaves] == [id(node.box) for node in leaf_nodes]
    assert len(result.leaf_point_indices) == len(result.leaves)
    # The leaves partition the kept points; kept plus dropped are all the points.
    kept = np.concatenate(result.leaf_point_indices) if leaf_nodes else np.empty(0, dtype=np.intp)
    dropped = result.dropped_point_indices
    assert len(np.unique(kept)) == len(kept)
    np.testing.assert_array_equal(np.sort(kept), result.kept_point_indices)
    np.testing.assert_array_equal(np.sort(np.concatenate([kept, dropped])), np.arange(count))
    for box, indices in zip(result.leaves, result.leaf_point_indices, strict=True):
        assert np.all(box.contains(points[indices]))
    # Total leaf volume never exceeds the root's.
    assert result.leaf_volume <= result.root_volume * (1.0 + 1e-9) + 1e-300
    if config.max_boxes is not None:
        assert len(result.leaves) <= config.max_boxes


@st.composite
def clouds(draw) -> np.ndarray:
    """Small clouds, general and degenerate: blobs, flat, on a line, duplicated, far away."""
    count = draw(st.integers(1, 60))
    seed = draw(st.integers(0, 2**32 - 1))
    kind = draw(st.sampled_from(['blobs', 'coplanar', 'collinear', 'duplicates', 'raw']))
    rng = np.random.default_rng(seed)
    if kind == 'raw':
        return draw(arrays(np.float64, (count, 3), elements=st.floats(-100, 100, width=32)))
    centres = rng.normal(0.0, 3.0, (3, 3))
    points = centres[rng.integers(0, 3, count)] + rng.normal(0.0, 0.5, (count, 3))
    points *= rng.uniform(0.2, 3.0, 3)
    if kind == 'coplanar':
        points[:, 2] = 0.0
    elif kind == 'collinear':
        points = np.outer(points[:, 0], rng.normal(size=3))
    elif kind == 'duplicates':
        points = points[rng.integers(0, max(1, count // 4), count)]
    rotation = Rotation.random(random_state=seed % 2**31).as_matrix()
    offset = rng.normal(0.0, 1e3) if draw(st.booleans()) else 0.0
    return points @ rotation.T + offset


decomposition_options = st.fixed_dictionaries(
    {
        'gain_threshold': st.sampled_from([0.5, 0.9, 0.94, 0.98, 1.0]),
        'min_points': st.integers(1, 12),
        'split_measure': st.sampled_from(['area', 'volume']),
        'rescore_cuts': st.integers(0, 3),
        'max_boxes': st.none() | st.integers(1, 6),
        'order': st.sampled_from(ORDERS),
        'grid_cells': st.sampled_from([2, 7, 32, 128]),
        'part_search': st.sampled_from(['light', 'full']),
    }
)


@settings(max_examples=60, deadline=None)
@given(points=clouds(), options=decomposition_options)
def test_invariants_hold_on_any_cloud(points, options):
    result = mvbb_ros.decompose(points, **options)
    assert_valid(result, points)


@settings(max_examples=15, deadline=None)
@given(points=clouds(), options=decomposition_options, seed=st.integers(0, 1000))
def test_same_seed_same_result(points, options, seed):
    first = mvbb_ros.decompose(points, seed=seed, **options)
    second = mvbb_ros.decompose(points.copy(), seed=seed, **options)
    assert first.to_json(include_point_indices=True) == second.to_json(include_point_indices=True)


def solid(low: list[float], high: list[float], count: int, rng: np.random.Generator) -> np.ndarray:
    """Return `count` uniform points in the axis-aligned block low..high."""
    return rng.uniform(low, high, (count, 3))


def l_shape(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Return a solid L (a 4 x 1 x 1 bar and a 1 x 2 x 1 post on its end) and its volume."""
    bar = solid([0, 0, 0], [4, 1, 1], 4000, rng)
    post = solid([3, 1, 0], [4, 3, 1], 2000, rng)
    return np.vstack([bar, post]), 4.0 + 2.0


def test_l_shape_gives_its_two_bars():
    rng = np.random.default_rng(0)
    points, volume = l_shape(rng)
    result = mvbb_ros.decompose(points, gain_threshold=0.94)
    assert_valid(result, points)
    assert len(result.leaves) == 2
    # The root box holds the L's bounding 4 x 3 x 1 (or a slightly smaller tilted box); the two
    # leaves are the bars, so their volume is the L's own.
    assert result.root_volume > 1.4 * volume
    assert result.leaf_volume == pytest.approx(volume, rel=0.05)
    assert result.root.cut is not None and result.root.gain < 0.94
    # The cut falls on the grid next to the bars' seam, so a few points may change sides: the
    # bars are 4 x 1 x 1 and 1 x 2 x 1 (or, cut the other way, 3 x 1 x 1 and 1 x 3 x 1).
    counts = sorted(len(indices) for indices in result.leaf_point_indices)
    volumes = sorted(box.volume for box in result.leaves)
    if counts[0] < 1500:
        expected_counts, expected_volumes = [1000, 5000], [3.0, 3.0]
    else:
        expected_counts, expected_volumes = [2000, 4000], [2.0, 4.0]
    np.testing.assert_allclose(counts, expected_counts, rtol=0.02)
    np.testing.assert_allclose(volumes, expected_volumes, rtol=0.05)


def test_lower_threshold_means_fewer_boxes():
    rng = np.random.default_rng(1)
    # Four blocks in a row with gaps: every split has a real gain.
    blocks = [solid([5 * k, 0, 0], [5 * k + 1 + k, 1, 1], 1500, rng) for k in range(4)]
    points = np.vstack(blocks)
    counts = [
        len(mvbb_ros.decompose(points, gain_threshold=t).leaves) for t in (0.0, 0.5, 0.9, 0.98)
    ]
    assert counts[0] == 1
    assert counts == sorted(counts)
    assert counts[-1] == 4


def test_outliers_below_min_points_are_dropped():
    rng = np.random.default_rng(2)
    cube = solid([0, 0, 0], [1, 1, 1], 3000, rng)
    outliers = np.array([[4.0, 0.5, 0.5], [0.5, 4.0, 0.5], [-3.0, -3.0, -3.0]])
    points = np.vstack([cube, outliers])
    result = mvbb_ros.decompose(points, gain_threshold=0.94, min_points=10)
    assert_valid(result, points)
    np.testing.assert_array_equal(result.dropped_point_indices, [3000, 3001, 3002])
    assert len(result.leaves) == 1
    np.testing.assert_array_equal(result.leaf_point_indices[0], np.arange(3000))
    assert result.leaves[0].volume == pytest.approx(1.0, rel=0.02)
    assert sum(node.point_count for node in result.nodes if node.dropped) == 3
    # Without noise removal the outliers stay, in flat boxes (three points have no volume).
    keep_all = mvbb_ros.decompose(points, gain_threshold=0.94, min_points=1)
    assert_valid(keep_all, points)
    assert len(keep_all.dropped_point_indices) == 0
    assert len(keep_all.leaves) >= 2
    outlier_leaves = [node for node in keep_all.leaf_nodes if np.any(node.point_indices >= 3000)]
    assert all(node.point_count <= 3 and node.box.volume < 1e-9 for node in outlier_leaves)


def test_max_boxes_caps_the_leaves():
    rng = np.random.default_rng(3)
    points = np.vstack([solid([3 * k, 0, 0], [3 * k + 1, 1, 1], 800, rng) for k in range(5)])
    free = mvbb_ros.decompose(points, gain_threshold=0.98)
    assert len(free.leaves) == 5
    for cap in (1, 2, 3):
        capped = mvbb_ros.decompose(points, gain_threshold=0.98, max_boxes=cap)
        assert_valid(capped, points)
        assert len(capped.leaves) == cap
        assert any(node.stop_reason == 'max_boxes' for node in capped.nodes) or cap == 1
        assert capped.settings.max_boxes == cap


@pytest.mark.parametrize('order', ORDERS)
def test_every_order_splits_separated_blocks(order):
    rng = np.random.default_rng(4)
    points = np.vstack([solid([3 * k, 0, 0], [3 * k + 1, 1, 1], 600, rng) for k in range(3)])
    result = mvbb_ros.decompose(points, gain_threshold=0.94, order=order)
    assert_valid(result, points)
    assert len(result.leaves) == 3
    assert result.volume_ratio == pytest.approx(3.0 / 7.0, rel=0.05)


def test_best_first_leaves_no_split_that_passes_at_the_end():
    rng = np.random.default_rng(5)
    points = np.vstack([l_shape(rng)[0], solid([6, 0, 0], [7, 2, 2], 1000, rng)])
    result = mvbb_ros.decompose(points, gain_threshold=0.98, order='gain')
    assert_valid(result, points)
    final_volume = result.leaf_volume
    refused = [node for node in result.leaf_nodes if node.stop_reason == 'gain']
    assert refused
    for node in refused:
        # Recompute the refused split and its Theta* against the final leaves (eq. 2).
        own = points[node.point_indices]
        scores = score_cuts(node.box.to_local(own), cells=result.settings.grid_cells)
        upper = cut_mask(scores, node.tested_cut)
        children = sum(fit_part(own[side]).volume for side in (upper, ~upper))
        others = final_volume - node.box.volume
        assert node.gain == pytest.approx((children + others) / final_volume, rel=1e-9)
        assert node.gain >= 0.98


def fitting_every_part(points: np.ndarray, **options) -> mvbb_ros.Decomposition:
    """Decompose with both parts of every candidate cut fitted: no bound, no skipped fit."""
    from unittest import mock

    from mvbb_ros.geometry.decomposition import split
    from mvbb_ros.geometry.decomposition import tree as decomposition

    def every_part(points, draft, settings, fit_parts, others=None, pool=None):
        box = draft.box
        # The decomposition's own framing of the points (the cuts depend on its rounding).
        local = split.frame_points_kernel(points, draft.point_indices, box.center, box.rotation)
        scores = score_cuts(
            local,
            cells=settings.grid_cells,
            measure=settings.split_measure,
            min_thickness=settings.min_thickness,
        )
        limit = max(1, settings.rescore_cuts) if fit_parts else 1
        splits = []
        for cut in split.candidate_cuts(scores, box, limit=limit):
            upper = cut_mask(scores, cut)
            parts = (draft.point_indices[~upper], draft.point_indices[upper])
            if not fit_parts:
                return decomposition._Split(cut=cut, parts=parts, boxes=None)
            full = settings.part_search == 'full'
            boxes = tuple(
                fit_part(np.ascontiguousarray(points[p]), seed=settings.seed, full=full)
                for p in parts
            )
            splits.append(decomposition._Split(cut=cut, parts=parts, boxes=boxes))
        if not splits:
            return None
        # The smallest pair of boxes; another cut must beat the paper's (the first) by the margin.
        best = min(splits, key=lambda s: s.volume)
        if best.volume >= splits[0].volume - RESCORE_MARGIN * box.volume:
            best = splits[0]
        return best

    with mock.patch.object(decomposition, '_best_split', every_part):
        return mvbb_ros.decompose(points, **options)


def assert_same_tree(fast: mvbb_ros.Decomposition, full: mvbb_ros.Decomposition) -> int:
    """
    Check that two decompositions are the same tree; return how many refused gains differ.

    A refused split's recorded Theta* may be the lower bound of its larger part's box alone: at
    least the threshold, at most the Theta* of both parts' boxes (then the cuts may differ).
    """
    assert len(fast.nodes) == len(full.nodes)
    bounded = 0
    for quick, whole in zip(fast.nodes, full.nodes, strict=True):
        np.testing.assert_array_equal(quick.box.center, whole.box.center)
        np.testing.assert_array_equal(quick.box.rotation, whole.box.rotation)
        np.testing.assert_array_equal(quick.box.extents, whole.box.extents)
        np.testing.assert_array_equal(quick.point_indices, whole.point_indices)
        assert quick.stop_reason == whole.stop_reason and quick.children == whole.children
        cuts = [None if n.tested_cut is None else n.tested_cut.to_dict() for n in (quick, whole)]
        if quick.gain != whole.gain:
            # Refused on bounds: the cut whose larger part's box is smallest, with that bound.
            assert quick.stop_reason == 'gain'
            assert fast.settings.gain_threshold <= quick.gain <= whole.gain
            bounded += 1
        else:
            assert cuts[0] == cuts[1]
    return bounded


@settings(max_examples=40, deadline=None)
@given(points=clouds(), options=decomposition_options)
def test_refusing_on_the_larger_part_alone_changes_no_box(points, options):
    assert_same_tree(mvbb_ros.decompose(points, **options), fitting_every_part(points, **options))


@st.composite
def blocks(draw) -> np.ndarray:
    """Unions of two to four rough blocks of a few hundred points: shapes worth splitting."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    parts = []
    for _ in range(draw(st.integers(2, 4))):
        low = rng.uniform(-2.0, 2.0, 3)
        parts.append(solid(list(low), list(low + rng.uniform(0.2, 3.0, 3)), 150, rng))
    points = np.vstack(parts) + rng.normal(
        0.0, draw(st.sampled_from([0.0, 0.02])), (150 * len(parts), 3)
    )
    return points @ Rotation.random(random_state=rng.integers(2**31)).as_matrix().T


@settings(max_examples=30, deadline=None)
@given(
    points=blocks(),
    threshold=st.sampled_from([0.9, 0.94, 0.98]),
    cuts=st.integers(2, 4),
    order=st.sampled_from(['volume', 'depth']),
)
def test_rescoring_with_bounds_and_skipped_fits_changes_no_box(points, threshold, cuts, order):
    options = {'gain_threshold': threshold, 'rescore_cuts': cuts, 'order': order}
    assert_same_tree(mvbb_ros.decompose(points, **options), fitting_every_part(points, **options))


def test_a_split_refused_on_its_larger_part_alone_is_the_one_refused_with_both():
    rng = np.random.default_rng(8)
    points = np.vstack([l_shape(rng)[0], solid([6, 0, 0], [7, 2, 2], 1000, rng)])
    points += rng.normal(0.0, 0.02, points.shape)  # a rough surface: shaving it gains little
    fast = mvbb_ros.decompose(points, gain_threshold=0.98)
    assert_valid(fast, points)
    # The bound refused some splits here; each is also refused with both parts fitted.
    assert assert_same_tree(fast, fitting_every_part(points, gain_threshold=0.98)) > 0


def root_children_volume(result: mvbb_ros.Decomposition) -> float:
    """Return the summed volume of the root's children's boxes."""
    return math.fsum(result.nodes[i].box.volume for i in result.root.children)


def test_rescoring_never_makes_the_first_split_worse():
    rng = np.random.default_rng(6)
    points, _ = l_shape(rng)
    points = np.vstack([points, solid([0, 0, 1], [0.5, 0.5, 2.5], 500, rng)])  # an ear
    paper = mvbb_ros.decompose(points, gain_threshold=1.0, max_boxes=2)
    rescored = mvbb_ros.decompose(points, gain_threshold=1.0, max_boxes=2, rescore_cuts=6)
    assert_valid(rescored, points)

    assert root_children_volume(rescored) <= root_children_volume(paper) * (1.0 + 1e-12)
    assert rescored.root.gain <= paper.root.gain + 1e-12


@settings(max_examples=40, deadline=None)
@given(points=clouds(), cuts=st.integers(2, 4))
def test_rescoring_leaves_the_papers_cut_only_for_clearly_smaller_boxes(points, cuts):
    options = {'gain_threshold': 1.0, 'max_boxes': 2, 'min_points': 1}
    paper = mvbb_ros.decompose(points, **options)
    rescored = mvbb_ros.decompose(points, rescore_cuts=cuts, **options)
    assert_valid(rescored, points)
    if not rescored.root.children:
        return

    def parts(result: mvbb_ros.Decomposition) -> list[list[int]]:
        return sorted(sorted(result.nodes[i].point_indices.tolist()) for i in result.root.children)

    if paper.root.children and parts(rescored) == parts(paper):
        return
    # Another cut won: its boxes are smaller than the paper's cut's by more than the margin
    # (the paper's cut is always one of the candidates, so the paper's tree split too).
    assert paper.root.children
    margin = RESCORE_MARGIN * rescored.root.box.volume
    assert root_children_volume(rescored) < root_children_volume(paper) - margin


def test_volume_measure_is_an_option_not_the_default():
    rng = np.random.default_rng(7)
    points, volume = l_shape(rng)
    default = mvbb_ros.decompose(points)
    assert default.settings.split_measure == 'area'
    assert default.settings.rescore_cuts == 0
    assert default.root.cut.projection_axis is not None  # a 2D projection family
    option = mvbb_ros.decompose(points, split_measure='volume')
    assert_valid(option, points)
    assert option.root.cut.projection_axis is None
    assert option.leaf_volume == pytest.approx(volume, rel=0.05)


def test_units_do_not_change_the_result():
    rng = np.random.default_rng(8)
    points, _ = l_shape(rng)
    metres = mvbb_ros.decompose(points, gain_threshold=0.98)
    millimetres = mvbb_ros.decompose(points * 1000.0, gain_threshold=0.98)
    assert [node.parent for node in millimetres.nodes] == [node.parent for node in metres.nodes]
    assert millimetres.volume_ratio == pytest.approx(metres.volume_ratio, rel=1e-6)
    for node_mm, node_m in zip(millimetres.nodes, metres.nodes, strict=True):
        np.testing.assert_array_equal(node_mm.point_indices, node_m.point_indices)


def test_input_is_copied_and_left_alone():
    rng = np.random.default_rng(9)
    points = rng.normal(size=(200, 3)).astype(np.float32)
    before = points.copy()
    result = mvbb_ros.decompose(points)
    np.testing.assert_array_equal(points, before)
    assert result.points.dtype == np.float64
    assert not result.points.flags.writeable
    assert not result.leaf_point_indices[0].flags.writeable


# Degenerate and tiny inputs --------------------------------------------------------------------


def test_empty_input_is_refused_clearly():
    with pytest.raises(ValueError, match='at least one point'):
        mvbb_ros.decompose(np.empty((0, 3)))
    with pytest.raises(ValueError, match='at least one point'):
        mvbb_ros.decompose([])


@pytest.mark.parametrize(
    ('points', 'message'),
    [
        (np.zeros((4, 2)), r'shape \(N, 3\)'),
        (np.zeros(3), r'shape \(N, 3\)'),
        (np.array([[0.0, np.nan, 0.0]]), 'non-finite'),
        (np.array([[0.0, np.inf, 0.0]]), 'non-finite'),
        ([['a', 'b', 'c']], 'array of numbers'),
    ],
)
def test_malformed_input_is_refused_clearly(points, message):
    with pytest.raises(ValueError, match=message):
        mvbb_ros.decompose(points)


@pytest.mark.parametrize(
    ('option', 'value'),
    [
        ('gain_threshold', 1.5),
        ('gain_threshold', -0.1),
        ('gain_threshold', float('nan')),
        ('min_points', 0),
        ('min_points', 2.5),
        ('split_measure', 'perimeter'),
        ('rescore_cuts', -1),
        ('part_search', 'heavy'),
        ('max_boxes', 0),
        ('seed', -1),
        ('grid_cells', 1),
        ('order', 'random'),
    ],
)
def test_bad_settings_are_refused_by_name(option, value):
    with pytest.raises(ValueError, match=option):
        mvbb_ros.decompose(np.zeros((5, 3)), **{option: value})


DEGENERATE = {
    'one point': np.array([[1.0, 2.0, 3.0]]),
    'two points': np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]),
    'collinear': np.outer(np.r_[np.linspace(0, 1, 20), np.linspace(3, 4, 20)], [1.0, 2.0, -1.0]),
    'coplanar': np.column_stack(
        [np.random.default_rng(0).uniform(0, 1, (60, 2)) * [5, 1], np.full(60, 2.0)]
    ),
    'identical': np.tile([[0.5, -0.5, 2.0]], (25, 1)),
    'fewer than min_points': np.random.default_rng(1).normal(size=(5, 3)),
}


@pytest.mark.parametrize('name', list(DEGENERATE))
@pytest.mark.parametrize('min_points', [1, 10])
@pytest.mark.parametrize('split_measure', ['area', 'volume'])
def test_degenerate_input_gives_a_valid_result(name, min_points, split_measure):
    points = DEGENERATE[name]
    result = mvbb_ros.decompose(
        points, min_points=min_points, split_measure=split_measure, gain_threshold=0.98
    )
    assert_valid(result, points)
    if len(points) < min_points:
        # Too few points for one box: the root is dropped as noise.
        assert result.root.dropped and result.leaves == []
        np.testing.assert_array_equal(result.dropped_point_indices, np.arange(len(points)))
    else:
        assert result.leaves
        assert result.leaf_volume == pytest.approx(0.0, abs=1e-9 * result.root.box.extents.max())
    json.loads(result.to_json())


def test_one_point_gives_a_point_box():
    result = mvbb_ros.decompose([[1.0, 2.0, 3.0]], min_points=1)
    assert len(result.leaves) == 1
    np.testing.assert_allclose(result.leaves[0].center, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(result.leaves[0].extents, np.zeros(3))
    assert result.root.stop_reason == 'no_cut'


# JSON ------------------------------------------------------------------------------------------


def test_json_has_the_tree_and_the_boxes():
    rng = np.random.default_rng(10)
    points, _ = l_shape(rng)
    points = np.vstack([points, [[20.0, 20.0, 20.0]]])  # one outlier, dropped
    result = mvbb_ros.decompose(points, gain_threshold=0.94, min_points=5)
    document = json.loads(result.to_json())
    assert document['settings'] == {
        'gain_threshold': 0.94,
        'min_points': 5,
        'split_measure': 'area',
        'rescore_cuts': 0,
        'max_boxes': None,
        'seed': 0,
        'grid_cells': result.settings.grid_cells,
        'order': 'volume',
        'min_thickness': 0.0,
        'part_search': 'light',
    }
    assert document['point_count'] == len(points)
    assert document['dropped_point_count'] == 1
    assert document['leaves'] == [node.index for node in result.leaf_nodes]
    assert len(document['nodes']) == len(result.nodes)
    for entry, node in zip(document['nodes'], result.nodes, strict=True):
        assert entry['parent'] == node.parent
        assert entry['children'] == list(node.children)
        assert entry['point_count'] == node.point_count
        assert 'point_indices' not in entry
        quaternion = np.asarray(entry['box']['quaternion'])
        assert np.linalg.norm(quaternion) == pytest.approx(1.0)
        rebuilt = Box.from_dict(entry['box'])
        np.testing.assert_allclose(rebuilt.center, node.box.center)
        np.testing.assert_allclose(rebuilt.extents, node.box.extents)
        np.testing.assert_allclose(rebuilt.rotation, node.box.rotation, atol=1e-12)
        assert (entry['cut'] is None) == (node.cut is None)
    with_points = result.to_dict(include_point_indices=True)
    assert with_points['nodes'][0]['point_indices'] == list(range(len(points)))


# Real data (the paper's models) ----------------------------------------------------------------


def test_bunny_decomposes_and_more_boxes_at_higher_threshold():
    points = np.load(require_shared_data('models', 'bunny_vertices.npy'))
    results = [mvbb_ros.decompose(points, gain_threshold=t) for t in (0.90, 0.98)]
    for result in results:
        assert_valid(result, points)
    assert 1 < len(results[0].leaves) < len(results[1].leaves)
    assert results[1].volume_ratio < results[0].volume_ratio < 1.0


@settings(max_examples=30, deadline=None)
@given(
    points=blocks(),
    threshold=st.sampled_from([0.9, 0.94, 0.98]),
    cuts=st.integers(0, 4),
    order=st.sampled_from(['volume', 'gain', 'depth', 'breadth']),
    max_boxes=st.sampled_from([None, 2, 3]),
)
def test_the_fits_spread_over_workers_change_nothing(points, threshold, cuts, order, max_boxes):
    from mvbb_ros.common.workers import workers

    options = {
        'gain_threshold': threshold,
        'rescore_cuts': cuts,
        'order': order,
        'max_boxes': max_boxes,
    }
    alone = mvbb_ros.decompose(points, **options)
    for count in (2, 3):
        spread = mvbb_ros.decompose(points, pool=workers(count), **options)
        assert assert_same_tree(spread, alone) == 0, 'every gain the same, bit for bit'
        assert [n.gain for n in spread.nodes] == [n.gain for n in alone.nodes]
