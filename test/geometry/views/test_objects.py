"""Objects in one cloud (geometry.objects): Euclidean clusters, occluded pieces joined."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mvbb_ros.geometry.views.objects import _cluster_labels, separate_objects
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

SPACING = 0.005


def slab(low, high, spacing: float = SPACING) -> np.ndarray:
    """Return a grid of points on the front face (smallest z) of an axis-aligned box."""
    x = np.arange(low[0], high[0] + 1e-9, spacing)
    y = np.arange(low[1], high[1] + 1e-9, spacing)
    grid = np.stack(np.meshgrid(x, y), axis=-1).reshape(-1, 2)
    return np.column_stack([grid, np.full(len(grid), low[2])])


def test_side_by_side_objects_are_separated_largest_first():
    big = slab((-0.15, -0.05, 0.8), (-0.03, 0.05, 0.9))
    small = slab((0.03, -0.04, 0.8), (0.10, 0.04, 0.9))
    points = np.concatenate([small, big])
    objects = separate_objects(points, 0.02, spacing=SPACING)
    assert [len(o) for o in objects] == [len(big), len(small)]
    np.testing.assert_array_equal(objects[1], np.arange(len(small)))


def test_pieces_of_one_object_that_touch_in_the_view_stay_one_object():
    """A bowl's front rim and its inner back wall: 4 cm apart, one continuing the other."""
    front = slab((-0.10, 0.00, 0.90), (0.10, 0.04, 1.0))
    # The back wall starts where the front rim ends in the image (y / z continues), 4 cm
    # deeper: more than the 2 cm tolerance, less than 2.5 tolerances.
    back = slab((-0.10, -0.05, 0.94), (0.10, -0.005, 1.0))
    objects = separate_objects(np.concatenate([front, back]), 0.02, spacing=SPACING)
    assert [len(o) for o in objects] == [len(front) + len(back)]
    # The same pieces side by side with background between them in the view: two objects.
    apart = np.concatenate([front, back + [0.0, -0.04, 0.0]])
    assert len(separate_objects(apart, 0.02, spacing=SPACING)) == 2


def test_no_tolerance_keeps_one_object_and_noise_is_left_out():
    points = np.concatenate([slab((0, 0, 1), (0.1, 0.1, 1.1)), [[5.0, 5.0, 5.0]]])
    assert [len(o) for o in separate_objects(points, 0.0, spacing=SPACING)] == [len(points)]
    objects = separate_objects(points, 0.02, spacing=SPACING, min_points=10)
    assert [len(o) for o in objects] == [len(points) - 1]
    assert separate_objects(points[:3], 0.0, spacing=SPACING, min_points=10) == []


@settings(max_examples=60, deadline=None)
@given(
    points=arrays(
        np.float64, st.tuples(st.integers(1, 120), st.just(3)), elements=st.floats(-1, 1)
    ),
    tolerance=st.floats(0.01, 0.5),
)
def test_property_cluster_labels_are_the_connected_components(points, tolerance):
    labels = _cluster_labels(points, tolerance)
    pairs = cKDTree(points).query_pairs(tolerance, output_type='ndarray')
    graph = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points))
    )
    count, reference = connected_components(graph, directed=False)
    assert labels.max() + 1 == count
    # The same partition: each of our labels maps to exactly one reference label and back.
    assert len(set(zip(labels.tolist(), reference.tolist(), strict=True))) == count
    # Labels are numbered by first point.
    first = [int(np.flatnonzero(labels == label)[0]) for label in range(count)]
    assert first == sorted(first)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(2, 400),
    spread=st.floats(0.001, 0.3),
    tolerance=st.floats(0.002, 0.05),
)
def test_property_clusters_are_the_components_of_the_pairs_within_the_tolerance(
    seed, count, spread, tolerance
):
    """Dense cells join without a test, sparse ones pair by pair: the same clusters."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-spread, spread, size=(4, 3))
    points = centres[rng.integers(0, 4, count)] + rng.normal(scale=spread / 10, size=(count, 3))
    pairs = cKDTree(points).query_pairs(tolerance, output_type='ndarray')
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(count, count))
    _, components = connected_components(graph, directed=False)
    labels = _cluster_labels(np.ascontiguousarray(points), tolerance)
    # Same partition, labels numbered by first point.
    _, first = np.unique(components, return_index=True)
    names = np.empty(components.max() + 1, dtype=np.int64)
    names[components[np.sort(first)]] = np.arange(len(first))
    np.testing.assert_array_equal(labels, names[components])
