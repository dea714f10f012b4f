"""
The compiled crop and voxel grid (Open3D's centroids bit for bit) and filter_points.

``reference_centroids`` is the definition written out in Python (Open3D's anchor, float64
floor of the division, per-voxel sums in input order, voxels sorted by index); it runs
everywhere. The comparisons with Open3D itself skip where Open3D is not installed (the numba
0.59 venv of ``make compat``).
"""

from __future__ import annotations

import time

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mvbb_ros.pipeline.filtering import (
    _radix_order,
    crop_points,
    DENSE_CELLS_PER_POINT,
    filter_points,
    voxel_down_sample,
)
import numpy as np
import pytest
from support.data import lidar_clouds, organized_frame, scan_paths, scene_grid


def reference_centroids(points: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Open3D's voxel centroids by the definition, voxels sorted by index (x slowest)."""
    values = np.asarray(points, dtype=np.float64)
    anchor = values.min(axis=0) - size * 0.5
    sums: dict[tuple, list] = {}
    for point in values:
        key = tuple(int(np.floor((point[axis] - anchor[axis]) / size)) for axis in range(3))
        entry = sums.setdefault(key, [0.0, 0.0, 0.0, 0])
        for axis in range(3):
            entry[axis] += point[axis]
        entry[3] += 1
    voxels = sorted(sums)
    centroids = np.array([[s[0] / s[3], s[1] / s[3], s[2] / s[3]] for s in map(sums.get, voxels)])
    counts = np.array([sums[voxel][3] for voxel in voxels], dtype=np.int64)
    return centroids.reshape(-1, 3), counts


def open3d_centroids(points: np.ndarray, size: float) -> np.ndarray:
    o3d = pytest.importorskip('open3d', reason='compared with Open3D (not in make compat)')
    cloud = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64))
    )
    return np.asarray(cloud.voxel_down_sample(size).points)


def sorted_rows(rows: np.ndarray) -> np.ndarray:
    return rows[np.lexsort(rows.T[::-1])]


def assert_same_as_open3d(points: np.ndarray, size: float) -> np.ndarray:
    centroids, counts = voxel_down_sample(points, size)
    theirs = open3d_centroids(points, size)
    assert counts.sum() == len(points)
    # Bit for bit: the same float64 sums in the same order, the same division.
    np.testing.assert_array_equal(sorted_rows(centroids), sorted_rows(theirs))
    return centroids


def object_points(count: int, seed: int = 0, dtype: type = np.float32) -> np.ndarray:
    """Noisy points on a 10 x 6 x 4 cm box surface about 0.7 m away, as a camera sees it."""
    rng = np.random.default_rng(seed)
    points = rng.uniform(-0.5, 0.5, size=(count, 3)) * (0.10, 0.06, 0.04)
    face = rng.integers(0, 3, size=count)
    points[np.arange(count), face] = (
        np.sign(points[np.arange(count), face]) * (np.array([0.05, 0.03, 0.02])[face])
    )
    points += rng.normal(0.0, 0.0005, size=points.shape) + (0.1, -0.05, 0.7)
    return points.astype(dtype)


@pytest.mark.parametrize('dtype', [np.float32, np.float64])
@pytest.mark.parametrize('voxel_size', [0.002, 0.005, 0.013])
def test_same_centroids_as_open3d(dtype, voxel_size):
    points = object_points(20_000, dtype=dtype)
    centroids = assert_same_as_open3d(points, voxel_size)
    _, counts = voxel_down_sample(points, voxel_size)
    assert (counts >= 1).all()
    assert centroids.dtype == np.float64 and centroids.flags.c_contiguous


@pytest.mark.parametrize('size', [0.002, 0.005, 0.013, 0.05])
def test_every_real_scan_matches_open3d(size):
    for path in scan_paths():
        assert_same_as_open3d(np.load(path), size)


@pytest.mark.parametrize('size', [0.002, 0.005, 0.02])
def test_organized_frame_and_scenes_match_open3d(size):
    grid = organized_frame(300_000)
    points = grid.reshape(-1, 3)
    assert_same_as_open3d(points[np.isfinite(points).all(axis=1)], size)
    for name in ('mosd_learn33.pcd', 'pcl_kinect_laptop_box_frame.pcd'):
        scene = scene_grid(name).reshape(-1, 3)
        assert_same_as_open3d(scene[np.isfinite(scene).all(axis=1)], size)


