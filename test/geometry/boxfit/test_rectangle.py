"""The compiled 2D hull and rotating calipers (mvbb_ros.geometry.boxfit.rectangle)."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mvbb_ros.geometry.boxfit.rectangle import calipers_kernel, hull_2d_kernel, min_area_rectangle
import numpy as np
import pytest
from scipy.spatial import ConvexHull


def _brute_force_rectangle_area(points):
    """Return the smallest rectangle area flush with a hull edge (Freeman and Shapira)."""
    scale = np.abs(points).max()
    polygon = points[ConvexHull(points / scale).vertices] / scale
    edges = np.roll(polygon, -1, axis=0) - polygon
    units = edges / np.linalg.norm(edges, axis=1)[:, None]
    normals = np.column_stack([-units[:, 1], units[:, 0]])
    areas = np.ptp(units @ polygon.T, axis=1) * np.ptp(normals @ polygon.T, axis=1)
    return areas.min() * scale**2


def _hull_2d(points):
    x = np.ascontiguousarray(points[:, 0])
    y = np.ascontiguousarray(points[:, 1])
    order = np.arange(len(points))
    out = np.empty(len(points) + 1, dtype=np.int64)
    size = hull_2d_kernel(x, y, order, len(points), out)
    return out[:size]


def _rank(points):
    centered = points - points.mean(axis=0)
    singular = np.linalg.svd(centered, compute_uv=False)
    return int(np.sum(singular > 1e-9 * max(singular.max(), 1e-300)))


@settings(max_examples=80, deadline=None)
@given(
    points=hnp.arrays(
        np.float64,
        st.tuples(st.integers(3, 200), st.just(2)),
        elements=st.floats(-100.0, 100.0, allow_nan=False),
    )
)
def test_min_area_rectangle_matches_brute_force_and_encloses(points):
    rectangle = min_area_rectangle(points)
    local = (points - rectangle.center) @ rectangle.axes
    scale = 1.0 + np.abs(points).max()
    assert np.all(np.abs(local) <= rectangle.extents / 2.0 + 1e-9 * scale)
    assert np.linalg.det(rectangle.axes) == pytest.approx(1.0)
    if _rank(points) == 2 and len(_hull_2d(points)) >= 3:
        expected = _brute_force_rectangle_area(points)
        assert rectangle.area == pytest.approx(expected, rel=1e-9, abs=1e-12 * scale**2)
    else:
        assert rectangle.area <= 1e-9 * scale**2


@settings(max_examples=80, deadline=None)
@given(
    points=hnp.arrays(
        np.float64,
        st.tuples(st.integers(1, 300), st.just(2)),
        elements=st.sampled_from([-2.0, -1.0, 0.0, 0.5, 1.0, 4.0]),
    )
)
def test_hull_2d_of_grid_points_is_qhull_without_collinear_vertices(points):
    found = _hull_2d(points)
    distinct = np.unique(points, axis=0)
    if len(distinct) == 1:
        assert len(found) == 1
        return
    if _rank(points) < 2:
        assert len(found) == 2
        return
    expected = ConvexHull(points)
    assert {tuple(p) for p in points[found]} == {tuple(p) for p in points[expected.vertices]}
    polygon = points[found]
    first = np.roll(polygon, -1, axis=0) - polygon
    second = np.roll(polygon, -2, axis=0) - polygon
    turns = first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0]
    assert np.all(turns > 0.0)


def test_calipers_on_regular_polygons():
    for sides in range(3, 40):
        angles = 2.0 * np.pi * np.arange(sides) / sides + 0.3
        x = np.cos(angles)
        y = np.sin(angles)
        area, dx, dy = calipers_kernel(x, y, np.arange(sides + 1) % sides, sides)
        expected = _brute_force_rectangle_area(np.column_stack([x, y]))
        assert area == pytest.approx(expected, rel=1e-12)
        assert np.hypot(dx, dy) == pytest.approx(1.0)


def test_hull_and_calipers_agree_with_brute_force_on_shuffled_polygons_with_repeats():
    """Polygons as the 3D search meets them: shuffled, repeated vertices, points on edges."""
    rng = np.random.default_rng(10)
    for _ in range(200):
        cloud = rng.normal(size=(rng.integers(3, 30), 2)) * rng.uniform(0.1, 5.0, size=2)
        polygon = cloud[ConvexHull(cloud).vertices]
        extra = np.vstack([polygon[:2], (polygon[0] + polygon[1]) / 2.0])
        shuffled = rng.permutation(np.vstack([polygon, extra]))
        x = np.ascontiguousarray(shuffled[:, 0])
        y = np.ascontiguousarray(shuffled[:, 1])
        # The midpoint may stay a vertex (it is collinear only up to rounding).
        found = _hull_2d(shuffled)
        assert len(polygon) <= len(found) <= len(polygon) + 1
        outline = np.append(found, 0)
        area, dx, dy = calipers_kernel(x, y, outline, len(found))
        assert area == pytest.approx(_brute_force_rectangle_area(polygon), rel=1e-9)
        assert np.hypot(dx, dy) == pytest.approx(1.0)
    # Fewer than two vertices: no rectangle to turn, area 0 along the first axis.
    assert calipers_kernel(np.zeros(1), np.zeros(1), np.zeros(2, dtype=np.int64), 1) == (
        0.0,
        1.0,
        0.0,
    )


def _walked_calipers(x, y, polygon, size):
    """Walk the rotating calipers in Python: each vertex moves on while its test passes."""
    if size < 2:
        return 0.0, 1.0, 0.0
    corners = [(float(x[polygon[i]]), float(y[polygon[i]])) for i in range(size)]
    if size == 2:
        dx, dy = corners[1][0] - corners[0][0], corners[1][1] - corners[0][1]
        length = float(np.hypot(dx, dy))  # the C library's, as the kernel's
        return (0.0, dx / length, dy / length) if length > 0.0 else (0.0, 1.0, 0.0)
    edges = [
        (corners[(i + 1) % size][0] - corners[i][0], corners[(i + 1) % size][1] - corners[i][1])
        for i in range(size)
    ]
    tests = (
        lambda ex, ey, e: ex * e[0] + ey * e[1] > 0.0,
        lambda ex, ey, e: ex * e[1] - ey * e[0] > 0.0,
        lambda ex, ey, e: ex * e[0] + ey * e[1] < 0.0,
    )

    def walk(position, ex, ey, test):
        for _ in range(size):
            if not test(ex, ey, edges[position]):
                break
            position = (position + 1) % size
        return position

    best, best_x, best_y = math.inf, 1.0, 0.0
    right = top = left = 1
    for i, (ex, ey) in enumerate(edges):
        squared = ex * ex + ey * ey
        if not squared > 0.0:
            continue
        right = walk(right, ex, ey, tests[0])
        top = walk(right if i == 0 else top, ex, ey, tests[1])
        left = walk(top if i == 0 else left, ex, ey, tests[2])
        along = ex * (corners[right][0] - corners[left][0]) + ey * (
            corners[right][1] - corners[left][1]
        )
        across = ex * (corners[top][1] - corners[i][1]) - ey * (corners[top][0] - corners[i][0])
        if along * across < best * squared:
            best, best_x, best_y = along * across / squared, ex, ey
    if best == math.inf:
        return 0.0, 1.0, 0.0
    length = float(np.hypot(best_x, best_y))
    return max(best, 0.0), best_x / length, best_y / length


@settings(max_examples=300, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(1, 60),
    shape=st.sampled_from(['hull', 'any', 'clockwise', 'repeats', 'collinear', 'grid']),
)
def test_property_calipers_are_the_walk_bit_for_bit(seed, count, shape):
    """
    The merges give the walk's rectangle exactly, on any polygon the search can pass.

    Convex outlines (from the 2D hull, from any start, with repeated corners or on an integer
    grid, whose hulls have exact right angles) and polygons that are not convex: clockwise
    ones, collinear points, any points in any order (where a walk goes round and the kernel
    walks instead).
    """
    rng = np.random.default_rng(seed)
    if shape in ('hull', 'grid'):
        cloud = rng.normal(size=(count + 3, 2)) * rng.uniform(0.01, 3.0, size=2)
        if shape == 'grid':
            cloud = np.round(3.0 * cloud)
        x = np.ascontiguousarray(cloud[:, 0])
        y = np.ascontiguousarray(cloud[:, 1])
        found = _hull_2d(cloud)
        start = int(rng.integers(len(found)))
        polygon = np.append(np.roll(found, start), found[start])
        size = len(found)
    else:
        angles = np.sort(rng.uniform(0.0, 2.0 * np.pi, count))
        if shape == 'clockwise':
            angles = angles[::-1]
        if shape == 'repeats':
            angles = np.repeat(angles, rng.integers(1, 3, size=count))
        x, y = np.cos(angles), rng.uniform(0.1, 2.0) * np.sin(angles)
        if shape == 'any':
            x, y = rng.normal(size=count), rng.normal(size=count)
        if shape == 'collinear':
            x = rng.normal(size=count)
            y = 0.5 * x
        size = len(x)
        polygon = np.arange(size + 1) % size
    assert calipers_kernel(x, y, polygon, size) == _walked_calipers(x, y, polygon, size)


def test_min_area_rectangle_of_degenerate_planar_points():
    assert min_area_rectangle([[2.0, 3.0]]).area == 0.0
    segment = min_area_rectangle([[0.0, 0.0], [3.0, 4.0], [1.5, 2.0], [3.0, 4.0]])
    np.testing.assert_allclose(segment.extents, [5.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(segment.center, [1.5, 2.0], atol=1e-12)
    ends = segment.corners()[[0, 2]]
    assert {tuple(np.round(p, 12)) for p in ends} == {(0.0, 0.0), (3.0, 4.0)}
    with pytest.raises(ValueError, match='empty'):
        min_area_rectangle(np.zeros((0, 2)))
    with pytest.raises(ValueError, match='finite'):
        min_area_rectangle([[0.0, np.nan]])
    with pytest.raises(ValueError, match='shape'):
        min_area_rectangle(np.zeros((3, 3)))


def test_many_points_go_through_the_octagon_cull():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(50_000, 2)) * [3.0, 1.0]
    rectangle = min_area_rectangle(points)
    assert rectangle.area == pytest.approx(_brute_force_rectangle_area(points), rel=1e-9)
