"""The cell binning that every compiled neighbour search uses."""

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mvbb_ros.geometry.views.cells import cell_grid, cell_key, cell_start, key_order
import numpy as np


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