@pytest.mark.parametrize('size', [0.005, 0.05, 0.5])
def test_lidar_sweeps_match_open3d(size):
    """A sweep spans about 250 m: the hashed grid, with millions of cells per axis at 5 mm."""
    for points in lidar_clouds():
        assert np.ptp(points, axis=0).max() > 100
        assert_same_as_open3d(points, size)


def test_a_wide_sparse_cloud_matches_open3d():
    rng = np.random.default_rng(1)
    points = np.concatenate([object_points(3000), rng.uniform(-30.0, 30.0, size=(500, 3))])
    assert_same_as_open3d(points, 0.005)


def test_centroids_are_sorted_by_voxel_and_deterministic():
    points = object_points(5000)
    first, _ = voxel_down_sample(points, 0.004)
    second, _ = voxel_down_sample(points[::-1].copy(), 0.004)
    keys = np.floor((first - (points.min(axis=0) - 0.002)) / 0.004).astype(np.int64)
    assert (np.diff(keys[:, 0]) >= 0).all()
    np.testing.assert_allclose(first, second, rtol=0, atol=1e-12)


def test_voxels_come_sorted_with_their_counts():
    points = np.random.default_rng(0).normal(scale=0.05, size=(5000, 3)).astype(np.float32)
    centroids, counts = voxel_down_sample(points, 0.01)
    expected, expected_counts = reference_centroids(points, 0.01)
    np.testing.assert_array_equal(centroids, expected)
    np.testing.assert_array_equal(counts, expected_counts)


finite_floats = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False, width=32)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    hnp.arrays(np.float32, st.tuples(st.integers(1, 300), st.just(3)), elements=finite_floats),
    st.sampled_from([1e-3, 0.004, 0.05, 0.37, 1.0, 7.0, 250.0]),
    st.sampled_from([np.float32, np.float64]),
    st.floats(-1e5, 1e5),
)
def test_property_equals_the_definition(points, size, dtype, offset):
    cloud = (points.astype(np.float64) + offset).astype(dtype)
    centroids, counts = voxel_down_sample(cloud, size)
    expected, expected_counts = reference_centroids(cloud, size)
    np.testing.assert_array_equal(centroids, expected)
    np.testing.assert_array_equal(counts, expected_counts)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    hnp.arrays(np.float64, st.tuples(st.integers(1, 200), st.just(3)), elements=finite_floats),
    st.sampled_from([1e-3, 0.05, 1.0]),
)
def test_property_equals_open3d(points, size):
    assert_same_as_open3d(points, size)


def test_points_on_voxel_faces_fall_where_the_division_puts_them():
    """Coordinates on and next to voxel boundaries, where a reciprocal would round differently."""
    size = 0.1
    # The min corner (-2, -2, -2) puts the anchor at -2.05 and the faces at -2.05 + k * 0.1.
    faces = np.arange(0, 40) * size - 1.95
    near = np.concatenate([faces, np.nextafter(faces, np.inf), np.nextafter(faces, -np.inf)])
    points = np.stack(np.meshgrid(near, near[:9], near[:7], indexing='ij'), axis=-1).reshape(-1, 3)
    points = np.vstack([[[-2.0, -2.0, -2.0]], points])
    centroids, counts = voxel_down_sample(points, size)
    expected, expected_counts = reference_centroids(points, size)
    np.testing.assert_array_equal(centroids, expected)
    np.testing.assert_array_equal(counts, expected_counts)


@pytest.mark.parametrize('cells_per_point', [0.1, 0.7, 0.8, 3.0])
def test_dense_and_hashed_lookups_give_the_definition(cells_per_point):
    """Either side of DENSE_CELLS_PER_POINT (grid cells per point), points in random order."""
    assert DENSE_CELLS_PER_POINT == 0.75
    rng = np.random.default_rng(7)
    side, size = 17, 0.01
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing='ij'), -1).reshape(-1, 3)
    count = round(len(grid) / cells_per_point)
    # The two far corners fix the grid's extent; one point at the middle of each occupied voxel
    # (the lowest puts the grid's anchor on the voxels' corners), the rest above it in them.
    occupied = grid[np.r_[0, len(grid) - 1, 1 + rng.permutation(len(grid) - 2)]]
    occupied = occupied[: min(count, len(grid))]
    extra = occupied[rng.integers(0, len(occupied), count - len(occupied))]
    points = np.concatenate([occupied + 0.5, extra + rng.uniform(0.5, 0.9, size=(len(extra), 3))])
    points = points[rng.permutation(len(points))] * size
    centroids, counts = voxel_down_sample(points, size)
    expected, expected_counts = reference_centroids(points, size)
    assert len(centroids) == len(occupied)
    np.testing.assert_array_equal(centroids, expected)
    np.testing.assert_array_equal(counts, expected_counts)


