"""
Read and write point clouds as plain (N, 3) arrays: NumPy .npy, PLY and PCD files.

PLY and PCD go through Open3D's tensor I/O (``open3d.t.io``), which keeps float32 or float64
coordinates as they are stored, reads PCL's ``binary_compressed`` PCD files and, for a PLY mesh,
returns its vertices. Extra fields (colour, normals, labels) are ignored. Open3D is loaded only
for a PLY or PCD file, after a PLY header was checked against the file's size: a .npy file, or
a PLY file that lies about its size, never loads it (Open3D alone reserves about a gigabyte of
address space). No ROS import.
"""

from __future__ import annotations

import os
from pathlib import Path

from mvbb_ros.common.atomic import atomic_open, atomic_path
import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: File extensions :func:`load_cloud` and :func:`save_cloud` understand (lower case).
CLOUD_EXTENSIONS: tuple[str, ...] = ('.npy', '.ply', '.pcd')


def _extension(path: Path) -> str:
    ext = path.suffix.lower()
    if ext not in CLOUD_EXTENSIONS:
        known = ', '.join(CLOUD_EXTENSIONS)
        raise ValueError(f'{path}: unknown point cloud file type {ext or "(none)"!r}; use {known}')
    return ext


def _as_xyz(array: np.ndarray, source: str) -> np.ndarray:
    """Check that `array` is (N, 3) or organized (H, W, 3) real numbers; return it as (N, 3)."""
    if array.dtype.kind not in 'fiu':
        raise ValueError(f'{source}: expected a numeric array of points, got dtype {array.dtype}')
    if array.ndim not in (2, 3) or array.shape[-1] != 3:
        raise ValueError(
            f'{source}: expected points of shape (N, 3) or (H, W, 3), got shape {array.shape}'
        )
    return array.reshape(-1, 3)


#: Bytes of each PLY scalar type (both the old and the sized names).
_PLY_SIZES = {
    **dict.fromkeys(('char', 'uchar', 'int8', 'uint8'), 1),
    **dict.fromkeys(('short', 'ushort', 'int16', 'uint16'), 2),
    **dict.fromkeys(('int', 'uint', 'float', 'int32', 'uint32', 'float32'), 4),
    **dict.fromkeys(('double', 'float64'), 8),
}

#: How far into a PLY file its header may reach.
_PLY_HEADER_LIMIT = 1 << 16


def check_ply_header(file: Path) -> None:
    """
    Refuse a PLY file whose header promises more data than the file holds.

    A reader trusts the element counts and allocates for them before it reads: a 36 KB file
    claiming 10^9 vertices would take gigabytes. Every element row needs at least its fixed-size
    properties (binary; a list property at least its count) or two bytes a property (ASCII).

    :raises ValueError: a header without ``end_header`` or counts the file cannot hold.
    """
    with file.open('rb') as stream:
        head = stream.read(_PLY_HEADER_LIMIT)
    end = head.find(b'end_header')
    if not head.startswith(b'ply') or end < 0:
        raise ValueError(f'{file}: not a PLY file (no ply ... end_header header)')
    body = file.stat().st_size - (head.find(b'\n', end) + 1)
    binary = b'binary' in head[:end]
    needed = 0
    count = 0
    row = 0
    for line in head[:end].decode('ascii', 'replace').splitlines():
        words = line.split()
        if words[:1] == ['element'] and len(words) == 3 and words[2].isdigit():
            needed += count * row
            count, row = int(words[2]), 0
        elif words[:2] == ['property', 'list'] and len(words) == 5:
            row += _PLY_SIZES.get(words[2], 1) if binary else 2
        elif words[:1] == ['property'] and len(words) == 3:
            row += _PLY_SIZES.get(words[1], 1) if binary else 2
    needed += count * row
    if needed > body:
        raise ValueError(
            f'{file}: the PLY header promises at least {needed} bytes of data, the file holds '
            f'{body} (truncated, or a corrupt element count)'
        )


