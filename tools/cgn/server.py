"""
Contact-GraspNet over stdin/stdout: load cgn-pytorch's model once, answer one JSON line a request.

Runs under .venv-cgn/bin/python (made by tools/cgn/make_venv.sh), never under the project's .venv;
mvbb_ros.evaluation.physics.contact_graspnet starts it and speaks for it, so that a benchmark pays
the model load once, not once a view.

Protocol, one JSON object a line:

- at start, once the model is loaded: ``{"ready": true, "torch": VERSION, "threads": N}``;
- a request: ``{"points": "IN.npz", "out": "OUT.npz", "max_grasps": 100, "min_score": 0.5,
  "seed": 0}``; IN.npz holds ``scene`` (N, 3) and optionally ``object`` (M, 3), metres, in a
  z-up world frame (the frame the model was trained in: table top horizontal, up = +z);
- its answer: ``{"ok": true, "out": "OUT.npz", "grasps": K, "seconds": S, "cpu_seconds": C}`` or
  ``{"ok": false, "error": "..."}``. OUT.npz (written atomically) holds, best first,
  ``transforms`` (K, 4, 4): cgn-pytorch's grasp transforms in the input frame (Panda hand base
  frame: fingers close along x, approach along z, the contact point 0.1034 m along z from the
  origin); ``widths`` (K,) metres; ``scores`` (K,) in [0, 1]; ``contacts`` (K, 3) the contact
  point on the finger the network predicted from;
- ``{"quit": true}`` or the end of stdin stops it.

What is done to a request, as the package's README and example scenes prescribe: with an object,
the scene is cut to a cube around the object (side twice the object's longest extent, between 0.3
and 0.6 m: the network's local region) and the object's points are marked, so that only grasps
whose contact lies on the object count; at most 20,000 points, in a seeded random order (as the
example scenes are: a full ball query keeps its lowest indices); the mean is subtracted (the
scenes it was trained on are centred); farthest point sampling picks the 2,048
points the network predicts grasps for; the confidences pass a sigmoid; the grasps above
``min_score`` are returned best first. torch and numpy are seeded with the request's seed before
each request, so the same request gives the same answer whatever came before it.
"""

import argparse
import contextlib
import io
import json
import os
from pathlib import Path
import sys
import tempfile
import time
from typing import Any
import warnings

import numpy as np

MAX_POINTS = 20000  # what the network was trained on
CENTRES = 2048  # points the network predicts a grasp for
REGION_SIDE_M = (0.3, 0.6)  # the cube cut around an object: its side's bounds, metres
SAME_POINT_M = 0.002  # a scene point this close to an object point is that object point
GRIPPER_DEPTH_M = 0.1034  # Panda hand base to the finger pads' centre: where contacts are put
GRIPPER_WIDTH_M = 0.16  # forward()'s default, which clamps widths to 0.08 m (the Panda's opening)


