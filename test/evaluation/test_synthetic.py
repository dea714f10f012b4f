"""
Synthetic sample data: meshes, ray-cast depth views, noise, scenes and organized frames.

The depth camera itself (noise, poses, ray casting) is :mod:`mvbb_ros.evaluation.camera`; the
scenes it looks at here are :mod:`mvbb_ros.evaluation.synthetic`'s.
"""

from __future__ import annotations

import math

from mvbb_ros.evaluation import camera, coverage
from mvbb_ros.evaluation.camera import (
    BACKGROUND,
    DepthNoise,
    look_at,
    orbit_pose,
    render_depth_cloud,
)
from mvbb_ros.evaluation.synthetic import (
    make_object_mesh,
    make_scene,
    organized_frame,
    place_objects,
    pose_matrix,
    scene_views,
    segmented_object_cloud,
)
import numpy as np
import open3d as o3d
import pytest
from scipy.spatial import cKDTree

# Small images keep the tests quick; the field of view is that of a 640 x 480, f = 525 camera.
W, H = 160, 120
F = camera.DEFAULT_FOCAL * W / camera.DEFAULT_WIDTH
SMALL = {'width': W, 'height': H, 'fx': F, 'fy': F}


def to_world(points, pose):
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return pts @ pose[:3, :3].T + pose[:3, 3]


def surface_distance(mesh, points_world):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    query = o3d.core.Tensor(np.asarray(points_world, dtype=np.float32))
    return scene.compute_distance(query).numpy()


def sample_surface(mesh, count, seed=0):
    """Return points drawn uniformly by area on a triangle mesh."""
    return coverage.sample_surface(
        np.asarray(mesh.vertices), np.asarray(mesh.triangles), count, seed
    )


def single_object(kind='mug', yaw_deg=0.0):
    """One object at the table centre and the view segmented_object_cloud documents."""
    scene = place_objects([kind], [pose_matrix(yaw=math.radians(yaw_deg))])
    center = scene.objects[0].mesh.get_axis_aligned_bounding_box().get_center()
    return scene, center


# Meshes -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ('kind', 'extent'),
    [
        ('mug', (0.08 + 0.0335, 0.08, 0.10)),  # handle reaches 33.5 mm out of the 80 mm body
        ('can', (0.066, 0.066, 0.122)),
        ('box', (0.158, 0.060, 0.210)),
        ('bottle', (0.072, 0.072, 0.250)),
    ],
)
def test_object_meshes_have_real_sizes_and_stand_on_z0(kind, extent):
    mesh = make_object_mesh(kind)
    bounds = mesh.get_axis_aligned_bounding_box()
    np.testing.assert_allclose(bounds.get_extent(), extent, atol=0.002)
    assert bounds.get_min_bound()[2] == pytest.approx(0.0, abs=1e-12)
    assert mesh.has_vertex_normals()


@pytest.mark.parametrize('kind', ['can', 'box', 'bottle'])
def test_closed_meshes_are_watertight_with_outward_normals(kind):
    mesh = make_object_mesh(kind)
    assert mesh.is_watertight()
    assert mesh.get_volume() > 0.0  # signed volume: positive means outward-facing triangles


def test_mug_is_hollow_with_a_handle():
    mesh = make_object_mesh('mug')
    # A ray straight down the axis enters the opening and stops on the inner bottom (6 mm base).
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    rays = np.array([[0, 0, 0.5, 0, 0, -1], [0.5, 0, 0.054, -1, 0, 0]], dtype=np.float32)
    t_hit = scene.cast_rays(o3d.core.Tensor(rays))['t_hit'].numpy()
    assert t_hit[0] == pytest.approx(0.5 - 0.006, abs=1e-5)
    # A ray towards the axis at mid-height meets the handle's outermost part first: centre line
    # at x = 68 mm, plus its 5.5 mm tube radius.
    assert t_hit[1] == pytest.approx(0.5 - (0.068 + 0.0055), abs=2e-4)


