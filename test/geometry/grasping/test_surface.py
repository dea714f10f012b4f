"""
The refinement's compiled kernels (surface normals, the pad gripper), without ROS or Open3D.

`make compat` runs this file on numba 0.59 too; the refinement as a whole is tested in
test_refine.py.
"""

import math

from hypothesis import assume, given, settings
from hypothesis import strategies as st
from mvbb_ros.geometry.grasping import surface
from mvbb_ros.geometry.grasping.contacts import (
    _evaluate,
    _parameters,
    _place_hand,
    COL_CONTACT_WIDTH,
    COL_VALID,
    COL_WIDTH,
    evaluate_lines,
    HAND_BEYOND_REACH,
    P_REACH_SLACK,
    REACH_SLACK,
)
from mvbb_ros.geometry.grasping.refinement_settings import GraspView, RefinementSettings
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.shapes import l_shape_points

ON = RefinementSettings(enabled=True)


def _wavy_sheet(count: int, seed: int) -> np.ndarray:
    """Return points on a gently curved sheet, 10 cm across (metres)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 0.1, size=(count, 2))
    z = 0.01 * np.sin(40.0 * xy[:, 0]) * np.cos(30.0 * xy[:, 1])
    return np.column_stack([xy, z])


def _brute_force_normals(points: np.ndarray, radius: float) -> np.ndarray:
    """Return surface._pca_normals' answer with every distance computed and numpy's eigh."""
    normals = np.zeros_like(points)
    distances = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    for i in range(len(points)):
        for reach in (1, 2, surface.MAX_REACH):
            near = points[distances[i] <= reach * radius]
            if len(near) >= surface.MIN_NEIGHBOURS:
                break
        if len(near) < 4:
            continue
        offsets = near - points[i]
        covariance = offsets.T @ offsets / len(near) - np.outer(offsets.mean(0), offsets.mean(0))
        values, vectors = np.linalg.eigh(covariance)
        if values[0] > surface.EDGE_VARIATION * values.sum():
            continue
        normals[i] = vectors[:, 0]
    return normals


@settings(max_examples=10, deadline=None)
@given(st.integers(20, 400), st.integers(0, 2**31 - 1), st.floats(0.004, 0.03))
def test_normals_are_the_pca_of_every_neighbour_within_the_radius(count, seed, radius):
    """The cell lookup (views/cells.py) finds exactly the neighbours a full search finds."""
    points = _wavy_sheet(count, seed)
    mine = surface._pca_normals(points, radius)
    theirs = _brute_force_normals(points, radius)
    found = np.linalg.norm(theirs, axis=1) > 0.0
    assert np.array_equal(np.linalg.norm(mine, axis=1) > 0.0, found)
    agreement = np.abs(np.einsum('ij,ij->i', mine[found], theirs[found]))
    assert np.all(agreement > 1.0 - 1e-6)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 60), max_size=80), st.integers(0, 20))
def test_key_starts_are_the_binary_searches_they_replace(keys, extra):
    """Each key's listed first place is cell_start's (and the places past the last key)."""
    from mvbb_ros.geometry.views.cells import cell_start

    sorted_keys = np.sort(np.array(keys, dtype=np.int64))
    cells = (max(keys) + 1 if keys else 0) + extra
    starts = surface._key_starts(sorted_keys, cells)
    assert starts.tolist() == [cell_start(sorted_keys, key) for key in range(cells + 1)]


@settings(max_examples=10, deadline=None)
@given(st.integers(1, 300), st.integers(0, 2**31 - 1), st.floats(0.004, 0.03))
def test_moments_with_listed_cells_are_the_searched_ones_bit_for_bit(count, seed, radius):
    """The cells' listed first places give the same sums as the binary search, every reach."""
    from mvbb_ros.geometry.views.cells import cell_grid

    points = _wavy_sheet(count, seed)
    cells, span, order, sorted_keys = cell_grid(points, radius, surface.MAX_REACH)
    ordered = np.ascontiguousarray(points[order])
    starts = surface._key_starts(sorted_keys, int(np.prod(span)))
    none = np.zeros(0, dtype=np.int64)
    for i in range(count):
        for reach in (1, 2, surface.MAX_REACH):
            args = (points, cells, span, ordered, sorted_keys)
            listed = surface._moments(*args, starts, i, reach, reach * radius)
            searched = surface._moments(*args, none, i, reach, reach * radius)
            assert np.array(listed).tobytes() == np.array(searched).tobytes()


