"""Tests for the split measure theta and the best cut (geometry.split, paper Sec. III-C)."""

from __future__ import annotations

import itertools

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.decomposition import split
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

IDENTITY_BOX = Box(center=np.zeros(3), rotation=np.eye(3), extents=np.ones(3))


def brute_force_theta(local: np.ndarray, cells: int, measure: str) -> np.ndarray:
    """Theta of every family and cut by explicit masks, one cut at a time (reference)."""
    index = split.grid_cell_index(local, cells)
    whole = local.max(axis=0) - local.min(axis=0)
    families = split.AREA_FAMILIES if measure == 'area' else [(None, axis) for axis in range(3)]
    theta = np.full((len(families), cells - 1), np.inf)
    for row, (projection_axis, axis) in enumerate(families):
        kept_axes = [k for k in range(3) if k != projection_axis]
        whole_size = np.prod(whole[kept_axes])
        if whole_size <= 0.0:
            continue
        for cell in range(1, cells):
            upper = index[:, axis] >= cell
            if upper.all() or not upper.any():
                continue
            size = 0.0
            for part in (local[~upper], local[upper]):
                extent = part.max(axis=0) - part.min(axis=0)
                size += np.prod(extent[kept_axes])
            theta[row, cell - 1] = size / whole_size
    return theta


def lattice(low: list[float], high: list[float], step: float = 0.25) -> np.ndarray:
    """Points of a regular lattice filling the axis-aligned block low..high (exact values)."""
    axes = [np.arange(lo, hi + step / 2, step) for lo, hi in zip(low, high, strict=True)]
    return np.array(list(itertools.product(*axes)))


def cube_and_plate() -> np.ndarray:
    """Return a unit cube [0, 1]^3 and, past a gap along x, a plate [3, 4] x [0, 1] x [0, 0.25]."""
    return np.vstack([lattice([0, 0, 0], [1, 1, 1]), lattice([3, 0, 0], [4, 1, 0.25])])


points_strategy = st.integers(2, 60).flatmap(
    lambda n: arrays(np.float64, (n, 3), elements=st.floats(-10.0, 10.0, width=32))
)


def test_families_follow_the_paper():
    # eq. 1: theta_1(A, c), theta_2(A, b), theta_3(C, a), theta_4(C, b), theta_5(B, a),
    # theta_6(B, c), where face A has normal a (axis 0), B normal b and C normal c.
    assert split.AREA_FAMILIES == ((0, 2), (0, 1), (2, 0), (2, 1), (1, 0), (1, 2))
    scores = split.score_cuts(cube_and_plate(), cells=8)
    assert scores.families == split.AREA_FAMILIES
    labels = []
    for projection_axis, axis in split.AREA_FAMILIES:
        cut = split.Cut(
            axis=axis,
            projection_axis=projection_axis,
            cell=1,
            cells=8,
            offset=0.0,
            theta=0.5,
            lower_count=1,
            upper_count=1,
            point=np.zeros(3),
            normal=np.eye(3)[axis],
        )
        labels.append((cut.family, cut.label))
    assert labels == [
        (1, 'theta_1(A, c)'),
        (2, 'theta_2(A, b)'),
        (3, 'theta_3(C, a)'),
        (4, 'theta_4(C, b)'),
        (5, 'theta_5(B, a)'),
        (6, 'theta_6(B, c)'),
    ]


@pytest.mark.parametrize('measure', ['area', 'volume'])
@settings(max_examples=60, deadline=None)
@given(local=points_strategy, cells=st.integers(2, 20))
def test_vectorised_scores_equal_brute_force(measure, local, cells):
    scores = split.score_cuts(local, cells=cells, measure=measure)
    expected = brute_force_theta(local, cells, measure)
    assert scores.theta.shape == expected.shape
    finite = np.isfinite(expected)
    assert np.array_equal(np.isfinite(scores.theta), finite)
    np.testing.assert_allclose(scores.theta[finite], expected[finite], rtol=1e-9, atol=1e-12)