def load_cloud(path: str | os.PathLike[str]) -> FloatArray:
    """
    Read the points of a .npy, .ply or .pcd file, without the non-finite ones.

    A .npy file must hold a numeric array of shape (N, 3) or (H, W, 3) (loaded without pickle).
    A .ply or .pcd file may be organized (PCL clouds with NaN for invalid pixels) or a mesh (its
    vertices are returned). Points with a NaN or infinite coordinate are dropped, so an organized
    cloud comes back unorganized, in row-major order.

    :param path: the file.
    :return: (N, 3) float64 points, N >= 1, in the file's units.
    :raises FileNotFoundError: when `path` does not exist.
    :raises IsADirectoryError: when `path` is a directory.
    :raises ValueError: for an unknown extension, a malformed or unreadable file, an array of
        the wrong shape or type, or a file without any finite point.
    """
    file = Path(path)
    if not file.exists():
        raise FileNotFoundError(f'point cloud file not found: {file}')
    if file.is_dir():
        raise IsADirectoryError(f'expected a point cloud file, got a directory: {file}')
    ext = _extension(file)
    if ext == '.npy':
        try:
            array = np.load(file, allow_pickle=False)
        except ValueError as error:  # pickled objects, or not a .npy file at all
            raise ValueError(f'{file}: not a plain NumPy array file ({error})') from error
        points = _as_xyz(np.asarray(array), str(file))
    else:
        if ext == '.ply':
            check_ply_header(file)
        import open3d as o3d  # only for PLY and PCD (see the module's docstring)

        cloud = o3d.t.io.read_point_cloud(str(file))
        if 'positions' not in cloud.point or len(cloud.point.positions) == 0:
            raise ValueError(f'{file}: no points read (empty, malformed or not a {ext} file)')
        points = _as_xyz(cloud.point.positions.numpy(), str(file))
    if len(points) == 0:
        raise ValueError(f'{file}: the cloud is empty (no points)')
    points = points.astype(np.float64, copy=False)
    finite = points[np.all(np.isfinite(points), axis=1)]
    if len(finite) == 0:
        raise ValueError(f'{file}: no finite points ({len(points)} points, all NaN or infinite)')
    return np.ascontiguousarray(finite)


def save_cloud(path: str | os.PathLike[str], points: ArrayLike) -> Path:
    """
    Write points to a .npy, .ply or .pcd file, atomically (a failure leaves no partial file).

    The coordinates keep their type: float32 stays float32 (PCD ``SIZE 4``, PLY ``float``),
    anything else is written as float64 (integers are converted). Binary PLY and PCD are
    written; NaN points are kept as they are (:func:`load_cloud` drops them).

    :param path: the file; its extension picks the format. Missing folders are created.
    :param points: (N, 3) or organized (H, W, 3) points (a .npy file keeps the organized shape,
        PLY and PCD store the points in row-major order).
    :return: the path written.
    :raises ValueError: for an unknown extension, no points, or points of the wrong shape.
    :raises OSError: when the file cannot be written.
    """
    file = Path(path)
    ext = _extension(file)
    array = np.asarray(points)
    flat = _as_xyz(array, 'save_cloud points')
    if len(flat) == 0:
        raise ValueError(f'save_cloud: no points to write to {file}')
    dtype = np.float32 if array.dtype == np.float32 else np.float64
    if ext == '.npy':
        with atomic_open(file, 'wb') as handle:
            np.save(handle, array.astype(dtype, copy=False), allow_pickle=False)
        return file
    import open3d as o3d  # only for PLY and PCD (see the module's docstring)

    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(np.ascontiguousarray(flat, dtype=dtype)))
    with atomic_path(file) as tmp:
        if not o3d.t.io.write_point_cloud(str(tmp), cloud, write_ascii=False):
            raise OSError(f'Open3D could not write {file}')
    return file