def _surface_cells_by_ndimage(points: np.ndarray, cell: float, seen: int):
    """Return surface._surface_cells' answer with scipy.ndimage's closing and erosion."""
    from scipy import ndimage

    low = points.min(axis=0) - 2 * cell
    index = np.floor((points - low) / cell).astype(np.int64)
    shape = tuple(int(v) for v in index.max(axis=0) + 3)
    occupied = np.zeros(shape, dtype=bool)
    occupied[tuple(index.T)] = True
    solid = ndimage.binary_closing(occupied) | occupied
    keep = (occupied & ~ndimage.binary_erosion(solid))[tuple(index.T)]
    cells, inverse = np.unique(
        np.ravel_multi_index(tuple(index[keep].T), shape), return_inverse=True
    )
    counts = np.bincount(inverse).astype(float)
    centroids = (
        np.column_stack([np.bincount(inverse, weights=points[keep, k]) for k in range(3)])
        / counts[:, None]
    )
    observed = np.bincount(inverse, weights=(np.flatnonzero(keep) < seen).astype(float))
    return centroids, np.where(observed > 0.0, 1.0, surface.ESTIMATED_WEIGHT)


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 600), st.integers(0, 2**31 - 1), st.floats(0.002, 0.02), st.floats(0, 1))
def test_surface_cells_are_the_closed_grids_boundary(count, seed, cell, seen_share):
    """The compiled grid gives the cells and centroids of scipy's closing and erosion, exactly."""
    rng = np.random.default_rng(seed)
    # A solid block with a hole and scattered points: inner cells, closed gaps and lone cells.
    block = rng.uniform(0.0, 0.05, size=(count, 3))
    block = block[np.linalg.norm(block - 0.025, axis=1) > 0.01]
    points = np.ascontiguousarray(np.vstack([block, rng.uniform(-0.02, 0.08, size=(5, 3))]))
    seen = int(seen_share * len(points))
    low = points.min(axis=0) - 2 * cell
    centroids, weights = surface._surface_cells(points, low, cell, seen, 2)
    expected_centroids, expected_weights = _surface_cells_by_ndimage(points, cell, seen)
    assert np.array_equal(centroids, expected_centroids)
    assert np.array_equal(weights, expected_weights)