def test_best_cut_of_cube_and_plate_is_in_the_gap():
    points = cube_and_plate()
    cut = split.best_cut(points, IDENTITY_BOX, cells=8)
    assert cut is not None
    # Cutting x in the gap: in face B (x, z) the parts' rectangles are the cube's 1 x 1 and the
    # plate's 1 x 0.25, over the whole 4 x 1: theta = 1.25 / 4. Every other cut is worse.
    assert cut.label == 'theta_5(B, a)'
    assert cut.theta == pytest.approx(1.25 / 4.0)
    upper = split.cut_mask(split.score_cuts(points, cells=8), cut)
    assert np.array_equal(upper, points[:, 0] >= 3.0)
    assert cut.offset == pytest.approx(2.0)  # midway between x = 1 and x = 3
    assert (cut.lower_count, cut.upper_count) == (125, 25 * 2)


def test_volume_measure_on_cube_and_plate():
    cut = split.best_cut(cube_and_plate(), IDENTITY_BOX, cells=8, measure='volume')
    assert cut is not None
    assert cut.projection_axis is None and cut.family is None
    assert cut.label == 'volume(a)'
    # Boxes 1 x 1 x 1 and 1 x 1 x 0.25 over the whole 4 x 1 x 1.
    assert cut.theta == pytest.approx(1.25 / 4.0)


@settings(max_examples=40, deadline=None)
@given(local=points_strategy, cells=st.integers(2, 40))
def test_cut_plane_separates_the_parts(local, cells):
    box = Box.enclosing(local)
    scores = split.score_cuts(box.to_local(local), cells=cells)
    for cut in split.candidate_cuts(scores, box, limit=5):
        upper = split.cut_mask(scores, cut)
        assert upper.sum() == cut.upper_count
        assert (~upper).sum() == cut.lower_count
        assert cut.lower_count > 0 and cut.upper_count > 0
        signed = (local - cut.point) @ cut.normal
        assert np.all(signed[upper] >= -1e-9)
        assert np.all(signed[~upper] <= 1e-9)
        assert np.isclose(np.linalg.norm(cut.normal), 1.0)


@settings(max_examples=40, deadline=None)
@given(local=points_strategy, limit=st.integers(1, 8))
def test_candidates_are_distinct_and_ranked(local, limit):
    scores = split.score_cuts(local, cells=16)
    cuts = split.candidate_cuts(scores, IDENTITY_BOX, limit=limit)
    assert len(cuts) <= limit
    if np.isfinite(scores.theta).any():
        assert cuts and cuts[0].theta == pytest.approx(float(np.min(scores.theta)))
    else:
        assert cuts == []
    assert [cut.theta for cut in cuts[1:]] == sorted(cut.theta for cut in cuts[1:])
    partitions = set()
    for cut in cuts:
        upper = split.cut_mask(scores, cut)
        partitions.add(tuple(upper ^ upper[0]))  # the same two parts in either order
    assert len(partitions) == len(cuts)


def test_theta_is_scale_and_rotation_free():
    rng = np.random.default_rng(3)
    points = np.vstack([rng.uniform(0, 1, (200, 3)), rng.uniform(0, 1, (50, 3)) * [3, 0.2, 0.2]])
    rotation = Rotation.from_euler('xyz', [0.3, -1.1, 2.0]).as_matrix()
    box = Box.enclosing(points)
    moved_box = box.transformed(rotation * 1.0, [5.0, -2.0, 1.0])
    scale = 1000.0  # metres to millimetres
    moved = (points @ rotation.T + [5.0, -2.0, 1.0]) * scale
    moved_box = Box(
        center=moved_box.center * scale, rotation=moved_box.rotation, extents=box.extents * scale
    )
    first = split.best_cut(points, box)
    second = split.best_cut(moved, moved_box)
    assert first is not None and second is not None
    assert (first.axis, first.projection_axis, first.cell) == (
        second.axis,
        second.projection_axis,
        second.cell,
    )
    assert first.theta == pytest.approx(second.theta, rel=1e-9)
    assert second.offset == pytest.approx(first.offset * scale, rel=1e-9)


