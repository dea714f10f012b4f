"""Boxes against whole objects: surface samples, coverage, volume ratio and thin plates."""

from __future__ import annotations

from mvbb_ros.evaluation.coverage import (
    box_metrics,
    convex_hull_volume,
    COVERAGE_TOLERANCE,
    covered,
    sample_surface,
    thin_count,
)
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.boxfit.fit import minimum_bounding_box
import numpy as np
import open3d as o3d
import pytest


def sphere(radius=0.05):
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=40)
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def box_mesh(size=(0.04, 0.06, 0.10)):
    mesh = o3d.geometry.TriangleMesh.create_box(*size)
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def test_surface_samples_are_uniform_by_area_on_every_side_and_repeatable():
    vertices, triangles = box_mesh((0.02, 0.02, 0.06))  # 2 x 2 end faces, 2 x 6 sides
    points = sample_surface(vertices, triangles, 20_000, seed=3)
    assert points.shape == (20_000, 3)
    np.testing.assert_array_equal(points, sample_surface(vertices, triangles, 20_000, seed=3))
    assert not np.array_equal(points, sample_surface(vertices, triangles, 20_000, seed=4))
    top = np.mean(points[:, 2] > 0.06 - 1e-9)
    bottom = np.mean(points[:, 2] < 1e-9)
    assert top == pytest.approx(4.0 / 52.0, abs=0.01)
    assert bottom == pytest.approx(4.0 / 52.0, abs=0.01)
    low = np.min(points, axis=0)
    high = np.max(points, axis=0)
    np.testing.assert_allclose(low, 0.0, atol=1e-3)
    np.testing.assert_allclose(high, [0.02, 0.02, 0.06], atol=1e-3)


def test_a_mesh_with_no_area_cannot_be_sampled():
    with pytest.raises(ValueError, match='no area'):
        sample_surface(np.zeros((3, 3)), [[0, 1, 2]], 10)


def test_the_objects_own_minimum_box_covers_its_whole_surface_with_volume_ratio_above_one():
    vertices, triangles = sphere()
    surface = sample_surface(vertices, triangles)
    hull = convex_hull_volume(vertices)
    metrics = box_metrics([minimum_bounding_box(vertices)], surface, hull)
    assert metrics.coverage > 0.999
    assert metrics.volume_ratio >= 1.0
    assert metrics.volume_ratio == pytest.approx(8.0 / (4.0 / 3.0 * np.pi), rel=0.05)  # cube
    assert metrics.boxes == 1 and metrics.thin == 0 and metrics.thin_share == 0.0


def test_a_box_around_the_top_half_covers_about_half_the_surface():
    vertices, triangles = sphere(0.05)
    surface = sample_surface(vertices, triangles)
    top = Box(center=[0.0, 0.0, 0.025], rotation=np.eye(3), extents=[0.1, 0.1, 0.05])
    metrics = box_metrics([top], surface, convex_hull_volume(vertices))
    # Half the sphere, plus the 2 mm band below the equator that the tolerance adds (2 %).
    assert 0.49 < metrics.coverage < 0.54
    assert metrics.volume_ratio == pytest.approx(0.5 * 8.0 / (4.0 / 3.0 * np.pi), rel=0.05)


def test_coverage_counts_the_union_of_boxes_once_and_the_tolerance():
    points = np.array([[0.0, 0.0, 0.0], [0.0105, 0.0, 0.0], [0.5, 0.0, 0.0]])
    cube = Box(center=[0.0, 0.0, 0.0], rotation=np.eye(3), extents=[0.02, 0.02, 0.02])
    inside = covered([cube, cube], points)
    np.testing.assert_array_equal(inside, [True, True, False])  # 0.5 mm over, within 2 mm
    assert COVERAGE_TOLERANCE == 0.002
    np.testing.assert_array_equal(covered([cube], points, tolerance=0.0), [True, False, False])
    np.testing.assert_array_equal(covered([], points), [False, False, False])


def test_thin_boxes_are_those_under_one_centimetre_thick():
    boxes = [
        Box(center=[0, 0, 0], rotation=np.eye(3), extents=[0.1, 0.1, 0.009]),
        Box(center=[0, 0, 0], rotation=np.eye(3), extents=[0.1, 0.011, 0.1]),
        Box(center=[0, 0, 0], rotation=np.eye(3), extents=[0.003, 0.1, 0.1]),
    ]
    assert thin_count(boxes) == 2
    vertices, triangles = box_mesh()
    metrics = box_metrics(boxes, sample_surface(vertices, triangles), 0.04 * 0.06 * 0.1)
    assert metrics.thin == 2 and metrics.thin_share == pytest.approx(2.0 / 3.0)


def test_convex_hull_volume_and_its_degenerate_cases():
    vertices, _ = box_mesh()
    assert convex_hull_volume(vertices) == pytest.approx(0.04 * 0.06 * 0.10)
    assert convex_hull_volume(np.zeros((2, 3))) == 0.0
    flat = np.random.default_rng(0).random((20, 3)) * [1.0, 1.0, 0.0]
    assert convex_hull_volume(flat) == 0.0
    with pytest.raises(ValueError):
        box_metrics([], vertices, 0.0)