def test_normals_of_a_sphere_point_away_from_its_centre():
    rng = np.random.default_rng(1)
    directions = rng.normal(size=(3000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    model = surface.surface_model(0.05 * directions, cell=0.004)
    radial = model.points / np.linalg.norm(model.points, axis=1, keepdims=True)
    assert np.median(np.abs(np.einsum('ij,ij->i', model.normals, radial))) > 0.99


@settings(max_examples=10, deadline=None)
@given(st.floats(0.02, 0.1), st.integers(0, 2**31 - 1))
def test_a_corner_has_no_normal_and_a_curved_face_keeps_its_own(radius, seed):
    """A blend of the faces' normals at a corner would make a pinch there look antipodal."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    sphere = surface.surface_model(radius * directions, cell=0.005)
    assert np.all(np.linalg.norm(sphere.normals, axis=1) > 0.0), 'a sphere has no corner'
    # Three faces of a cube meeting at the origin, sampled every millimetre up to 2 cm out.
    side = np.linspace(0.0, 0.02, 21)
    u, v = (a.ravel() for a in np.meshgrid(side, side))
    zero = np.zeros_like(u)
    faces = [np.column_stack(c) for c in ((zero, u, v), (u, zero, v), (u, v, zero))]
    points = np.unique(np.concatenate(faces), axis=0)
    normals = surface._pca_normals(points, 0.005)
    apex = np.flatnonzero(np.all(points == 0.0, axis=1))
    assert not np.any(normals[apex]), 'no normal where three faces meet'
    middle = np.flatnonzero(np.all(np.isclose(points, [0.0, 0.015, 0.015]), axis=1))
    assert abs(normals[middle[0], 0]) == pytest.approx(1.0), 'a face keeps its normal'


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_sensor_noise_on_a_plane_is_not_an_edge(seed):
    """1.5 mm of noise at a 5 mm radius varies like an edge there, not twice as wide."""
    rng = np.random.default_rng(seed)
    plane = np.column_stack([rng.uniform(-0.04, 0.04, (4000, 2)), rng.normal(0, 0.0015, 4000)])
    normals = surface._pca_normals(plane, 0.005)
    kept = np.linalg.norm(normals, axis=1) > 0.0
    assert kept.mean() >= 0.95, f'{kept.mean():.0%} of a noisy plane keeps its normals'


def test_a_box_closed_across_its_faces_holds_with_its_width():
    half = np.array([0.03, 0.02, 0.025])
    axes = [np.linspace(-h, h, int(2 * h / 0.004) + 1) for h in half]
    grid = np.stack(np.meshgrid(*axes, indexing='ij'), -1).reshape(-1, 3)
    model = surface.surface_model(grid, cell=0.004, up=(0.0, 0.0, 1.0))
    view = GraspView(gripper_max_width=0.1, standoff=0.05, up=np.array([0.0, 0.0, 1.0]))
    rows = evaluate_lines(
        model,
        np.zeros((2, 3)),
        np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]]),
        np.array([[1.0, 0.0, 0.0], [math.cos(0.1), math.sin(0.1), 0.0]]),
        ON,
        view,
    )
    assert np.all(rows[:, COL_VALID] == 1.0)
    assert abs(rows[0, COL_CONTACT_WIDTH] - 2.0 * half[0]) <= 0.004
    assert abs(rows[0, COL_WIDTH] - 2.0 * half[0]) <= 0.004


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0.0, 0.2), st.floats(-0.15, 0.15)), min_size=1, max_size=60),
    st.floats(0.005, 0.03),
    st.floats(0.0, 0.03),
)
def test_the_hand_placed_on_the_points_within_reach_is_the_one_placed_on_the_whole_band(
    band, depth, slack
):
    """Placed on the band's points up to `reach`, the hand is the whole band's, or says so."""
    half, pad = 0.04, 0.02
    along = np.array([u for u, _ in band])
    across = np.array([v for _, v in band])
    centred = along[np.abs(across) <= half]
    assume(len(centred))
    first_centred = float(centred.min())
    reach = first_centred + depth + slack
    near = along <= reach
    whole = _place_hand(along, across, len(along), first_centred, depth, half, pad, math.inf)
    placed = _place_hand(
        along[near], across[near], int(near.sum()), first_centred, depth, half, pad, reach
    )
    if placed[0] == HAND_BEYOND_REACH:
        return  # the kernel then places the hand on the whole band
    assert placed == whole


def _l_shape_lines(seed: int, up: bool):
    """Return an L's surface model and 200 lines along its box axes, tilted a little."""
    rng = np.random.default_rng(seed)
    rotation = Rotation.random(random_state=seed).as_matrix()
    points = l_shape_points(seed, count=3000) @ rotation.T
    model = surface.surface_model(points, cell=0.005, up=(0.0, 0.0, 1.0) if up else None)
    # Many such lines hold, some do not.
    axis = rng.integers(0, 3, 200)
    approaches = rotation[:, axis].T * rng.choice([-1.0, 1.0], (200, 1))
    closings = rotation[:, (axis + rng.integers(1, 3, 200)) % 3].T
    tilt = Rotation.from_rotvec(rng.normal(scale=0.15, size=(200, 3)))
    approaches, closings = tilt.apply(approaches), tilt.apply(closings)
    origins = points[rng.integers(0, len(points), 200)] - 0.1 * approaches
    return model, origins, approaches, closings


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 0.03), st.booleans())
def test_the_hand_placed_on_the_band_near_the_first_contact_is_the_one_on_the_whole_band(
    seed, opening_slack, up
):
    """The kernel searches the band near the first contact; the result is the whole band's."""
    model, origins, approaches, closings = _l_shape_lines(seed, up)
    view = GraspView(
        gripper_max_width=0.06 + opening_slack,
        standoff=0.05,
        up=np.array([0.0, 0.0, 1.0]) if up else None,
    )
    up_vector = np.zeros(3) if view.up is None else view.up
    depths = ON.finger_depth * np.array(ON.depth_fractions)
    rows = []
    for slack in (0.0, REACH_SLACK * ON.pad_size, math.inf):
        params = _parameters(ON, view, model.cell, model.floor)
        params[P_REACH_SLACK] = slack
        rows.append(
            _evaluate(
                model.points,
                model.normals,
                model.weights,
                origins,
                approaches,
                closings,
                depths,
                params,
                up_vector,
            )
        )
    assert rows[1][:, COL_VALID].any(), 'some lines hold'
    np.testing.assert_array_equal(rows[0], rows[2])
    np.testing.assert_array_equal(rows[1], rows[2])
    np.testing.assert_array_equal(
        rows[1], evaluate_lines(model, origins, approaches, closings, ON, view)
    )


