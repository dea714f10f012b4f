"""
Box fit quality against the slow exhaustive reference on hundreds of varied clouds.

The clouds and the reference are those of ``support/boxfit_reference.py`` (rotated, cropped and
sub-sampled shared scans, ray-cast partial views of the shared meshes, resampled dense range
scans); ``benchmarks/boxfit_quality.py`` runs thousands. Also the properties of the search's
walk and of the coreset's leak check.
"""

from __future__ import annotations

from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from mvbb_ros.geometry.boxfit import enclose, hull, search, turn
from mvbb_ros.geometry.boxfit.fit import fit_part, minimum_bounding_box, ROOT_SEARCH
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from support.boxfit_reference import reference_box, varied_clouds
from support.data import require_shared_data

#: The issue's target: every fit within 1 % of the reference's volume, the node's part fits
#: (``part_search: full``) too; the light part search trades some of it for speed
#: (``fit.PART_SEARCH``: worst 1.01-1.07 x on 3,000 varied clouds, ``docs/performance.md``).
QUALITY_BOUNDS = {'default': 1.01, 'root': 1.01, 'full part': 1.01, 'light part': 1.015}
#: The reference may be beaten only by rounding.
REFERENCE_SLACK = 1e-6

FITS = {
    'default': minimum_bounding_box,
    'root': lambda points: minimum_bounding_box(points, **ROOT_SEARCH),
    'full part': lambda points: fit_part(points, full=True),
    'light part': fit_part,
}


def _check_fits(clouds) -> None:
    """Assert every fit encloses each cloud within the bound of the reference's volume."""
    failures = []
    for cloud in clouds:
        best = reference_box(cloud.points).volume
        for name, function in FITS.items():
            box = function(cloud.points)
            assert box.contains(cloud.points).all(), f'{name} leaks on {cloud.name}'
            ratio = box.volume / best
            assert ratio >= 1.0 - REFERENCE_SLACK, f'{name} beats the reference on {cloud.name}'
            if ratio > QUALITY_BOUNDS[name]:
                failures.append(f'{name} {cloud.name}: {ratio:.4f}')
    assert not failures, failures


def test_fits_are_within_one_percent_of_the_reference_on_varied_clouds():
    """240 scans and views of 150 to 4,000 points (both sides of the part coreset's 1,000)."""
    data = require_shared_data()
    _check_fits(varied_clouds(240, 11, data, kinds=('scan', 'view'), max_points=4000))


def test_fits_are_within_one_percent_of_the_reference_on_dense_range_scans():
    """Resampled bunny scans of 30,000 to 40,000 points: the root fit's coreset."""
    data = require_shared_data()
    _check_fits(varied_clouds(8, 12, data, kinds=('dense',)))


def test_the_reference_finds_a_sampled_boxs_own_volume():
    """Points on the faces of a turned box: its box is the minimum (every face is a facet)."""
    rng = np.random.default_rng(3)
    for seed in range(5):
        extents = rng.uniform(0.2, 2.0, 3)
        local = rng.uniform(-0.5, 0.5, size=(600, 3)) * extents
        face = rng.integers(0, 3, 600)
        local[np.arange(600), face] = np.sign(rng.normal(size=600)) * 0.5 * extents[face]
        rotation = Rotation.random(random_state=seed).as_matrix()
        points = local @ rotation.T
        found = reference_box(points)
        assert found.volume == pytest.approx(np.prod(np.ptp(local, axis=0)), rel=1e-9)


# Properties of the walk and the leak check --------------------------------------------------


def _hull_of(seed: int, count: int):
    points = np.random.default_rng(seed).normal(size=(count, 3)) * [1.0, 0.6, 0.3]
    found = hull.convex_hull(points)
    assume(found.status == hull.FULL_RANK)
    return np.ascontiguousarray(points[found.vertices]), found


#: How closely a walk's volume matches its frame's box (see the assertion).
VOLUME_REL = 1e-8