@pytest.mark.parametrize(
    'points',
    [
        np.zeros((1, 3)),
        np.ones((7, 3)),
        np.outer(np.linspace(0, 1, 9), [1.0, 0.0, 0.0]) + [0.0, 2.0, 3.0],
    ],
    ids=['one point', 'identical', 'collinear'],
)
def test_no_cut_without_area(points):
    # One point, duplicates and points on a line along a box axis (as in their own MVBB)
    # project to rectangles of zero area in every face, so no cut has a finite theta.
    assert split.best_cut(points, IDENTITY_BOX) is None
    assert split.best_cut(points, IDENTITY_BOX, measure='volume') is None


def test_coplanar_points_are_cut_in_their_plane():
    rng = np.random.default_rng(0)
    left = rng.uniform(0, 1, (100, 2))
    right = rng.uniform(0, 1, (100, 2)) * [1.0, 0.1] + [3.0, 0.0]
    points = np.column_stack([np.vstack([left, right]), np.zeros(200)])
    cut = split.best_cut(points, IDENTITY_BOX)
    assert cut is not None
    assert cut.axis == 0 and cut.projection_axis == 2  # the only face with area
    assert cut.lower_count == 100 and cut.upper_count == 100
    # Flat points have no volume to split.
    assert split.best_cut(points, IDENTITY_BOX, measure='volume') is None


def test_two_points_are_split_apart():
    points = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5]])
    cut = split.best_cut(points, IDENTITY_BOX)
    assert cut is not None
    assert (cut.lower_count, cut.upper_count) == (1, 1)
    assert cut.theta == 0.0


@pytest.mark.parametrize(
    ('kwargs', 'message'),
    [({'cells': 1}, 'grid_cells'), ({'measure': 'perimeter'}, 'split_measure')],
)
def test_bad_arguments_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        split.score_cuts(cube_and_plate(), **kwargs)


def test_no_points_are_refused():
    with pytest.raises(ValueError, match='at least one point'):
        split.score_cuts(np.empty((0, 3)))


def test_cut_to_dict_is_plain_json():
    cut = split.best_cut(cube_and_plate(), IDENTITY_BOX, cells=8)
    data = cut.to_dict()
    assert data['label'] == cut.label
    assert data['family'] == 5
    assert isinstance(data['point'], list) and len(data['normal']) == 3
    assert data['lower_count'] + data['upper_count'] == len(cube_and_plate())


@pytest.mark.parametrize('measure', ['area', 'volume'])
@settings(max_examples=40, deadline=None)
@given(local=points_strategy, cells=st.integers(2, 20), floor=st.floats(0.0, 5.0))
def test_thickness_floor_drops_exactly_the_thin_cuts(measure, local, cells, floor):
    """With a floor, a cut stays a candidate iff both parts are that thick along its axis."""
    plain = split.score_cuts(local, cells=cells, measure=measure)
    floored = split.score_cuts(local, cells=cells, measure=measure, min_thickness=floor)
    index = split.grid_cell_index(local, cells)
    for row, (_, axis) in enumerate(plain.families):
        for position in range(cells - 1):
            upper = index[:, axis] >= position + 1
            parts = [local[~upper, axis], local[upper, axis]]
            thick = all(len(part) and np.ptp(part) >= floor for part in parts)
            expected = plain.theta[row, position] if thick or floor == 0.0 else np.inf
            assert floored.theta[row, position] == expected


def test_a_subnormal_range_still_gets_its_cells():
    """A range of 1e-313 overflows cells / range: the offset is divided by the range."""
    local = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 2.2250738585e-313], [0.5, 0.2, 1e-313]])
    index = split.grid_cell_index(local, 4)
    np.testing.assert_array_equal(index[:, 2], [0, 3, 1])
    scores = split.score_cuts(local, cells=4)
    assert np.all(scores.lower_count >= 0) and np.isfinite(scores.theta).any()