def test_unknown_kind_and_bad_resolution_are_refused():
    with pytest.raises(ValueError, match='unknown object kind'):
        make_object_mesh('teapot')
    with pytest.raises(ValueError, match='resolution'):
        make_object_mesh('can', resolution=3)


# Camera -----------------------------------------------------------------------------------------


def test_look_at_gives_an_optical_frame_with_world_up_upwards_in_the_image():
    pose = look_at([0.5, -0.6, 0.4], [0.0, 0.0, 0.05])
    rotation = pose[:3, :3]
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    forward = np.array([0.0, 0.0, 0.05]) - np.array([0.5, -0.6, 0.4])
    np.testing.assert_allclose(rotation[:, 2], forward / np.linalg.norm(forward), atol=1e-12)
    assert rotation[:, 1] @ [0.0, 0.0, 1.0] < 0.0  # image y (down) points against world up
    assert abs(rotation[:, 0] @ [0.0, 0.0, 1.0]) < 1e-12  # image x stays horizontal
    with pytest.raises(ValueError):
        look_at([0, 0, 1], [0, 0, 0])  # looking straight down: up is undefined


def test_rays_match_open3d_pinhole_model():
    """Pixel (u, v) looks along ((u - cx) / fx, (v - cy) / fy, 1), like Open3D's pinhole rays."""
    scene, center = single_object('mug')
    pose = orbit_pose(center, 0.5, -60.0, 35.0)
    points, _ = render_depth_cloud(scene, pose, noise=None, **SMALL)
    cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
    # Open3D puts pixel centres at u + 0.5, so shifting its principal point by half a pixel
    # gives the same rays.
    intrinsic = np.array([[F, 0.0, cx + 0.5], [0.0, F, cy + 0.5], [0.0, 0.0, 1.0]])
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(intrinsic), o3d.core.Tensor(np.linalg.inv(pose)), W, H
    )
    caster = o3d.t.geometry.RaycastingScene()
    for mesh in [*scene.meshes, scene.table]:
        caster.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    t_hit = caster.cast_rays(rays)['t_hit'].numpy()
    hits = rays.numpy()[..., :3] + rays.numpy()[..., 3:] * t_hit[..., None]
    assert np.array_equal(np.isfinite(points[..., 2]), np.isfinite(t_hit))
    valid = np.isfinite(t_hit)
    np.testing.assert_allclose(to_world(points[valid], pose), hits[valid], atol=2e-5)


# Ray-cast views ---------------------------------------------------------------------------------


def test_mug_points_lie_on_the_mug_surface_within_the_noise():
    scene, center = single_object('mug')
    pose = orbit_pose(center, 0.6, -60.0, 35.0)
    noise = camera.DEFAULT_NOISE
    points, labels = render_depth_cloud(scene, pose, noise=noise, seed=3, **SMALL)
    mug = points[labels == 0]
    assert len(mug) > 300
    distance = surface_distance(scene.objects[0].mesh, to_world(mug, pose))
    # Noise moves a point along its pixel's ray (|ray| <= 1.1 here) by a Gaussian of sigma(z).
    bound = 1.1 * 5.0 * float(noise.sigma(mug[:, 2].max()))
    assert distance.max() < bound
    assert np.median(distance) < 0.7 * float(noise.sigma(mug[:, 2].mean()))

    exact, exact_labels = render_depth_cloud(scene, pose, noise=None, **SMALL)
    exact_distance = surface_distance(
        scene.objects[0].mesh, to_world(exact[exact_labels == 0], pose)
    )
    assert exact_distance.max() < 2e-5