@settings(max_examples=80, deadline=None)
@example(seed=5, count=5, steps=1, first_step=0.0001, axes=1, pivots=0)  # 3.9e-9 apart
@given(
    seed=st.integers(0, 2**16),
    count=st.integers(5, 300),
    steps=st.integers(0, 6),
    first_step=st.floats(1e-4, 0.3),
    axes=st.integers(1, 3),
    pivots=st.sampled_from([0, 1]),
)
def test_property_the_walk_never_grows_the_box_and_returns_its_frame(
    seed, count, steps, first_step, axes, pivots
):
    vertices, found = _hull_of(seed, count)
    work = turn.new_work(vertices, found.normals, found.edges, found.edge_facets)
    start = Rotation.random(random_state=seed).as_matrix()
    frame = np.empty((3, 3))
    volume = turn.rotate_about(vertices, work, *start[:, 0], frame)
    walked_volume, walked = search.walk(vertices, work, frame, volume, first_step, steps)
    assert walked_volume <= volume
    np.testing.assert_allclose(walked.T @ walked, np.eye(3), atol=1e-12)
    assert np.linalg.det(walked) == pytest.approx(1.0)
    # The volume is that of the hull's box in the returned frame, up to the silhouette's
    # tolerance: a facet within SILHOUETTE_TOLERANCE of parallel to the axis counts as turned
    # away, which may leave a sliver of the outline out of the rectangle's area.
    assert walked_volume == pytest.approx(
        np.prod(np.ptp(vertices @ walked, axis=0)), rel=VOLUME_REL
    )
    settled_volume, settled = search.settle(
        vertices, work, walked, walked_volume, 3, steps, first_step, axes, pivots
    )
    assert settled_volume <= walked_volume
    assert np.linalg.det(settled) == pytest.approx(1.0)
    assert settled_volume == pytest.approx(
        np.prod(np.ptp(vertices @ settled, axis=0)), rel=VOLUME_REL
    )


def _thin(seed: int, count: int, thickness: float) -> np.ndarray:
    """Return a plate of uniform random points, `thickness` thick across 2 x 1.2."""
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (count, 3)) * [1.0, 0.6, thickness]


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    count=st.integers(5, 300),
    thickness=st.floats(0.005, 0.5),
    tilt=st.floats(0.0, 0.2),
)
def test_property_the_pivots_never_grow_the_box_and_return_its_frame(seed, count, thickness, tilt):
    points = _thin(seed, count, thickness)
    found = hull.convex_hull(points)
    assume(found.status == hull.FULL_RANK)
    vertices = np.ascontiguousarray(points[found.vertices])
    work = turn.new_work(vertices, found.normals, found.edges, found.edge_facets)
    # A frame near the plate's, as the walks leave it: its box has faces flush with hull edges.
    start = Rotation.from_rotvec([tilt, 0.5 * tilt, 0.0]).as_matrix()
    frame = np.empty((3, 3))
    volume = turn.rotate_about(vertices, work, *start[:, 2], frame)
    pivoted_volume, pivoted = search.pivot_thinnest(vertices, work, frame, volume)
    assert pivoted_volume <= volume
    np.testing.assert_allclose(pivoted.T @ pivoted, np.eye(3), atol=1e-12)
    assert np.linalg.det(pivoted) == pytest.approx(1.0)
    assert pivoted_volume == pytest.approx(
        np.prod(np.ptp(vertices @ pivoted, axis=0)), rel=VOLUME_REL
    )
    if pivoted_volume == volume:
        np.testing.assert_array_equal(pivoted, frame)


@pytest.mark.slow
def test_the_pivots_find_the_thin_boxes_flush_with_edges_on_opposite_faces():
    """
    Find the boxes of thin plates whose two large faces each hold a hull edge.

    Such a minimal box lies on a ridge of the volume that the walks' tilts do not follow; the
    pivots about the flush edge do (plates of 60 points).
    """
    without, with_pivots = [], []
    for seed in range(200):
        points = _thin(seed, 60, 0.03)
        best = reference_box(points).volume
        plain = minimum_bounding_box(points, edge_pivots=0).volume
        pivoted = minimum_bounding_box(points).volume
        assert pivoted <= plain
        without.append(plain / best)
        with_pivots.append(pivoted / best)
    missed = np.count_nonzero(np.array(without) > 1.003)
    still_missed = np.count_nonzero(np.array(with_pivots) > 1.003)
    assert missed >= 5, 'the plates no longer test the pivots: the search alone finds them'
    assert 4 * still_missed <= missed, (missed, still_missed)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**16), count=st.integers(4, 400), kept=st.integers(1, 50))
def test_property_leaks_are_the_points_outside_the_grown_box(seed, count, kept):
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(count, 3)) * [1.0, 0.5, 0.2]
    subset = np.ascontiguousarray(points[: min(kept, count)])
    frame = Rotation.random(random_state=seed).as_matrix()
    leaked, bounds = enclose._leaks(points, subset, frame)
    local = points @ frame
    # The subset's rows of the same product: products of different shapes may round apart (by
    # the CPU's BLAS kernel), and the box of one point has no margin to absorb that.
    low, high = local[: len(subset)].min(axis=0), local[: len(subset)].max(axis=0)
    margin = enclose.LEAK_TOLERANCE * (high - low)
    outside = ((local < low - margin) | (local > high + margin)).any(axis=1)
    np.testing.assert_array_equal(leaked, np.flatnonzero(outside))
    np.testing.assert_allclose(bounds, [local.min(axis=0), local.max(axis=0)], atol=1e-12)
