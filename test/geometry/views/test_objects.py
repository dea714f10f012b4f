"""Objects in one cloud (geometry.objects): Euclidean clusters, occluded pieces joined."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mvbb_ros.geometry.views.objects import (
    _cluster_labels,
    _members,
    own_footprints,
    separate_objects,
)
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from support.data import scene_grid

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


#: The table of the footprint tests: y = 0.1 in a camera's optical frame (y down), up is -y.
TABLE = np.array([0.0, -1.0, 0.0, 0.1])
#: The scene stage drops what lies within 1 cm of the table (the node's support_distance).
CLEARANCE = 0.01


def standing_box(x0, x1, z0, z1, height=0.1) -> np.ndarray:
    """Return a box's front face and top seen from the camera, standing on :data:`TABLE`."""
    front = slab((x0, 0.1 - height, z0), (x1, 0.1, z0))
    x = np.arange(x0, x1 + 1e-9, SPACING)
    z = np.arange(z0, z1 + 1e-9, SPACING)
    top = np.stack(np.meshgrid(x, z), axis=-1).reshape(-1, 2)
    return np.concatenate(
        [front, np.column_stack([top[:, 0], np.full(len(top), 0.1 - height), top[:, 1]])]
    )


def test_pieces_resting_side_by_side_on_the_support_are_two_objects():
    """Two boxes on a table, 3 cm apart, one partly behind the other: touching in the view."""
    first = standing_box(-0.15, -0.03, 0.80, 0.90)
    second = standing_box(-0.03, 0.10, 0.93, 1.03)
    points = np.concatenate([first, second])
    # Without the table they are pieces of one object (within 2.5 tolerances, touching).
    assert len(separate_objects(points, 0.02, spacing=SPACING)) == 1
    objects = separate_objects(
        points, 0.02, spacing=SPACING, support=2.0 * TABLE, clearance=CLEARANCE
    )
    assert sorted(len(o) for o in objects) == sorted([len(first), len(second)])


def test_pieces_that_do_not_each_rest_on_the_support_stay_one_object():
    # A bowl's front rim resting on the table and its inner back wall above it (the bowl test
    # above, put on a table): the back piece does not reach down to the table.
    front = slab((-0.10, 0.06, 0.90), (0.10, 0.10, 1.0))
    back = slab((-0.10, 0.01, 0.94), (0.10, 0.055, 1.0))
    points = np.concatenate([front, back])
    assert (
        len(separate_objects(points, 0.02, spacing=SPACING, support=TABLE, clearance=CLEARANCE))
        == 1
    )


def test_own_footprints_needs_two_resting_pieces_with_disjoint_footprints():
    box = standing_box(-0.15, -0.03, 0.80, 0.90)
    beside = standing_box(0.0, 0.10, 0.80, 0.90)
    assert own_footprints(box, beside, TABLE, 25, CLEARANCE)
    # A piece resting across the other's footprint is not apart: a wall along the depth
    # (x = -0.09, z from 0.78 to 0.84) crossing the box's front edge on the table.
    wall = slab((-0.09, 0.05, 0.78), (-0.09, 0.1, 0.78))
    crossing = np.concatenate([wall + [0.0, 0.0, dz] for dz in np.arange(0.0, 0.06, SPACING)])
    assert not own_footprints(box, crossing, TABLE, 25, CLEARANCE)
    assert own_footprints(box, crossing + [0.2, 0.0, 0.0], TABLE, 25, CLEARANCE)
    # A piece above the table (a handle) does not rest on it.
    assert not own_footprints(box, beside + [0.0, -0.05, 0.0], TABLE, 25, CLEARANCE)
    # Too few contact points: not resting.
    assert not own_footprints(box, beside, TABLE, 100_000, CLEARANCE)
    # The contact band starts where the table's points were dropped: lifted by 3 cm, the
    # boxes rest on a table whose points went up to 3 cm above the plane.
    lifted = [box + [0.0, -0.03, 0.0], beside + [0.0, -0.03, 0.0]]
    assert not own_footprints(*lifted, TABLE, 25, CLEARANCE)
    assert own_footprints(*lifted, TABLE, 25, 0.03)


@settings(max_examples=60, deadline=None)
@given(labels=arrays(np.int64, st.integers(0, 300), elements=st.integers(0, 12)))
def test_property_members_are_each_labels_sorted_indices(labels):
    """One stable sort gives what one pass per label gave (empty labels left out)."""
    expected = [np.flatnonzero(labels == label) for label in np.unique(labels)]
    found = _members(labels) if len(labels) else []
    assert len(found) == len(expected)
    for mine, theirs in zip(found, expected, strict=True):
        np.testing.assert_array_equal(mine, theirs)


def test_objects_of_a_real_scene_are_unions_of_the_components_within_the_tolerance():
    """
    A shared scene, voxelised, cut at a tolerance that leaves hundreds of clusters.

    Every point is in one group; each connected component of the pairs within the tolerance
    (scipy's reference) lies in one group; groups come largest first.
    """
    grid = scene_grid('pcl_kinect_laptop_box_frame.pcd').reshape(-1, 3).astype(np.float64)
    points = grid[np.isfinite(grid).all(axis=1)]
    # A 5 mm voxel grid's first point per voxel, in cloud order (the voxel filter's spacing).
    _, first = np.unique(np.floor(points / 0.005).astype(np.int64), axis=0, return_index=True)
    points = points[np.sort(first)]
    tolerance = 0.0075
    pairs = cKDTree(points).query_pairs(tolerance, output_type='ndarray')
    graph = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points))
    )
    count, components = connected_components(graph, directed=False)
    assert count > 100  # the case of many small clusters
    groups = separate_objects(points, tolerance, spacing=0.005)
    group_of = np.full(len(points), -1)
    for number, group in enumerate(groups):
        assert np.all(group_of[group] == -1)
        group_of[group] = number
    assert np.all(group_of >= 0)
    assert len(set(zip(components.tolist(), group_of.tolist(), strict=True))) == count
    assert len(groups) < count  # occluded pieces were joined
    sizes = [len(group) for group in groups]
    assert sizes == sorted(sizes, reverse=True)
