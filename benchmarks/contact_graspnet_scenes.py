"""
Contact-GraspNet on its example scenes: do its grasps land on the objects, which frame, how fast.

    tools/cgn/make_venv.sh                                  # once: .venv-cgn
    .venv/bin/python benchmarks/contact_graspnet_scenes.py  # 8 minutes here, other jobs running
    .venv/bin/python benchmarks/contact_graspnet_scenes.py --top 10 --json out/cgn_scenes.json

cgn-pytorch ships three cluttered tabletop scenes (``cgn_pytorch/scenes/*.npz``, rendered from
ACRONYM): each holds two clouds of 20,000 points in a z-up world frame with its mean subtracted,
a mask of the target object's points in the first cloud, that mean, and the camera's pose (OpenGL
axes: it looks along its -z). Each scene is run through :class:`ContactGraspNet` (the adapter the
physics benchmark uses, so the pose conversion is exercised too) four ways:

- ``world+object``: the z-up cloud as shipped, with the object's points (the local region);
- ``world``: the same cloud, no object given (grasps anywhere in the scene);
- ``camera+object``: the same points and object in the camera's frame (OpenCV axes: x right,
  y down, z forward), the poses mapped back to the world frame before they are judged;
- ``object only``: the object's points alone (a segmented view without the table), z-up.

A grasp *lands on the object* when the point between its fingertips (our pose's origin) lies
within ``--near`` (2 cm) of one of the object's points; it *encloses* the object when at least
five object points lie between the open Panda pads (8 cm apart, 1.8 cm square). Also counted:
grasps approaching
downwards (approach z < 0 in the world frame) and from the camera's side (approach pointing away
from the camera, as a hand reaching past what the camera sees would). Time: the server's wall
and CPU seconds per view, median over fifteen views (the four runs above plus the second cloud
of each scene without an object), once with one torch thread and once with torch's default.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import statistics
import sys

from mvbb_ros.common.atomic import atomic_open
from mvbb_ros.evaluation.physics.contact_graspnet import (
    ContactGraspNet,
    ContactGraspNetUnavailable,
    DEFAULT_PYTHON,
)
import numpy as np
from scipy.spatial import cKDTree

#: OpenGL camera axes (x right, y up, looking along -z) to OpenCV ones (y down, z forward).
GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])
#: The Panda hand's opening and half its pad size, metres; object points between the open pads.
OPENING_M, PAD_HALF_M, ENCLOSED_POINTS = 0.08, 0.009, 5


def example_scenes(python: Path) -> list[Path]:
    """Return the .npz scenes of the cgn_pytorch installed beside `python`."""
    lib = python.parent.parent / 'lib'
    return sorted(lib.glob('python*/site-packages/cgn_pytorch/scenes/*.npz'))


def load_scene(path: Path) -> dict[str, np.ndarray]:
    """Both clouds, the object mask of the first, and world-from-camera (OpenCV axes, centred)."""
    with np.load(path) as data:  # arr_5 (labels, pickled) is never read
        clouds, mask = data['arr_0'].astype(np.float64), data['arr_2'][:, 0].astype(bool)
        mean, camera_gl = data['arr_3'], data['arr_4']
    world_from_camera = camera_gl @ GL_TO_CV
    world_from_camera[:3, 3] -= mean  # the clouds are the world minus their mean
    return {'clouds': clouds, 'mask': mask, 'world_from_camera': world_from_camera}


def transform(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def encloses(pose: np.ndarray, target: np.ndarray) -> bool:
    """Whether object points lie between the open Panda fingers' pads (our pose convention)."""
    local = (target - pose[:3, 3]) @ pose[:3, :3]
    between = (
        (np.abs(local[:, 0]) <= PAD_HALF_M)
        & (np.abs(local[:, 1]) <= OPENING_M / 2.0)
        & (np.abs(local[:, 2]) <= PAD_HALF_M)
    )
    return int(np.count_nonzero(between)) >= ENCLOSED_POINTS


def judge(poses: np.ndarray, target: np.ndarray, camera: np.ndarray, near_m: float) -> dict:
    """Fractions of grasps (world frame) on the object, approaching downwards, from the camera."""
    if not len(poses):
        return {'grasps': 0, 'on_object': None, 'downwards': None, 'camera_side': None}
    centres, approach = poses[:, :3, 3], poses[:, :3, 2]
    distance, _ = cKDTree(target).query(centres)
    sight = centres - camera
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    return {
        'grasps': len(poses),
        'on_object': float(np.mean(distance <= near_m)),
        'encloses': float(np.mean([encloses(pose, target) for pose in poses])),
        'downwards': float(np.mean(approach[:, 2] < 0.0)),
        'camera_side': float(np.mean(np.sum(approach * sight, axis=1) > 0.0)),
        'median_distance_m': float(np.median(distance)),
    }