def _region(scene: np.ndarray, obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scene points in the cube around the object, then the object's; and the object mask."""
    from scipy.spatial import cKDTree

    low, high = obj.min(0), obj.max(0)
    half = float(np.clip(2.0 * np.max(high - low), *REGION_SIDE_M)) / 2.0
    centre = (low + high) / 2.0
    inside = np.all(np.abs(scene - centre) <= half, axis=1)
    rest = scene[inside]
    if len(rest):
        distance, _ = cKDTree(obj).query(rest, k=1)
        rest = rest[distance > SAME_POINT_M]
    cloud = np.concatenate([rest, obj])
    mask = np.concatenate([np.zeros(len(rest), bool), np.ones(len(obj), bool)])
    return cloud, mask


def _load_model(threads: int | None) -> Any:
    """Load cgn-pytorch's pretrained model on the CPU, in eval mode."""
    import torch

    if threads:
        torch.set_num_threads(threads)
    warnings.simplefilter('ignore')
    import cgn_pytorch

    with contextlib.redirect_stdout(io.StringIO()):
        model, _, _ = cgn_pytorch.from_pretrained(device='cpu')
    model.eval()
    return model


def predict(
    model: Any,
    scene: np.ndarray,
    obj: np.ndarray | None,
    max_grasps: int,
    min_score: float,
    seed: int,
) -> dict[str, np.ndarray]:
    """Grasps for one view: transforms, widths, scores, contacts (input frame), best first."""
    import torch
    from torch_geometric.nn import fps

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    scene = np.asarray(scene, dtype=np.float64).reshape(-1, 3)
    scene = scene[np.all(np.isfinite(scene), axis=1)]
    if obj is not None:
        obj = np.asarray(obj, dtype=np.float64).reshape(-1, 3)
        obj = obj[np.all(np.isfinite(obj), axis=1)]
        if not len(obj):
            raise ValueError('the object has no finite points')
        cloud, mask = _region(scene, obj)
    else:
        cloud, mask = scene, np.ones(len(scene), bool)
    if len(cloud) < 4:
        raise ValueError(f'{len(cloud)} finite points: too few to grasp from')
    # A seeded random order, at most MAX_POINTS: the training scenes (and the shipped examples)
    # are in random order, and the ball queries keep the lowest indices when a ball is full, so
    # an ordered cloud (image rows, or the scene before the object) would bias every feature.
    keep = rng.permutation(len(cloud))[:MAX_POINTS]
    cloud, mask = cloud[keep], mask[keep]
    mean = cloud.mean(axis=0)
    pos = torch.from_numpy((cloud - mean).astype(np.float32))
    batch = torch.zeros(len(pos), dtype=torch.long)
    with torch.no_grad():
        idx = fps(pos, batch, ratio=min(1.0, CENTRES / len(pos)))
        points, grasps, logits, widths, _, _ = model(
            pos[:, 3:],
            pcd_poses=pos,
            batch=batch,
            idxs=idx,
            gripper_depth=GRIPPER_DEPTH_M,
            gripper_width=GRIPPER_WIDTH_M,
        )
    scores = torch.sigmoid(logits).reshape(-1).numpy().astype(np.float64)
    scores = scores * mask[idx.numpy()]
    transforms = grasps.reshape(-1, 4, 4).numpy().astype(np.float64)
    finite = np.isfinite(scores) & np.all(np.isfinite(transforms), axis=(1, 2))
    order = np.argsort(-np.where(finite, scores, -np.inf), kind='stable')
    order = order[finite[order] & (scores[order] > min_score)][: max(0, int(max_grasps))]
    transforms = transforms[order]
    transforms[:, :3, 3] += mean
    return {
        'transforms': transforms,
        'widths': widths.reshape(-1).numpy().astype(np.float64)[order],
        'scores': scores[order],
        'contacts': points.reshape(-1, 3).numpy().astype(np.float64)[order] + mean,
    }


def _save(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write an .npz so that a reader never sees half of it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.npz', dir=path.parent)
    try:
        with os.fdopen(handle, 'wb') as stream:
            np.savez(stream, **arrays)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def _answer(model: Any, request: dict[str, Any]) -> dict[str, Any]:
    start, cpu_start = time.perf_counter(), time.process_time()
    with np.load(request['points']) as data:
        scene = data['scene']
        obj = data['object'] if 'object' in data.files else None
    result = predict(
        model,
        scene,
        obj,
        max_grasps=int(request.get('max_grasps', 100)),
        min_score=float(request.get('min_score', 0.5)),
        seed=int(request.get('seed', 0)),
    )
    _save(Path(request['out']), result)
    return {
        'ok': True,
        'out': request['out'],
        'grasps': len(result['scores']),
        'seconds': time.perf_counter() - start,
        'cpu_seconds': time.process_time() - cpu_start,
    }


def main(argv: list[str] | None = None) -> int:
    """Serve requests from stdin until it ends or a quit line comes."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--threads', type=int, default=0, help='torch threads (0: its default)')
    args = parser.parse_args(argv)
    # The protocol owns stdout; anything the libraries print goes to stderr instead.
    protocol = os.fdopen(os.dup(1), 'w', buffering=1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    model = _load_model(args.threads or None)
    # One throw-away view: torch_geometric compiles its message-passing code on first use, which
    # would otherwise be charged to the first real view.
    predict(model, np.random.default_rng(0).uniform(-0.1, 0.1, (3000, 3)), None, 1, 0.0, 0)
    import torch

    ready = {'ready': True, 'torch': torch.__version__, 'threads': torch.get_num_threads()}
    protocol.write(json.dumps(ready) + '\n')
    for line in sys.stdin:
        if not line.strip():
            continue
        try:
            request = json.loads(line)
            if request.get('quit'):
                break
            reply = _answer(model, request)
        except Exception as error:  # a bad request is answered, not fatal
            reply = {'ok': False, 'error': f'{type(error).__name__}: {error}'}
        protocol.write(json.dumps(reply, allow_nan=False) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
