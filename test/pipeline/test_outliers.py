"""
The compiled statistical outlier removal: Open3D's kept indices, and a brute-force definition.

``reference_kept`` writes out what Open3D computes (see the module docstring of
:mod:`mvbb_ros.pipeline.outliers`) with a full distance matrix; it runs everywhere. The
comparisons with Open3D itself skip where Open3D is not installed (``make compat``).
"""

from __future__ import annotations

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from mvbb_ros.pipeline.filtering import voxel_down_sample
from mvbb_ros.pipeline.outliers import mean_neighbor_distances, remove_statistical_outliers
import numpy as np
import pytest
from support.data import lidar_clouds, organized_frame, scan_paths, scene_grid


def reference_means(points: np.ndarray, k: int) -> np.ndarray:
    """Mean distance to the min(k, N) nearest points, the point itself included (sorted sum)."""
    values = np.asarray(points, dtype=np.float64)
    difference = values[:, None, :] - values[None, :, :]
    squared = (difference[..., 0] ** 2 + difference[..., 1] ** 2) + difference[..., 2] ** 2
    nearest = np.sort(squared, axis=1)[:, : min(k, len(values))]
    means = np.empty(len(values))
    for i, row in enumerate(nearest):
        total = 0.0
        for value in row:  # nearest first, one addition at a time
            total += np.sqrt(value)
        means[i] = total / len(row)
    return means


def reference_kept(points: np.ndarray, k: int, ratio: float) -> np.ndarray:
    means = reference_means(points, k)
    if len(means) < 2:
        return np.empty(0, dtype=np.intp)
    positive = means > 0
    mean = means[positive].sum() / len(means)
    spread = np.sqrt(((means[positive] - mean) ** 2).sum() / (len(means) - 1))
    return np.flatnonzero(positive & (means < mean + ratio * spread))


def open3d_kept(points: np.ndarray, k: int, ratio: float) -> np.ndarray:
    o3d = pytest.importorskip('open3d', reason='compared with Open3D (not in make compat)')
    cloud = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64))
    )
    return np.asarray(cloud.remove_statistical_outlier(int(k), float(ratio))[1], dtype=np.intp)


SETTINGS = [(20, 2.0), (8, 1.0), (50, 0.5), (3, 3.0)]


def assert_same_as_open3d(points: np.ndarray) -> None:
    for k, ratio in SETTINGS:
        ours = remove_statistical_outliers(points, k, ratio)
        np.testing.assert_array_equal(ours, open3d_kept(points, k, ratio), err_msg=f'{k} {ratio}')


@pytest.mark.slow
def test_real_scans_match_open3d():
    for path in scan_paths():
        for size in (0.005, 0.002):
            centroids, _ = voxel_down_sample(np.load(path), size)
            assert_same_as_open3d(centroids)


def test_raw_scans_match_open3d():
    """Not only voxel centroids: raw sensor points, with their duplicates and quantisation."""
    for path in scan_paths()[::4]:
        points = np.load(path)
        ours = remove_statistical_outliers(points, 20, 2.0)
        np.testing.assert_array_equal(ours, open3d_kept(points, 20, 2.0))


@pytest.mark.slow
def test_organized_frame_scenes_and_lidar_match_open3d():
    grid = organized_frame(300_000).reshape(-1, 3)
    clouds = [grid[np.isfinite(grid).all(axis=1)]]
    for name in ('mosd_learn33.pcd', 'pcl_table_scene_mug_stereo_textured.pcd'):
        scene = scene_grid(name).reshape(-1, 3)
        clouds.append(scene[np.isfinite(scene).all(axis=1)])
    for points in clouds:
        centroids, _ = voxel_down_sample(points, 0.005)
        assert_same_as_open3d(centroids)
    for points in lidar_clouds()[:2]:
        for size in (0.005, 0.1):  # near and far field differ by orders of magnitude
            centroids, _ = voxel_down_sample(points, size)
            np.testing.assert_array_equal(
                remove_statistical_outliers(centroids, 20, 2.0), open3d_kept(centroids, 20, 2.0)
            )


