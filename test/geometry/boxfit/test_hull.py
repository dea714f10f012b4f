"""The compiled quickhull and grid coreset (geometry/boxfit/hull.py): exactness, topology, rank."""

from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mvbb_ros.geometry.boxfit import hull
import numpy as np
import pytest
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation


def _assert_closed_hull(found, points, slack=1e-9):
    """Check a closed, outward, triangulated surface that holds every point (to `slack`)."""
    assert found.status == hull.FULL_RANK
    facets, edges, edge_facets = found.facets, found.edges, found.edge_facets
    count = len(facets)
    assert count >= 4
    assert len(found.normals) == len(found.areas) == count
    # Each edge once, shared by exactly two facets.
    assert len(edges) * 2 == 3 * count
    # Euler: V - E + F = 2 for a sphere.
    assert len(found.vertices) - len(edges) + count == 2
    # Every directed facet edge appears once, and its reverse once.
    directed = {(a, b) for f in facets for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
    assert len(directed) == 3 * count
    assert all((b, a) in directed for a, b in directed)
    for (a, b), (f, g) in zip(edges, edge_facets, strict=True):
        assert {a, b} <= set(facets[f]) and {a, b} <= set(facets[g])
    np.testing.assert_allclose(np.linalg.norm(found.normals, axis=1), 1.0)
    vertices = points[found.vertices]
    corners = vertices[facets]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    np.testing.assert_allclose(0.5 * np.linalg.norm(cross, axis=1), found.areas, rtol=1e-9)
    offsets = np.einsum('fk,fk->f', found.normals, corners.mean(axis=1))
    # Outward: the vertices' centroid lies below every facet plane (to rounding, for slivers).
    size = np.abs(points).max()
    assert np.all(found.normals @ vertices.mean(axis=0) - offsets < 1e-9 * size)
    if slack is not None:
        # Every input point lies below every facet plane (to the tolerance).
        heights = points @ found.normals.T - offsets
        assert heights.max() <= slack * size


@pytest.mark.parametrize('shape', ['ball', 'sphere', 'cuboid', 'gauss'])
def test_quickhull_finds_the_qhull_hull(shape):
    rng = np.random.default_rng(12)
    points = rng.normal(size=(20_000, 3))
    if shape == 'ball':
        points *= (
            rng.uniform(size=(len(points), 1)) ** (1.0 / 3.0)
            / np.linalg.norm(points, axis=1)[:, None]
        )
    elif shape == 'sphere':
        points = points[:3000] / np.linalg.norm(points[:3000], axis=1)[:, None]
    elif shape == 'cuboid':
        half = np.array([0.3, 0.2, 0.1])
        corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * 3)).reshape(3, -1).T * half
        points = np.vstack([corners, rng.uniform(-1.0, 1.0, size=(20_000, 3)) * half])
        points = points @ Rotation.random(random_state=1).as_matrix().T
    found = hull.convex_hull(points)
    expected = ConvexHull(points)
    assert set(found.vertices.tolist()) == set(expected.vertices.tolist())
    assert found.areas.sum() == pytest.approx(expected.area, rel=1e-9)
    _assert_closed_hull(found, points)


def test_small_clouds_far_away_get_the_exact_hull():
    """The fit hulls centred, unit-size coordinates: there the hull is exactly Qhull's."""
    points = np.random.default_rng(22).normal(size=(500, 3)) * [3.0, 2.0, 1.0] + 100.0
    centered = (points - points.mean(axis=0)) / np.abs(points - points.mean(axis=0)).max()
    found = hull.convex_hull(centered)
    assert set(found.vertices.tolist()) == set(ConvexHull(centered).vertices.tolist())


def test_flat_and_tiny_inputs_report_their_rank_and_never_raise():
    assert hull.convex_hull(np.zeros((0, 3))).status == 0
    assert hull.convex_hull(np.ones((5, 3))).status == 0
    line = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    assert hull.convex_hull(line).status == 1
    flat = np.column_stack([np.random.default_rng(13).normal(size=(50, 2)), np.zeros(50)])
    # Exactly flat (Qhull refuses such input): rank 2 and empty fields, no error.
    found = hull.convex_hull(flat)
    assert found.status == 2
    assert len(found.vertices) == len(found.facets) == len(found.edges) == 0
    # Three points make no solid whatever they are.
    assert hull.convex_hull(flat[:3]).status == 2
    found = hull.convex_hull(np.vstack([flat, [[0.0, 0.0, 1.0]]]))
    assert found.status == hull.FULL_RANK


