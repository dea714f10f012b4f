"""Point cloud files: round trips, the shared real files, and clear errors."""

from __future__ import annotations

import os

from mvbb_ros.cli.cloud_io import load_cloud, save_cloud
import numpy as np
import open3d as o3d
import pytest
from support.data import require_shared_data

FORMATS = ('npy', 'ply', 'pcd')


def sample_points(count=500, dtype=np.float64):
    rng = np.random.default_rng(0)
    return (rng.normal(size=(count, 3)) * [0.1, 0.05, 0.02] + [0.0, 0.1, 0.8]).astype(dtype)


@pytest.mark.parametrize('ext', FORMATS)
@pytest.mark.parametrize('dtype', [np.float32, np.float64])
def test_save_then_load_round_trips_exactly(tmp_path, ext, dtype):
    points = sample_points(dtype=dtype)
    path = save_cloud(tmp_path / f'cloud.{ext}', points)
    loaded = load_cloud(path)
    assert loaded.dtype == np.float64
    assert loaded.shape == points.shape
    assert np.array_equal(loaded, points.astype(np.float64))  # float32 stays float32 on disk
    assert sorted(os.listdir(tmp_path)) == [f'cloud.{ext}']  # no temporary files left


@pytest.mark.parametrize('ext', ['ply', 'pcd'])
def test_files_keep_the_coordinate_type(tmp_path, ext):
    save_cloud(tmp_path / f'single.{ext}', sample_points(dtype=np.float32))
    save_cloud(tmp_path / f'double.{ext}', sample_points(dtype=np.float64))
    single = o3d.t.io.read_point_cloud(str(tmp_path / f'single.{ext}'))
    double = o3d.t.io.read_point_cloud(str(tmp_path / f'double.{ext}'))
    assert single.point.positions.dtype == o3d.core.float32
    assert double.point.positions.dtype == o3d.core.float64
    # Other tools read them too: Open3D's legacy reader gives the same float32 points.
    legacy = np.asarray(o3d.io.read_point_cloud(str(tmp_path / f'single.{ext}')).points)
    assert np.array_equal(legacy, sample_points(dtype=np.float32).astype(np.float64))


@pytest.mark.parametrize('ext', FORMATS)
def test_non_finite_points_are_dropped_on_load(tmp_path, ext):
    points = sample_points(10)
    points[2] = np.nan
    points[5, 1] = np.inf
    points[7, 2] = -np.inf
    save_cloud(tmp_path / f'holes.{ext}', points)
    loaded = load_cloud(tmp_path / f'holes.{ext}')
    keep = [0, 1, 3, 4, 6, 8, 9]
    assert np.array_equal(loaded, points[keep])


def test_organized_arrays_are_flattened_in_row_major_order(tmp_path):
    organized = np.full((4, 5, 3), np.nan, dtype=np.float32)
    organized[1:3, 1:4] = np.arange(18, dtype=np.float32).reshape(2, 3, 3)
    save_cloud(tmp_path / 'organized.npy', organized)
    assert np.load(tmp_path / 'organized.npy').shape == (4, 5, 3)  # .npy keeps the layout
    expected = organized[1:3, 1:4].reshape(-1, 3)
    assert np.array_equal(load_cloud(tmp_path / 'organized.npy'), expected)
    save_cloud(tmp_path / 'organized.pcd', organized)
    assert np.array_equal(load_cloud(tmp_path / 'organized.pcd'), expected)


def test_integer_arrays_and_upper_case_extensions(tmp_path):
    with open(tmp_path / 'ints.NPY', 'wb') as handle:  # np.save would append '.npy'
        np.save(handle, np.arange(12).reshape(4, 3))
    assert np.array_equal(load_cloud(tmp_path / 'ints.NPY'), np.arange(12.0).reshape(4, 3))
    save_cloud(tmp_path / 'CLOUD.PLY', sample_points())
    assert np.array_equal(load_cloud(tmp_path / 'CLOUD.PLY'), sample_points())


def test_a_ply_mesh_gives_its_vertices(tmp_path):
    mesh = o3d.geometry.TriangleMesh.create_box(0.1, 0.2, 0.3)
    o3d.io.write_triangle_mesh(str(tmp_path / 'box.ply'), mesh)
    loaded = load_cloud(tmp_path / 'box.ply')
    np.testing.assert_allclose(loaded, np.asarray(mesh.vertices), atol=1e-7)


def test_saving_replaces_atomically_and_creates_folders(tmp_path):
    path = tmp_path / 'deep' / 'er' / 'cloud.pcd'
    save_cloud(path, sample_points())
    save_cloud(path, sample_points(7))
    assert len(load_cloud(path)) == 7
    assert os.listdir(path.parent) == ['cloud.pcd']


# Shared real data -------------------------------------------------------------------------------