def test_only_the_camera_facing_side_is_seen():
    scene, center = single_object('can')
    pose = orbit_pose(center, 0.6, 30.0, 25.0)
    points, labels = render_depth_cloud(
        scene, pose, noise=None, width=320, height=240, fx=262.5, fy=262.5
    )
    world = to_world(points[labels == 0], pose)
    # Points on the can's side (below the top bevel) all face the camera's side of the axis.
    side = world[(world[:, 2] > 0.01) & (world[:, 2] < 0.105)]
    towards_camera = pose[:2, 3] / np.linalg.norm(pose[:2, 3])
    assert len(side) > 500
    assert np.min(side[:, :2] @ towards_camera) > -1e-3
    # About half of the can's surface is seen: most of the far side is missing.
    surface = sample_surface(scene.objects[0].mesh, 4000)
    near, _ = cKDTree(world).query(surface)
    seen = np.mean(near < 0.004)
    assert 0.25 < seen < 0.65


def test_same_seed_same_cloud_other_seed_other_noise():
    first = segmented_object_cloud('mug', seed=1, width=W, height=H)
    again = segmented_object_cloud('mug', seed=1, width=W, height=H)
    other = segmented_object_cloud('mug', seed=2, width=W, height=H)
    assert first.dtype == np.float32
    assert first.shape[1] == 3
    assert np.array_equal(first, again)
    assert first.shape == other.shape  # same pixels (no random dropout by default) ...
    assert not np.allclose(first, other)  # ... with different noise
    # The noise is along the rays: the same pixel keeps its direction x/z, y/z.
    np.testing.assert_allclose(first[:, :2] / first[:, 2:], other[:, :2] / other[:, 2:], atol=1e-5)


def test_segmented_object_cloud_is_the_object_pixels_of_the_documented_view():
    scene, center = single_object('box', yaw_deg=20.0)
    pose = orbit_pose(center, 0.7, -30.0, 40.0)
    expected, labels = render_depth_cloud(scene, pose, seed=5, **SMALL)
    view = {'distance': 0.7, 'azimuth_deg': -30.0, 'elevation_deg': 40.0, 'yaw_deg': 20.0}
    cloud = segmented_object_cloud('box', seed=5, width=W, height=H, **view)
    assert np.array_equal(cloud, expected[labels == 0])
    assert np.all(np.isfinite(cloud))
    assert np.all(cloud[:, 2] > 0.5)
    assert np.all(cloud[:, 2] < 0.9)


def test_depth_noise_has_the_documented_standard_deviation():
    # A wall facing the camera 1 m away: depth residuals have sigma(1 m) = 0.0005 + 0.0012.
    wall = o3d.geometry.TriangleMesh.create_box(4.0, 4.0, 0.01).translate([-2.0, -2.0, 1.0])
    pose = np.eye(4)  # the optical frame is the world frame: the camera looks along +z
    noise = DepthNoise()
    exact, _ = render_depth_cloud(wall, pose, noise=None, **SMALL)
    noisy, labels = render_depth_cloud(wall, pose, noise=noise, seed=0, **SMALL)
    assert np.all(labels == 0)
    residual = (noisy[..., 2] - exact[..., 2]).ravel()
    assert np.std(residual) == pytest.approx(float(noise.sigma(1.0)), rel=0.05)
    assert abs(np.mean(residual)) < 0.05 * float(noise.sigma(1.0))


def test_disparity_quantisation_puts_depths_on_the_inverse_depth_grid():
    wall = o3d.geometry.TriangleMesh.create_box(4.0, 4.0, 0.01).translate([-2.0, -2.0, 0.9])
    tilted = wall.rotate(look_at([0, 0, 0], [0.3, 0, 1])[:3, :3], center=[0, 0, 1.0])
    noise = DepthNoise(sigma_const=0.0, sigma_quadratic=0.0, disparity_step=0.0029)
    points, _ = render_depth_cloud(tilted, np.eye(4), noise=noise, **SMALL)
    depth = points[..., 2][np.isfinite(points[..., 2])].astype(np.float64)
    steps = 1.0 / (depth * noise.disparity_step)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)
    assert len(np.unique(np.round(steps))) > 5  # a tilted wall spans several depth steps