def test_many_voxels_grow_the_table():
    points = np.random.default_rng(1).uniform(-50, 50, size=(60_000, 3))
    centroids, counts = voxel_down_sample(points, 1e-3)  # every point alone: 60k voxels
    assert len(centroids) == len(points) and (counts == 1).all()
    np.testing.assert_array_equal(sorted_rows(centroids), sorted_rows(points))


# --------------------------------------------------------------------------------------------
# Crop, bounds from the decoder, edge cases and limits.


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    hnp.arrays(np.float32, st.tuples(st.integers(1, 200), st.just(3)), elements=finite_floats),
    st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
    st.lists(st.floats(0, 2e3), min_size=3, max_size=3),
)
def test_property_crop_is_voxels_of_the_cropped_points(points, low, span):
    high = [a + b for a, b in zip(low, span, strict=True)]
    inside = crop_points(points, low, high)
    mask = np.all((points >= low) & (points <= high), axis=1)
    np.testing.assert_array_equal(inside, points[mask])
    fused, fused_counts = voxel_down_sample(points, 0.5, crop_min=low, crop_max=high)
    if not len(inside):
        assert fused.shape == (0, 3)
        return
    expected, expected_counts = reference_centroids(inside, 0.5)
    np.testing.assert_array_equal(fused, expected)
    np.testing.assert_array_equal(fused_counts, expected_counts)


def test_bounds_from_the_decoder_skip_the_first_pass_and_are_checked():
    points = np.random.default_rng(2).normal(size=(1000, 3)).astype(np.float32)
    bounds = np.stack([points.min(axis=0), points.max(axis=0)]).astype(np.float64)
    plain = voxel_down_sample(points, 0.1)
    given_bounds = voxel_down_sample(points, 0.1, bounds=bounds)
    np.testing.assert_array_equal(plain[0], given_bounds[0])
    with pytest.raises(ValueError, match='outside the given bounds'):
        voxel_down_sample(points, 0.1, bounds=bounds * 0.5)
    with pytest.raises(ValueError, match='bounds must be finite'):
        voxel_down_sample(points, 0.1, bounds=[[0, 0, 0], [np.inf, 1, 1]])
    spoiled = points.copy()
    spoiled[10, 2] = np.nan  # trusted bounds skip the finite check: still caught, never indexed
    with pytest.raises(ValueError, match='outside the given bounds'):
        voxel_down_sample(spoiled, 0.1, bounds=bounds)


def test_edge_cases():
    empty, counts = voxel_down_sample(np.empty((0, 3), dtype=np.float32), 0.01)
    assert empty.shape == (0, 3) and counts.shape == (0,)
    one, counts = voxel_down_sample([[1.0, 2.0, 3.0]], 0.01)
    np.testing.assert_array_equal(one, [[1.0, 2.0, 3.0]])
    assert counts.tolist() == [1]
    same, counts = voxel_down_sample(np.ones((7, 3)), 0.01)
    np.testing.assert_array_equal(same, [[1.0, 1.0, 1.0]])
    assert counts.tolist() == [7]
    integers, _ = voxel_down_sample(np.arange(12).reshape(4, 3), 100.0)
    np.testing.assert_array_equal(integers, [[4.5, 5.5, 6.5]])
    outside, counts = voxel_down_sample(
        np.ones((3, 3)), 0.1, crop_min=(2, 2, 2), crop_max=(3, 3, 3)
    )
    assert outside.shape == (0, 3)


@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
def test_non_finite_points_are_refused(bad):
    points = np.zeros((10, 3))
    points[6, 1] = bad
    with pytest.raises(ValueError, match='point 6'):
        voxel_down_sample(points, 0.1)


