"""The numpy voxel grid against Open3D's voxel_down_sample, and filter_points' back-ends."""

from __future__ import annotations

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
from mvbb_ros.pipeline import filtering
from mvbb_ros.pipeline.filtering import filter_points, voxel_down_sample
import numpy as np
import open3d as o3d
import pytest


def open3d_centroids(points: np.ndarray, voxel_size: float) -> np.ndarray:
    cloud = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64))
    )
    return np.asarray(cloud.voxel_down_sample(voxel_size).points)


def sorted_rows(points: np.ndarray) -> np.ndarray:
    return points[np.lexsort(points.T[::-1])]


def assert_same_centroids(ours: np.ndarray, theirs: np.ndarray) -> None:
    assert ours.shape == theirs.shape
    np.testing.assert_allclose(sorted_rows(ours), sorted_rows(theirs), rtol=0, atol=1e-9)


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
    centroids, counts = voxel_down_sample(points, voxel_size)

    assert_same_centroids(centroids, open3d_centroids(points, voxel_size))
    assert counts.sum() == len(points) and (counts >= 1).all()
    assert centroids.dtype == np.float64 and centroids.flags.c_contiguous


def test_sparse_grid_path_gives_the_same_centroids(monkeypatch):
    # A wide, sparse cloud (a lidar sweep) is grouped by sorting; force both paths to compare.
    rng = np.random.default_rng(1)
    points = np.concatenate([object_points(3000), rng.uniform(-30.0, 30.0, size=(500, 3))])
    sparse, sparse_counts = voxel_down_sample(points, 0.005)
    monkeypatch.setattr(filtering, 'DENSE_GRID_MIN_CELLS', 0)
    monkeypatch.setattr(filtering, 'DENSE_GRID_FACTOR', 0)
    also_sparse, _ = voxel_down_sample(object_points(3000), 0.005)

    assert_same_centroids(sparse, open3d_centroids(points, 0.005))
    assert sparse_counts.sum() == len(points)
    assert_same_centroids(also_sparse, open3d_centroids(object_points(3000), 0.005))


def test_centroids_are_sorted_by_voxel_and_deterministic():
    points = object_points(5000)
    first, _ = voxel_down_sample(points, 0.004)
    second, _ = voxel_down_sample(points[::-1].copy(), 0.004)
    keys = np.floor((first - (points.min(axis=0) - 0.002)) / 0.004).astype(np.int64)
    assert (np.diff(keys[:, 0]) >= 0).all()
    np.testing.assert_allclose(first, second, rtol=0, atol=1e-12)


def test_edge_cases():
    empty, counts = voxel_down_sample(np.empty((0, 3), dtype=np.float32), 0.01)
    assert empty.shape == (0, 3) and counts.shape == (0,)
    one, counts = voxel_down_sample([[1.0, 2.0, 3.0]], 0.01)
    np.testing.assert_array_equal(one, [[1.0, 2.0, 3.0]])
    assert counts.tolist() == [1]
    same, counts = voxel_down_sample(np.ones((7, 3)), 0.01)
    assert same.shape == (1, 3) and counts.tolist() == [7]
    with pytest.raises(ValueError, match='voxel_size must be > 0'):
        voxel_down_sample(np.ones((3, 3)), 0.0)
    with pytest.raises(ValueError, match='too small'):
        voxel_down_sample([[0.0, 0.0, 0.0], [1e6, 1e6, 1e6]], 1e-9)


coordinates = st.floats(-2.0, 2.0, allow_nan=False, width=32)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.tuples(coordinates, coordinates, coordinates), min_size=1, max_size=300),
    st.sampled_from([0.001, 0.01, 0.05, 0.3]),
    st.sampled_from([np.float32, np.float64]),
)
def test_property_voxel_grid_matches_open3d(rows, voxel_size, dtype):
    points = np.asarray(rows, dtype=dtype)
    centroids, counts = voxel_down_sample(points, voxel_size)

    assert_same_centroids(centroids, open3d_centroids(points, voxel_size))
    assert counts.sum() == len(points)


@pytest.mark.parametrize('outlier_neighbors', [0, 20])
def test_both_backends_filter_to_the_same_points(outlier_neighbors):
    rng = np.random.default_rng(2)
    points = np.concatenate([object_points(30_000), rng.uniform(-0.5, 0.5, (40, 3)) + 0.7])
    options = {'voxel_size': 0.005, 'outlier_neighbors': outlier_neighbors}

    ours, our_counts = filter_points(points, **options)
    theirs, their_counts = filter_points(points, voxel_backend='open3d', **options)

    assert our_counts == their_counts
    assert_same_centroids(ours, theirs)
    if outlier_neighbors:
        assert our_counts.inliers < our_counts.downsampled


def test_filter_accepts_float32_and_returns_float64_with_counts():
    points = object_points(2000)
    filtered, counts = filter_points(
        points, crop_min=(0.0, -1.0, 0.0), crop_max=(0.12, 1.0, 1.0), voxel_size=0.0
    )
    inside = points[(points[:, 0] >= 0.0) & (points[:, 0] <= 0.12)]
    assert filtered.dtype == np.float64
    np.testing.assert_array_equal(filtered, inside.astype(np.float64))
    assert counts.finite == 2000 and counts.cropped == len(inside) == counts.inliers
    with pytest.raises(ValueError, match='voxel_backend'):
        filter_points(points, voxel_backend='pcl')