def test_reads_the_shared_npy_and_ply_scans_identically():
    npy = require_shared_data('scans', 'pcl_kinect_box.npy')
    ply = require_shared_data('scans', 'pcl_kinect_box.ply')
    from_npy, from_ply = load_cloud(npy), load_cloud(ply)
    assert from_npy.shape == (12993, 3)  # MANIFEST: 12993 points, no NaNs, metres
    assert np.array_equal(from_npy, from_ply)  # same points, same order (PLY has rgb too)
    assert 0.3 < np.median(from_npy[:, 2]) < 3.0  # a Kinect scan in the optical frame


@pytest.mark.parametrize(
    ('name', 'finite'),
    [
        ('pcl_table_scene_mug_stereo_textured.pcd', 209280),
        ('pcl_kinect_laptop_box_frame.pcd', 271575),
        ('mosd_learn33.pcd', 179131),
    ],
)
def test_reads_the_shared_organized_pcd_scenes_without_their_nans(name, finite):
    path = require_shared_data('scenes', name)
    points = load_cloud(path)
    assert points.shape == (finite, 3)  # MANIFEST: finite points of the 640 x 480 frame
    assert np.all(np.isfinite(points))


def test_reads_a_shared_mesh_ply_as_its_vertices():
    path = require_shared_data('models', 'homer_mesh.ply')
    vertices = require_shared_data('models', 'homer_vertices.npy')
    assert np.array_equal(load_cloud(path), load_cloud(vertices))


# Errors -----------------------------------------------------------------------------------------


def test_missing_file_names_the_path(tmp_path):
    missing = tmp_path / 'nowhere' / 'cloud.pcd'
    with pytest.raises(FileNotFoundError, match='nowhere'):
        load_cloud(missing)


def test_a_directory_is_not_a_cloud(tmp_path):
    with pytest.raises(IsADirectoryError):
        load_cloud(tmp_path)


def test_unknown_extensions_are_refused(tmp_path):
    (tmp_path / 'cloud.xyz').write_text('0 0 0\n')
    with pytest.raises(ValueError, match=r"unknown point cloud file type '\.xyz'"):
        load_cloud(tmp_path / 'cloud.xyz')
    with pytest.raises(ValueError, match='unknown point cloud file type'):
        save_cloud(tmp_path / 'cloud.txt', sample_points())
    assert os.listdir(tmp_path) == ['cloud.xyz']


@pytest.mark.parametrize(
    ('array', 'message'),
    [
        (np.zeros((5, 2)), 'shape'),
        (np.zeros(9), 'shape'),
        (np.zeros((2, 3, 4)), 'shape'),
        (np.array(['a', 'b', 'c']).reshape(1, 3), 'numeric'),
        (np.full((3, 3), np.nan), 'no finite points'),
        (np.zeros((0, 3)), 'empty'),
    ],
)
def test_bad_npy_contents_are_refused(tmp_path, array, message):
    np.save(tmp_path / 'bad.npy', array)
    with pytest.raises(ValueError, match=message):
        load_cloud(tmp_path / 'bad.npy')


def test_pickled_npy_files_are_refused(tmp_path):
    np.save(tmp_path / 'objects.npy', np.array([{'x': 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match='not a plain NumPy array'):
        load_cloud(tmp_path / 'objects.npy')


@pytest.mark.parametrize('ext', ['ply', 'pcd'])
def test_malformed_ply_and_pcd_files_are_refused(tmp_path, ext):
    (tmp_path / f'junk.{ext}').write_text('this is not a point cloud\n')
    with pytest.raises(ValueError, match='no points read|not a PLY file'):
        load_cloud(tmp_path / f'junk.{ext}')


@pytest.mark.parametrize(
    'points', [np.zeros((0, 3)), np.zeros((4, 2)), np.array([['a', 'b', 'c']])]
)
def test_save_refuses_bad_points_and_writes_nothing(tmp_path, points):
    with pytest.raises(ValueError):
        save_cloud(tmp_path / 'cloud.ply', points)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize('encoding', ['binary_little_endian', 'ascii'])
def test_a_ply_header_promising_more_than_the_file_holds_is_refused_before_reading(
    tmp_path, encoding
):
    path = tmp_path / 'liar.ply'
    save_cloud(path, sample_points(200, np.float32))
    header, body = path.read_bytes().split(b'end_header\n', 1)
    header = header.replace(b'element vertex 200', b'element vertex 1000000000')
    header = header.replace(b'binary_little_endian', encoding.encode())
    path.write_bytes(header + b'end_header\n' + body)
    with pytest.raises(ValueError, match='promises at least'):
        load_cloud(path)


def test_an_honest_ply_header_is_read(tmp_path):
    path = tmp_path / 'honest.ply'
    points = sample_points(200, np.float32)
    save_cloud(path, points)
    np.testing.assert_array_equal(load_cloud(path), points.astype(np.float64))