@pytest.mark.parametrize('size', [0.0, -1.0, np.nan, np.inf])
def test_bad_voxel_sizes_are_refused(size):
    with pytest.raises(ValueError, match='voxel_size'):
        voxel_down_sample(np.ones((3, 3)), size)


@pytest.mark.parametrize(
    ('points', 'size'),
    [
        ([[0.0, 0.0, 0.0], [1e38, 1e38, 1e38]], 0.005),
        ([[-3.4e38, 0.0, 0.0], [3.4e38, 0.0, 0.0]], 1e20),
        ([[0.0, 0.0, 0.0], [1e300, 0.0, 0.0]], 1.0),
        ([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], 1e-300),
        ([[0.0, 0.0, 0.0], [2.2e7, 0.0, 0.0]], 0.01),
    ],
)
def test_absurd_extents_are_refused_at_once(points, size):
    start = time.perf_counter()
    with pytest.raises(ValueError, match='too small for a cloud spanning'):
        voxel_down_sample(points, size)
    assert time.perf_counter() - start < 0.5


def test_sparse_huge_extent_below_the_limit_works():
    """Corners 2e7 voxels apart on every axis (Open3D's limit is 2**31): the table stays small."""
    points = np.array([[0.0, 0.0, 0.0], [2e4, 2e4, 2e4], [2e4, 0.0, 1e4], [0.0005, 0.0, 0.0]])
    centroids, counts = voxel_down_sample(points, 1e-3)
    expected, expected_counts = reference_centroids(points, 1e-3)
    np.testing.assert_array_equal(centroids, expected)
    np.testing.assert_array_equal(counts, expected_counts)
    assert_same_as_open3d(points, 1e-3)


# --------------------------------------------------------------------------------------------
# filter_points: the steps together, against Open3D's chain.


def open3d_chain(points: np.ndarray, size: float, k: int, ratio: float) -> np.ndarray:
    o3d = pytest.importorskip('open3d', reason='compared with Open3D (not in make compat)')
    cloud = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64))
    )
    cloud = cloud.voxel_down_sample(size)
    if k:
        cloud, _ = cloud.remove_statistical_outlier(nb_neighbors=k, std_ratio=ratio)
    return np.asarray(cloud.points)


@pytest.mark.parametrize('outlier_neighbors', [0, 20])
def test_filter_points_equals_open3ds_chain(outlier_neighbors):
    rng = np.random.default_rng(2)
    points = np.concatenate([object_points(30_000), rng.uniform(-0.5, 0.5, (40, 3)) + 0.7])
    options = {'voxel_size': 0.005, 'outlier_neighbors': outlier_neighbors}

    ours, counts = filter_points(points, **options)
    theirs = open3d_chain(points, 0.005, outlier_neighbors, 2.0)

    np.testing.assert_array_equal(sorted_rows(ours), sorted_rows(theirs))
    assert counts.finite == counts.cropped == len(points) and counts.inliers == len(ours)
    if outlier_neighbors:
        assert counts.inliers < counts.downsampled


def test_filter_points_with_the_decoders_bounds_gives_the_same_points():
    points = object_points(10_000)
    low, high = (0.06, -1.0, 0.0), (0.2, 1.0, 1.0)
    plain, plain_counts = filter_points(
        points, voxel_size=0.004, outlier_neighbors=10, crop_min=low, crop_max=high
    )
    inside = crop_points(points, low, high)
    bounds = np.stack([inside.min(axis=0), inside.max(axis=0)]).astype(np.float64)
    decoded, decoded_counts = filter_points(
        inside, voxel_size=0.004, outlier_neighbors=10, crop_min=low, crop_max=high,
        bounds=bounds, finite=len(points),
    )  # fmt: skip
    np.testing.assert_array_equal(plain, decoded)
    assert plain_counts == decoded_counts
    assert plain_counts.finite == len(points) and plain_counts.cropped == len(inside)


def test_filter_accepts_float32_and_returns_float64_with_counts():
    points = object_points(2000)
    filtered, counts = filter_points(
        points, crop_min=(0.0, -1.0, 0.0), crop_max=(0.12, 1.0, 1.0), voxel_size=0.0
    )
    inside = points[(points[:, 0] >= 0.0) & (points[:, 0] <= 0.12)]
    assert filtered.dtype == np.float64
    np.testing.assert_array_equal(filtered, inside.astype(np.float64))
    assert counts.finite == 2000 and counts.cropped == len(inside) == counts.inliers


