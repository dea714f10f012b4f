"""Tests for mvbb_ros.geometry.views.raster: the grid of a view and the view drawn in it."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from mvbb_ros.geometry.views.raster import (
    CELLS_PER_SPACING,
    MAX_RASTER_SIDE,
    raster_grid,
    view_raster,
)
import numpy as np
import pytest


@settings(max_examples=40, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(1, 400),
    st.floats(0.3, 3.0),
    st.floats(0.002, 0.02),
)
def test_the_grid_alone_puts_every_point_in_the_cell_the_drawn_view_does(
    seed, count, distance, spacing
):
    """:func:`raster_grid`'s cells are :meth:`ViewRaster.locate`'s, for its points and others."""
    rng = np.random.default_rng(seed)
    eye = rng.normal(0.0, 0.5, 3)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    points = eye + distance * direction + rng.normal(0.0, 0.05, (count, 3))
    assume_in_front = (points - eye) @ direction > 0.0
    points = points[assume_in_front] if assume_in_front.any() else points[:0]
    if not len(points):
        return
    raster = view_raster(points, eye, spacing)
    grid = raster_grid(points, eye, spacing)
    assert (grid.rows, grid.cols) == raster.mask.shape
    # The grid's own terms: cells 1.5 spacings wide at the median range (at most 256 a side),
    # each point in the cell its ray crosses, the outline `margin` cells inside the border.
    relative = (points - eye) @ grid.frame.T
    tangent = relative[:, :2] / relative[:, 2:3]
    median = float(np.median(np.linalg.norm(points - eye, axis=1)))
    widest = float(np.max(np.ptp(tangent, axis=0)))
    assert grid.cell == max(CELLS_PER_SPACING * spacing / median, widest / MAX_RASTER_SIDE)
    own, _ = grid.cells(points)
    scaled = (tangent - grid.origin) / grid.cell  # its cell, but for rounding at a border
    assert np.all((own <= scaled + 1e-9) & (own > scaled - 1.0 - 1e-9))
    assert own.min() >= grid.margin - 1
    assert np.all(own.max(axis=0) < np.array([grid.rows, grid.cols]) - grid.margin + 1)
    others = np.concatenate([points, eye + rng.normal(0.0, 1.0, (50, 3))])
    for cloud in (points, others):
        cells, ranges = grid.cells(cloud)
        expected_cells, expected_ranges = raster.locate(cloud)
        np.testing.assert_array_equal(cells, expected_cells)
        np.testing.assert_array_equal(ranges, expected_ranges)


def test_a_grid_needs_a_viewing_direction():
    points = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match='surround the viewpoint'):
        raster_grid(points, np.zeros(3), 0.01)
