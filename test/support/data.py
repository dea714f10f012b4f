"""
The repository's paths and the shared real data: where it lives, how to skip clearly without it.

The clouds the filter tests share (real scans, an organized frame, organized scenes, lidar
sweeps) are here too; each skips with its reason where its data or the library that reads it
is absent.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
import sys
from types import ModuleType

from mvbb_ros.evaluation.shared_data import missing, shared_data_folder
import numpy as np
import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]


def load_benchmark(name: str) -> ModuleType:
    """Import ``benchmarks/<name>.py`` (a script, not a package module) for its tests."""
    spec = importlib.util.spec_from_file_location(
        f'{name}_bench', REPO_ROOT / f'benchmarks/{name}.py'
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


#: The shared real data (models, scans, bags): :func:`shared_data_folder`'s rule.
SHARED_DATA = shared_data_folder(REPO_ROOT)


def require_shared_data(*relative: str) -> Path:
    """Return SHARED_DATA / relative, or skip the test with a message saying what is missing."""
    path = SHARED_DATA.joinpath(*relative)
    reason = missing(path)
    if reason is not None:
        pytest.skip(reason)
    return path


# Clouds for the filter tests (test_filtering.py, test_outliers.py): real scans, an organized
# frame, organized scenes and lidar sweeps. Each skips with its reason where its data or the
# library that reads it is absent (the numba 0.59 venv of `make compat` has no Open3D, rclpy or
# rosbags).


def scan_paths() -> list[Path]:
    """Return every real scan of the shared data; skip when there is none."""
    paths = sorted((SHARED_DATA / 'scans').glob('*.npy'))
    if not paths:
        pytest.skip(f'shared scans not found in {SHARED_DATA / "scans"}')
    return paths


def organized_frame(points: int = 300_000, seed: int = 0) -> np.ndarray:
    """Render the package's synthetic organized frame (H, W, 3), NaN off the object."""
    pytest.importorskip('open3d', reason='the frame is rendered with Open3D')
    from mvbb_ros.evaluation.synthetic import organized_frame as render

    return render(points, seed=seed)


def scene_grid(name: str) -> np.ndarray:
    """Read an organized scene of the shared data as an (H, W, 3) float32 grid (NaN kept)."""
    o3d = pytest.importorskip('open3d', reason='the scenes are read with Open3D')
    path = require_shared_data('scenes', name)
    cloud = o3d.io.read_point_cloud(
        str(path), remove_nan_points=False, remove_infinite_points=False
    )
    return np.asarray(cloud.points, dtype=np.float32).reshape(480, 640, 3)


def lidar_clouds() -> list[np.ndarray]:
    """Decode every cloud of the shared ROS 2 lidar bag (about 250 m wide) to (N, 3) arrays."""
    highlevel = pytest.importorskip('rosbags.highlevel', reason='the bag is read with rosbags')
    from mvbb_ros.pipeline.decode import read_points

    path = require_shared_data('bags', 'embag_luminar_lidar_ros2')
    clouds = []
    with highlevel.AnyReader([path]) as reader:
        for connection, _, raw in reader.messages():
            if connection.msgtype == 'sensor_msgs/msg/PointCloud2':
                clouds.append(read_points(reader.deserialize(raw, connection.msgtype)))
    return clouds