coordinates = st.floats(-10, 10, allow_nan=False, allow_infinity=False, width=32)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    hnp.arrays(np.float64, st.tuples(st.integers(0, 120), st.just(3)), elements=coordinates),
    st.integers(1, 30),
    st.floats(0.1, 4.0),
)
def test_property_equals_the_definition(points, k, ratio):
    np.testing.assert_array_equal(
        remove_statistical_outliers(points, k, ratio), reference_kept(points, k, ratio)
    )
    if len(points):
        np.testing.assert_array_equal(
            mean_neighbor_distances(points, k), reference_means(points, k)
        )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    clusters=st.integers(1, 6),
    k=st.integers(1, 40),
)
def test_property_leaves_sharing_candidates_equal_the_definition(seed, clusters, k):
    """
    Many leaves, in clusters whose spacing differs by up to a thousand times.

    A leaf's reach comes from the leaf before it: after a sparse cluster it holds far more
    candidates than needed, after a dense one too few, and the points that find fewer than k
    within it ask the tree. Duplicates put ties at the k-th distance.
    """
    rng = np.random.default_rng(seed)
    parts = []
    for _ in range(clusters):
        count = int(rng.integers(1, 160))
        scale = 10.0 ** rng.uniform(-3.0, 0.0)
        parts.append(rng.normal(0.0, scale, (count, 3)) + rng.uniform(-5.0, 5.0, 3))
    points = np.concatenate(parts)
    points[rng.integers(0, len(points), len(points) // 8)] = points[0]
    np.testing.assert_array_equal(mean_neighbor_distances(points, k), reference_means(points, k))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    hnp.arrays(
        np.float64,
        st.tuples(st.integers(0, 80), st.just(3)),
        elements=st.sampled_from([0.0, 1.0, 2.0, 0.5, -1.0]),  # a lattice: ties everywhere
    ),
    st.integers(1, 12),
    st.floats(0.1, 3.0),
)
def test_property_ties_and_duplicates_equal_open3d(points, k, ratio):
    pytest.importorskip('open3d', reason='compared with Open3D (not in make compat)')
    np.testing.assert_array_equal(
        remove_statistical_outliers(points, k, ratio), open3d_kept(points, k, ratio)
    )


def test_open3d_conventions():
    line = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0], [7, 0, 0], [15, 0, 0]], dtype=float)
    # The point counts itself: with k = 2 the mean is half the distance to the nearest other.
    np.testing.assert_array_equal(mean_neighbor_distances(line, 2), [0.5, 0.5, 1.0, 2.0, 4.0])
    # Strictly below the threshold: two points have the same mean, equal to the threshold.
    assert remove_statistical_outliers([[0, 0, 0], [1, 0, 0]], 20, 2.0).size == 0
    # One point, no point: nothing kept; k = 1: every mean is 0, nothing kept.
    assert remove_statistical_outliers([[1, 2, 3]], 20, 2.0).size == 0
    assert remove_statistical_outliers(np.empty((0, 3)), 20, 2.0).size == 0
    assert remove_statistical_outliers(line, 1, 2.0).size == 0
    # k copies of a point: mean 0, removed (and left out of the statistics but not the count).
    copies = np.vstack([np.zeros((3, 3)), np.random.default_rng(0).normal(size=(40, 3))])
    kept = remove_statistical_outliers(copies, 3, 2.0)
    assert not set(kept.tolist()) & {0, 1, 2}
    np.testing.assert_array_equal(kept, reference_kept(copies, 3, 2.0))


@pytest.mark.parametrize(
    ('k', 'ratio', 'message'),
    [(0, 2.0, 'nb_neighbors'), (-3, 2.0, 'nb_neighbors'), (5, 0.0, 'std_ratio'),
     (5, -1.0, 'std_ratio'), (5, np.nan, 'std_ratio')],
)  # fmt: skip
def test_bad_settings_are_refused(k, ratio, message):
    with pytest.raises(ValueError, match=message):
        remove_statistical_outliers(np.ones((5, 3)), k, ratio)


def test_non_finite_points_are_refused():
    points = np.zeros((5, 3))
    points[2, 0] = np.nan
    with pytest.raises(ValueError, match='finite'):
        remove_statistical_outliers(points, 3, 2.0)


def test_float32_input_is_the_same_as_float64():
    points = np.random.default_rng(4).normal(size=(2000, 3)).astype(np.float32)
    np.testing.assert_array_equal(
        remove_statistical_outliers(points, 20, 2.0),
        remove_statistical_outliers(points.astype(np.float64), 20, 2.0),
    )


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(1, 6000),
    neighbors=st.integers(1, 40),
    duplicates=st.booleans(),
)
def test_the_queries_split_over_workers_give_the_same_distances(
    seed, count, neighbors, duplicates
):
    from mvbb_ros.common.workers import workers

    rng = np.random.default_rng(seed)
    points = rng.normal(0.0, 1.0, (count, 3)) * rng.uniform(0.01, 3.0, 3)
    if duplicates:
        points[rng.integers(0, count, count // 3)] = points[0]  # ties in the k-th distance
    alone = mean_neighbor_distances(points, neighbors)
    for count_workers in (2, 3):
        split = mean_neighbor_distances(points, neighbors, workers(count_workers))
        assert split.tobytes() == alone.tobytes()
    kept = remove_statistical_outliers(points, neighbors, 1.0)
    assert np.array_equal(kept, remove_statistical_outliers(points, neighbors, 1.0, workers(2)))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(1, 3000),
    neighbors=st.integers(1, 30),
    ranges=st.integers(1, 40),
    threads=st.integers(1, 4),
)
def test_query_ranges_taken_by_any_threads_give_the_same_distances(
    seed, count, neighbors, ranges, threads
):
    import threading

    from mvbb_ros.pipeline.outliers import NeighbourQueries

    rng = np.random.default_rng(seed)
    points = rng.normal(0.0, 1.0, (count, 3)) * rng.uniform(0.01, 3.0, 3)
    points[rng.integers(0, count, count // 4)] = points[-1]  # ties in the k-th distance
    alone = mean_neighbor_distances(points, neighbors)
    queries = NeighbourQueries(np.ascontiguousarray(points), neighbors, ranges)
    takers = [threading.Thread(target=queries.take) for _ in range(threads - 1)]
    for taker in takers:
        taker.start()
    queries.take()
    for taker in takers:
        taker.join()
    assert queries.distances.tobytes() == alone.tobytes()


def test_cancelled_queries_stop_taking_ranges():
    from mvbb_ros.pipeline.outliers import NeighbourQueries

    points = np.random.default_rng(1).normal(size=(4000, 3))
    queries = NeighbourQueries(points, 20, 16)
    queries.cancel()
    queries.take()
    assert not queries.distances.any(), 'no range computed after cancel'