def test_grids_with_many_coplanar_and_collinear_points_give_closed_hulls():
    axis = np.linspace(-1.0, 1.0, 7)
    grid = np.array(np.meshgrid(axis, axis, axis)).reshape(3, -1).T
    for seed in range(5):
        points = grid @ Rotation.random(random_state=seed).as_matrix().T
        found = hull.convex_hull(points)
        _assert_closed_hull(found, points)
        # The cube's corners are hull vertices; points on its faces may or may not be.
        corner_ids = np.flatnonzero(np.all(np.abs(grid) == 1.0, axis=1))
        assert set(corner_ids.tolist()) <= set(found.vertices.tolist())


@settings(max_examples=150, deadline=None)
@given(
    points=hnp.arrays(
        np.float64,
        st.tuples(st.integers(4, 120), st.just(3)),
        elements=st.sampled_from([-1.0, -0.5, 0.0, 0.25, 1.0]),
    ),
    seed=st.integers(0, 2**16),
    thin=st.sampled_from([1.0, 1e-3, 1e-5, 1e-7, 1e-9]),
)
def test_quickhull_never_fails_on_degenerate_rich_input(points, seed, thin):
    points = points * [1.0, 1.0, thin] @ Rotation.random(random_state=seed).as_matrix().T
    found = hull.convex_hull(points)
    assert found.status in (0, 1, 2, 3)
    if found.status != hull.FULL_RANK:
        return
    if thin >= 1e-5:
        _assert_closed_hull(found, points)
        return
    # Thinner than the fit hulls alone (fit.FLAT_SEARCH): grid points coplanar with sliver
    # facets may be dropped, but the surface stays closed and faces outward.
    _assert_closed_hull(found, points, slack=None)


def _brute_force_columns(points, cells):
    """Return, per axis, the columns of `points` (lists of indices), as the kernel defines them."""
    low = points.min(axis=0)
    span = points.max(axis=0) - low
    # The offset times cells / span, or over the span where that quotient overflows (subnormal).
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        factor = np.where(span > 0.0, cells / np.where(span > 0.0, span, 1.0), 0.0)
        divided = (
            np.where(span > 0.0, (points - low) / np.where(span > 0.0, span, 1.0), 0.0) * cells
        )
        scaled = np.where(
            np.isfinite(factor),
            (points - low) * np.where(np.isfinite(factor), factor, 0.0),
            divided,
        )
    bins = np.minimum(scaled.astype(int), cells - 1)
    out = []
    for axis in range(3):
        others = [(axis + 1) % 3, (axis + 2) % 3]
        columns = {}
        for index, key in enumerate(map(tuple, bins[:, others])):
            columns.setdefault(key, []).append(index)
        out.append(list(columns.values()))
    return out


@settings(max_examples=60, deadline=None)
@given(
    points=hnp.arrays(
        np.float64,
        st.tuples(st.integers(1, 400), st.just(3)),
        elements=st.floats(-5.0, 5.0, allow_nan=False, allow_infinity=False),
    ),
    cells=st.integers(1, 12),
)
# Found on main: a subnormal span made the numpy version index out of its columns.
@example(points=np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.2250738585e-313]]), cells=2)
@example(points=np.array([[0.0, 1.0, 2.0], [5e-324, 1.0, 2.0], [0.0, 1.0, 2.0]]), cells=12)
def test_column_extremes_keeps_exactly_the_extremes_of_every_column(points, cells):
    """Every kept point is a top or bottom of its column; every column keeps its top and bottom."""
    kept = hull.column_extremes(points, cells)
    assert np.all(np.diff(kept) > 0)
    kept_set = set(kept.tolist())
    extremes = set()
    for axis, columns in enumerate(_brute_force_columns(points, cells)):
        for members in columns:
            heights = points[members, axis]
            tops = {m for m, h in zip(members, heights, strict=True) if h == heights.max()}
            bottoms = {m for m, h in zip(members, heights, strict=True) if h == heights.min()}
            assert tops & kept_set and bottoms & kept_set
            extremes |= tops | bottoms
    assert kept_set <= extremes


def test_the_coreset_hull_lies_inside_the_exact_one_and_spans_it():
    # A large cloud on an ellipsoid (every point a hull vertex): its coreset keeps far fewer.
    many = np.random.default_rng(23).normal(size=(8000, 3))
    many = many / np.linalg.norm(many, axis=1)[:, None] * [0.9, 0.6, 0.3]
    coreset = many[hull.column_extremes(many, 32)]
    exact = hull.convex_hull(many)
    found = hull.convex_hull(coreset)
    assert len(found.vertices) < len(exact.vertices)
    planes = ConvexHull(many).equations
    assert (coreset[found.vertices] @ planes[:, :3].T + planes[:, 3]).max() <= 1e-12
    # The extreme point along each axis is the extreme of its own column.
    widths = np.ptp(coreset[found.vertices], axis=0) / np.ptp(many, axis=0)
    np.testing.assert_allclose(widths, 1.0, atol=1e-12)