def run(cgn: ContactGraspNet, scenes: list[Path], top: int, near_m: float) -> tuple[dict, list]:
    """Judge the three runs of every scene; return the verdicts and the per-view timings."""
    verdicts: dict[str, dict] = {}
    timings = []
    for path in scenes:
        scene = load_scene(path)
        cloud, second = scene['clouds'][0], scene['clouds'][1]
        target = cloud[scene['mask']]
        to_world = scene['world_from_camera']
        to_camera = np.linalg.inv(to_world)
        camera = to_world[:3, 3]
        runs = {
            'world+object': (cloud, target, np.eye(4)),
            'world': (cloud, None, np.eye(4)),
            'camera+object': (transform(to_camera, cloud), transform(to_camera, target), to_world),
            'object only': (target, target, np.eye(4)),
        }
        for name, (points, obj, back) in runs.items():
            proposals = cgn.grasps(points, obj, max_grasps=top)
            timings.append(cgn.last_answer)
            poses = np.array([back @ p.pose for p in proposals]).reshape(-1, 4, 4)
            verdict = judge(poses, target, camera, near_m)
            verdict['top1_on_object'] = None if not len(poses) else verdict_on(poses[:1], target)
            verdicts.setdefault(name, {})[path.stem] = verdict
        cgn.grasps(second, None, max_grasps=top)
        timings.append(cgn.last_answer)
    return verdicts, timings


def verdict_on(poses: np.ndarray, target: np.ndarray, near_m: float = 0.02) -> bool:
    distance, _ = cKDTree(target).query(poses[:, :3, 3])
    return bool(np.all(distance <= near_m))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--python', type=Path, default=DEFAULT_PYTHON)
    parser.add_argument('--top', type=int, default=10, help='grasps judged per view')
    parser.add_argument('--near', type=float, default=0.02, help='metres: on the object')
    parser.add_argument('--json', type=Path, help='write the figures here')
    args = parser.parse_args(argv)
    scenes = example_scenes(args.python)
    if not scenes:
        print(
            f'no example scenes beside {args.python}: run tools/cgn/make_venv.sh', file=sys.stderr
        )
        return 1
    record: dict = {'scenes': [p.stem for p in scenes], 'top': args.top, 'near_m': args.near}
    for label, threads in (('default threads', None), ('1 thread', 1)):
        try:
            with ContactGraspNet(args.python, threads=threads) as cgn:
                verdicts, timings = run(cgn, scenes, args.top, args.near)
        except ContactGraspNetUnavailable as error:
            print(error, file=sys.stderr)
            return 1
        record.setdefault('verdicts', verdicts)
        wall = [t['seconds'] for t in timings]
        cpu = [t['cpu_seconds'] for t in timings]
        record.setdefault('timing', {})[label] = {
            'views': len(wall),
            'median_s': statistics.median(wall),
            'max_s': max(wall),
            'median_cpu_s': statistics.median(cpu),
        }
    print(f'top {args.top} grasps a view; on obj: fingertip centre within {args.near} m of it;')
    print('encl: object points between the open pads; down: approach z < 0; cam: from its side')
    print(
        f'{"run":15} {"scene":7} {"grasps":>6} {"on obj":>6} {"encl":>5} {"top-1":>5} '
        f'{"down":>5} {"cam":>5}'
    )
    for name, per_scene in record['verdicts'].items():
        for stem, v in per_scene.items():
            if not v['grasps']:
                print(f'{name:15} {stem:7} {0:6}')
                continue
            print(
                f'{name:15} {stem:7} {v["grasps"]:6} {v["on_object"]:6.2f} {v["encloses"]:5.2f} '
                f'{"yes" if v["top1_on_object"] else "no":>5} {v["downwards"]:5.2f} '
                f'{v["camera_side"]:5.2f}'
            )
    for label, t in record['timing'].items():
        print(
            f'{label}: median {t["median_s"]:.2f} s a view (max {t["max_s"]:.2f}), '
            f'median CPU {t["median_cpu_s"]:.2f} s, {t["views"]} views'
        )
    if args.json:
        with atomic_open(args.json) as stream:
            json.dump(record, stream, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