@settings(max_examples=15, deadline=None)
@given(
    st.integers(0, 2**31 - 1),
    st.booleans(),
    st.booleans(),
    st.sampled_from(['', 'lenient', 'held']),
)
def test_lines_asked_only_whether_they_hold_say_what_the_whole_evaluation_says(
    seed, up, hand, mode
):
    """valid_only stops a line at its first depth that holds: the same COL_VALID as without."""
    from mvbb_ros.pipeline.settings import PipelineSettings

    model, origins, approaches, closings = _l_shape_lines(seed, up)
    view = GraspView(
        gripper_max_width=0.08, standoff=0.05, up=np.array([0.0, 0.0, 1.0]) if up else None
    )
    refinement = PipelineSettings().refinement if hand else ON
    options = {'lenient': mode == 'lenient', 'held': mode == 'held'}
    lines = (model, origins, approaches, closings, refinement, view)
    whole = evaluate_lines(*lines, **options)
    asked = evaluate_lines(*lines, valid_only=True, **options)
    assert np.array_equal(asked[:, COL_VALID], whole[:, COL_VALID])
    assert whole[:, COL_VALID].any(), 'some lines hold'


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), outliers=st.integers(1, 5), depth=st.floats(0.005, 0.05))
def test_the_floor_is_the_observed_base_whatever_a_few_noisy_points_below_it(
    seed, outliers, depth
):
    """A few points below an object's base (sensor noise) leave its floor at the base."""
    rng = np.random.default_rng(seed)
    # A 6 x 6 x 3 cm box's observed surface (top and two sides), its base at z = 0.
    top = np.column_stack([rng.uniform(0, 0.06, (900, 2)), np.full(900, 0.03)])
    side = np.column_stack([rng.uniform(0, 0.06, 600), np.zeros(600), rng.uniform(0, 0.03, 600)])
    front = side[:, [1, 0, 2]]
    low = np.column_stack([rng.uniform(0, 0.06, (outliers, 2)), np.full(outliers, -depth)])
    observed = np.concatenate([top, side, front, low])
    hidden = observed[:300] - [0.0, 0.0, 0.1]  # estimated points never lower the floor
    model = surface.surface_model(
        np.concatenate([observed, hidden]), observed=len(observed), cell=0.005, up=(0, 0, 1)
    )
    assert 0.0 <= model.floor <= 0.002
    table = surface.surface_model(observed, cell=0.005, up=(0, 0, 1), support_floor=-0.004)
    assert table.floor == -0.004
    assert surface.surface_model(observed, cell=0.005).floor == -math.inf
