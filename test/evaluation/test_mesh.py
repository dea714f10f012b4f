"""The grasp target (evaluation.mesh): mass properties, closed and open meshes, every mesh form."""

from __future__ import annotations

import math

from mvbb_ros.evaluation.mesh import center_of_mass, GraspTarget, is_closed
from mvbb_ros.evaluation.simulation import grasp_quality
import numpy as np
import open3d as o3d
import pytest
from support.grasp_targets import CUBE_GRIPPER, cube_mesh, top_grasp


def test_cube_target_mass_properties(cube):
    assert cube.closed
    assert cube.com_method == 'solid'
    np.testing.assert_allclose(cube.center_of_mass, 0.0, atol=1e-12)
    assert cube.radius == pytest.approx(math.sqrt(3) / 2)
    assert cube.diameter == pytest.approx(math.sqrt(3))


def test_center_of_mass_is_the_solid_centroid_not_the_vertex_mean():
    # A square pyramid (apex up) has its centroid at a quarter of its height, whatever the
    # triangulation; its vertex mean (what Open3D's get_center returns) is higher.
    base = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
    apex = np.array([[0.0, 0.0, 2.0]])
    verts = np.vstack([base, apex])
    tris = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    centre, method = center_of_mass(verts, tris)
    assert method == 'solid'
    np.testing.assert_allclose(centre, [0.0, 0.0, 0.5], atol=1e-12)
    assert verts.mean(axis=0)[2] == pytest.approx(0.4)
    # The winding (inward or outward) does not matter.
    centre_flipped, _ = center_of_mass(verts, tris[:, ::-1])
    np.testing.assert_allclose(centre_flipped, centre, atol=1e-12)


def test_open_mesh_uses_the_surface_centroid():
    # The cube without its top face: the area-weighted centroid of five unit squares.
    mesh = cube_mesh()
    tris = np.asarray(mesh.triangles)
    verts = np.asarray(mesh.vertices)
    centroids = verts[tris].mean(axis=1)
    open_tris = tris[centroids[:, 2] < 0.5 - 1e-9]
    assert not is_closed(open_tris)
    centre, method = center_of_mass(verts, open_tris)
    assert method == 'surface'
    np.testing.assert_allclose(centre, [0.0, 0.0, -0.1], atol=1e-12)


def test_targets_from_every_mesh_form(tmp_path, cube):
    legacy = cube_mesh()
    path = tmp_path / 'cube.ply'
    assert o3d.io.write_triangle_mesh(str(path), legacy)
    forms = [
        legacy,
        o3d.t.geometry.TriangleMesh.from_legacy(legacy),
        (np.asarray(legacy.vertices), np.asarray(legacy.triangles)),
        path,
        str(path),
    ]
    for form in forms:
        target = GraspTarget.from_mesh(form)
        quality = grasp_quality(target, top_grasp(), gripper=CUBE_GRIPPER)
        assert quality.epsilon == pytest.approx(
            grasp_quality(cube, top_grasp(), gripper=CUBE_GRIPPER).epsilon, rel=1e-6
        )
    assert GraspTarget.from_mesh(cube) is cube
    with pytest.raises(FileNotFoundError):
        GraspTarget.from_mesh(tmp_path / 'missing.ply')