def test_grazing_surfaces_are_dropped():
    # A floor seen at about 84 degrees from its normal: a real sensor returns almost nothing.
    floor = o3d.geometry.TriangleMesh.create_box(4.0, 4.0, 0.01).translate([-2.0, -0.5, -0.11])
    pose = look_at([0.0, 0.0, 0.0], [0.0, 1.0, -0.1])
    exact, _ = render_depth_cloud(floor, pose, noise=None, **SMALL)
    steep, _ = render_depth_cloud(floor, pose, noise=DepthNoise(max_incidence_deg=85.0), **SMALL)
    default, _ = render_depth_cloud(floor, pose, noise=DepthNoise(), **SMALL)
    n_exact, n_steep, n_default = (
        np.count_nonzero(np.isfinite(p[..., 2])) for p in (exact, steep, default)
    )
    assert n_exact > 1000
    assert 0 < n_steep < n_exact
    assert n_default < n_steep


def test_dropout_removes_the_expected_fraction():
    scene, center = single_object('box')
    pose = orbit_pose(center, 0.6, -60.0, 35.0)
    full, _ = render_depth_cloud(scene, pose, noise=DepthNoise(), **SMALL)
    lossy, labels = render_depth_cloud(scene, pose, noise=DepthNoise(dropout=0.2), **SMALL)
    kept = np.count_nonzero(np.isfinite(lossy[..., 2])) / np.count_nonzero(
        np.isfinite(full[..., 2])
    )
    assert kept == pytest.approx(0.8, abs=0.03)
    assert np.all(labels[~np.isfinite(lossy[..., 2])] == BACKGROUND)


@pytest.mark.parametrize(
    'kwargs',
    [
        {'sigma_const': -1.0},
        {'max_incidence_deg': 0.0},
        {'max_incidence_deg': 95.0},
        {'dropout': 1.0},
    ],
)
def test_bad_noise_models_are_refused(kwargs):
    with pytest.raises(ValueError):
        DepthNoise(**kwargs)


# Scenes and labels ------------------------------------------------------------------------------


def test_organized_frame_has_nan_where_rays_miss_and_matching_labels():
    scene = make_scene(seed=4)
    # Looking over the table edge: the upper part of the image sees nothing.
    pose = orbit_pose([0.0, 0.0, 0.1], 0.8, -90.0, 10.0)
    points, labels = render_depth_cloud(scene, pose, seed=0, **SMALL)
    assert points.shape == (H, W, 3)
    assert points.dtype == np.float32
    assert labels.shape == (H, W)
    assert labels.dtype == np.int32
    finite = np.all(np.isfinite(points), axis=2)
    assert np.all(np.isnan(points[~finite]))  # a missing pixel is NaN in all three coordinates
    assert 0.05 < np.mean(finite) < 0.95
    assert not finite[0].any()  # the top row looks over the table into the void
    assert np.all(labels[~finite] == BACKGROUND)
    seen = set(np.unique(labels[finite]).tolist())
    assert seen <= {BACKGROUND, *range(len(scene.objects))}
    assert len(seen - {BACKGROUND}) >= 3
    # Every labelled point lies on the object its label names, closer than to any other.
    world = to_world(points[finite], pose)
    distances = np.stack([surface_distance(m, world) for m in [*scene.meshes, scene.table]])
    nearest = np.argmin(distances, axis=0)
    nearest[nearest == len(scene.objects)] = BACKGROUND
    agree = np.mean(nearest == labels[finite])
    assert agree > 0.99  # only noisy points at contact lines (object on table) may disagree


def test_unorganized_render_is_the_finite_pixels_in_row_major_order():
    scene = make_scene(seed=1)
    pose = orbit_pose([0.0, 0.0, 0.05], 0.8, -100.0, 35.0)
    points, labels = render_depth_cloud(scene, pose, seed=2, **SMALL)
    flat_points, flat_labels = render_depth_cloud(scene, pose, seed=2, organized=False, **SMALL)
    finite = np.isfinite(points[..., 2])
    assert np.array_equal(flat_points, points[finite])
    assert np.array_equal(flat_labels, labels[finite])
    assert np.all(np.isfinite(flat_points))