@pytest.mark.parametrize('count_workers', [1, 2, 3])
@pytest.mark.parametrize(
    ('size', 'neighbors', 'crop'),
    [(0.002, 20, False), (0.004, 10, True), (0.05, 20, False), (0.0, 0, True), (0.003, 0, False)],
)
def test_a_background_filter_gives_filter_points_answer(count_workers, size, neighbors, crop):
    """Voxels and outlier queries begun on a helper, the rest taken here: the same points."""
    from mvbb_ros.common.workers import workers
    from mvbb_ros.pipeline.filtering import BackgroundFilter
    from mvbb_ros.pipeline.stage_settings import FilterSettings

    rng = np.random.default_rng(count_workers)
    points = np.concatenate([object_points(40_000), rng.uniform(-0.5, 0.5, (60, 3)) + 0.7])
    options = {'voxel_size': size, 'outlier_neighbors': neighbors}
    if crop:
        options.update(crop_min=(0.02, -1.0, -1.0), crop_max=(0.3, 1.0, 1.0))
    expected, expected_counts = filter_points(points, **options)
    pending = BackgroundFilter(workers(count_workers), points, FilterSettings(**options))
    time.sleep(0.002 * count_workers)  # the helper is at the voxels or the queries, or done
    filtered, counts = pending.result()
    assert filtered.tobytes() == expected.tobytes() and filtered.dtype == np.float64
    assert counts == expected_counts
    assert pending.result()[1] == counts, 'asked again: the same answer'


def test_a_cancelled_background_filter_leaves_its_pool_working():
    from mvbb_ros.common.workers import workers
    from mvbb_ros.pipeline.filtering import BackgroundFilter
    from mvbb_ros.pipeline.stage_settings import FilterSettings

    points = object_points(40_000)
    pool = workers(2)
    settings = FilterSettings(voxel_size=0.002, outlier_neighbors=20)
    for pause in (0.0, 0.001, 0.003, 0.01):
        pending = BackgroundFilter(pool, points, settings)
        time.sleep(pause)
        pending.cancel()
    later = pool.submit(lambda: 42)
    assert later.result() == 42
    expected = filter_points(points, voxel_size=0.002, outlier_neighbors=20)
    again = BackgroundFilter(pool, points, settings).result()
    assert again[0].tobytes() == expected[0].tobytes()


def test_a_background_filter_raises_the_errors_of_filter_points():
    from mvbb_ros.common.workers import workers
    from mvbb_ros.pipeline.filtering import BackgroundFilter
    from mvbb_ros.pipeline.stage_settings import FilterSettings

    pool = workers(2)
    with pytest.raises(ValueError, match='std_ratio must be finite and > 0'):
        BackgroundFilter(
            pool,
            object_points(100),
            FilterSettings(voxel_size=0.01, outlier_neighbors=5, outlier_std_ratio=0.0),
        )
    far = np.array([[0.0, 0.0, 0.0], [1e38, 1e38, 1e38]])
    pending = BackgroundFilter(pool, far, FilterSettings(voxel_size=0.005, outlier_neighbors=5))
    with pytest.raises(ValueError, match='too small for a cloud spanning'):
        pending.result()


def test_outliers_are_skipped_when_no_more_points_than_neighbours_are_left():
    points = object_points(200)
    filtered, counts = filter_points(points, voxel_size=0.05, outlier_neighbors=20)
    assert counts.downsampled <= 20 and counts.inliers == counts.downsampled
    np.testing.assert_array_equal(filtered, voxel_down_sample(points, 0.05)[0])


@settings(max_examples=200, deadline=None)
@given(
    hnp.arrays(
        np.int64,
        st.integers(0, 3000),
        elements=st.one_of(st.integers(0, 40), st.integers(0, 2**62 - 1)),
    )
)
def test_property_radix_order_is_numpys_stable_argsort(keys):
    """The voxel grid's radix sort orders like numpy, ties (stable) and large keys included."""
    np.testing.assert_array_equal(_radix_order(keys), np.argsort(keys, kind='stable'))
