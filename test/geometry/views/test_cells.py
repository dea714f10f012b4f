"""The cell binning that every compiled neighbour search uses."""

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mvbb_ros.geometry.views.cells import (
    cell_grid,
    cell_key,
    cell_start,
    key_order,
    neighbour_distances,
)
import numpy as np
from scipy.spatial import cKDTree


@settings(max_examples=200, deadline=None)
@given(arrays(np.int64, st.integers(0, 300), elements=st.integers(-50, 50)))
def test_key_order_is_numpys_stable_argsort(keys: np.ndarray) -> None:
    np.testing.assert_array_equal(key_order(keys), np.argsort(keys, kind='stable'))


@settings(max_examples=100, deadline=None)
@given(
    arrays(np.float64, st.tuples(st.integers(1, 200), st.just(3)), elements=st.floats(-1, 1)),
    st.floats(0.01, 0.5),
)
def test_a_cell_lists_exactly_the_points_binned_in_it(points: np.ndarray, width: float) -> None:
    cells, span, order, sorted_keys = cell_grid(points, width, 1)
    assert np.all(cells >= 1) and np.all(cells < span - 1)
    for i in range(len(points)):
        key = cell_key(cells[i, 0], cells[i, 1], cells[i, 2], span)
        start = cell_start(sorted_keys, key)
        end = start
        while end < len(sorted_keys) and sorted_keys[end] == key:
            end += 1
        same = np.flatnonzero(np.all(cells == cells[i], axis=1))
        assert sorted(order[start:end]) == list(same)


@settings(max_examples=300, deadline=None)
@given(
    count=st.integers(1, 600),
    scale=st.tuples(*(st.sampled_from([1e-3, 0.05, 1.0, 30.0]) for _ in range(3))),
    duplicates=st.integers(0, 50),
    grid=st.sampled_from([0.0, 0.01, 0.1]),
    single=st.booleans(),
    seed=st.integers(0, 10_000),
)
def test_neighbour_distances_are_the_k_d_trees_bit_for_bit(
    count, scale, duplicates, grid, single, seed
):
    """The sorted sweep gives the very floats of scipy's k-d tree, ties and duplicates too."""
    rng = np.random.default_rng(seed)
    points = rng.normal(0.0, 1.0, (count, 3)) * scale
    if grid:  # points on a lattice: many equal distances and equal coordinates
        points = np.round(points / grid) * grid
    points = np.concatenate([points, points[rng.integers(0, count, duplicates)]])
    if single:  # float32 points, as decoded
        points = points.astype(np.float32).astype(np.float64)
    axis = int(np.argmax(np.ptp(points, axis=0)))
    order = np.argsort(points[:, axis])
    queries = np.arange(0, len(points), max(1, len(points) // 97))
    expected = cKDTree(points).query(points[queries], k=2)[0][:, 1]
    found = neighbour_distances(np.ascontiguousarray(points), order, axis, queries)
    np.testing.assert_array_equal(found, expected)
    # Any axis, any sorting order of ties: the same distances.
    other = (axis + 1) % 3
    order = np.argsort(points[:, other], kind='stable')
    np.testing.assert_array_equal(neighbour_distances(points, order, other, queries), expected)