def test_make_scene_is_deterministic_and_objects_stand_apart_on_the_table():
    scene = make_scene(seed=7)
    again = make_scene(seed=7)
    other = make_scene(seed=8)
    assert scene.names == ['mug', 'can', 'box', 'bottle']
    for a, b in zip(scene.poses, again.poses, strict=True):
        assert np.array_equal(a, b)
    assert not all(np.allclose(a, b) for a, b in zip(scene.poses, other.poses, strict=True))
    for mesh in scene.meshes:
        assert mesh.get_min_bound()[2] == pytest.approx(0.0, abs=1e-9)
    # Footprints (discs around each axis) do not overlap.
    centers = [pose[:2, 3] for pose in scene.poses]
    radii = [
        np.max(np.linalg.norm(np.asarray(m.vertices)[:, :2] - c, axis=1))
        for m, c in zip(scene.meshes, centers, strict=True)
    ]
    for i in range(len(centers)):
        for j in range(i + 1, len(centers)):
            assert np.linalg.norm(centers[i] - centers[j]) > radii[i] + radii[j]
    assert scene.label_of('box') == 2


def test_scene_views_orbit_the_target_and_are_reproducible():
    scene = make_scene(seed=0)
    target = np.array([0.0, 0.0, 0.05])
    views = list(scene_views(scene, 4, **SMALL_VIEW, seed=9))
    again = list(scene_views(scene, 4, **SMALL_VIEW, seed=9))
    assert [v.index for v in views] == [0, 1, 2, 3]
    positions = np.array([v.camera_pose[:3, 3] for v in views])
    np.testing.assert_allclose(np.linalg.norm(positions - target, axis=1), 0.8)
    azimuths = np.degrees(np.arctan2(positions[:, 1], positions[:, 0]))
    np.testing.assert_allclose(azimuths, np.linspace(-135.0, -45.0, 4), atol=1e-9)
    for view, twin in zip(views, again, strict=True):
        # The target projects to the image centre.
        local = np.linalg.inv(view.camera_pose) @ np.append(target, 1.0)
        assert local[0] == pytest.approx(0.0, abs=1e-12)
        assert local[1] == pytest.approx(0.0, abs=1e-12)
        assert np.array_equal(view.points, twin.points, equal_nan=True)
        assert np.array_equal(view.labels, twin.labels)
        assert view.points.shape == (H, W, 3)
    # Each frame has its own noise.
    both = np.isfinite(views[0].points[..., 2]) & np.isfinite(views[1].points[..., 2])
    assert not np.array_equal(views[0].points[both], views[1].points[both])
    seen = set().union(*(np.unique(v.labels).tolist() for v in views))
    assert set(range(len(scene.objects))) <= seen


SMALL_VIEW = {'width': W, 'height': H, 'fx': F, 'fy': F}


# Benchmark frames -------------------------------------------------------------------------------


def test_organized_frame_has_about_the_requested_object_points():
    frame = organized_frame(20_000, kind='can', seed=0)
    height, width, _ = frame.shape
    assert width / height == pytest.approx(4.0 / 3.0, abs=0.01)
    assert frame.dtype == np.float32
    count = np.count_nonzero(np.isfinite(frame[..., 2]))
    assert count == pytest.approx(20_000, rel=0.05)
    assert np.isnan(frame[0, 0]).all()  # corners show the background, NaN


def test_default_size_frames_have_their_full_sizes():
    """The default 640 x 480 ray cast and the 300k-point frame at full size (timed elsewhere)."""
    scene = make_scene(seed=0)
    pose = orbit_pose([0.0, 0.0, 0.05], 0.8, -90.0, 35.0)
    points, labels = render_depth_cloud(scene, pose)
    assert points.shape == (480, 640, 3)
    assert labels.shape == (480, 640)
    frame = organized_frame()
    count = np.count_nonzero(np.isfinite(frame[..., 2]))
    assert count == pytest.approx(300_000, rel=0.05)
