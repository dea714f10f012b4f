"""mvbb_ros/arrays.py: the column reductions and the cross product every layer takes."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mvbb_ros.arrays import (
    column_max,
    column_min,
    column_span,
    cross,
    lexicographic_order,
    perpendicular_axes,
    read_only,
)
import numpy as np
import pytest

finite = st.floats(-1e6, 1e6, allow_nan=False)
#: Shapes that broadcast against each other, each ending in 3.
pairs = hnp.mutually_broadcastable_shapes(num_shapes=2, min_dims=0, max_dims=3, max_side=4)


@settings(max_examples=60, deadline=None)
@given(pairs, st.data())
def test_cross_is_numpys_bit_for_bit_with_its_broadcasting(shapes, data):
    first, second = (
        data.draw(hnp.arrays(np.float64, (*shape, 3), elements=finite))
        for shape in shapes.input_shapes
    )
    ours = cross(first, second)
    numpys = np.cross(first, second)
    assert ours.shape == numpys.shape
    np.testing.assert_array_equal(ours, numpys)
    assert np.array_equal(np.signbit(ours), np.signbit(numpys)), 'signed zeros as numpy'


@settings(max_examples=30, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 50), st.integers(1, 4)), elements=finite))
def test_column_reductions_are_numpys(values):
    np.testing.assert_array_equal(column_min(values), values.min(axis=0))
    np.testing.assert_array_equal(column_max(values), values.max(axis=0))
    np.testing.assert_array_equal(column_span(values), values.max(axis=0) - values.min(axis=0))


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(np.float64, 3, elements=st.floats(-1.0, 1.0)).filter(lambda v: v @ v > 1e-6))
def test_perpendicular_axes_make_a_right_handed_frame_with_the_axis(direction):
    axis = direction / np.linalg.norm(direction)
    first, second = perpendicular_axes(axis)
    frame = np.stack([first, second, axis])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(frame) > 0.0


def test_read_only_is_a_float_copy_that_cannot_be_written():
    source = np.array([[1, 2, 3]], dtype=np.int32)
    frozen = read_only(source)
    assert frozen.dtype == np.float64 and not frozen.flags.writeable
    np.testing.assert_array_equal(frozen, source)
    source[0, 0] = 7
    assert frozen[0, 0] == 1.0, 'a copy, not a view'
    with pytest.raises(ValueError):
        frozen[0, 0] = 5.0


@settings(max_examples=80, deadline=None)
@given(
    hnp.arrays(
        np.float64,
        st.tuples(st.integers(0, 60), st.integers(1, 3)),
        elements=st.sampled_from([-1.0, -0.0, 0.0, 0.5, 2.0]) | finite,
    )
)
def test_lexicographic_order_is_lexsorts_with_and_without_ties(keys):
    columns = [keys[:, column] for column in range(keys.shape[1])]
    np.testing.assert_array_equal(lexicographic_order(*columns), np.lexsort(columns[::-1]))
