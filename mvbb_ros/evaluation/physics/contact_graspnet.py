"""
Contact-GraspNet as a grasp contender, run in its own virtual environment (issue 36).

The network (``cgn-pytorch`` 0.4.3, a PyTorch port of Sundermeyer et al., ICRA 2021, with its
checkpoint in the wheel) lives in ``.venv-cgn/`` at the repository root, made by
``tools/cgn/make_venv.sh``; torch never enters this package or its requirements. A
:class:`ContactGraspNet` starts ``tools/cgn/server.py`` under that environment's Python once,
then sends it one view at a time through files (``.npz``) and JSON lines, so the model is loaded
once per benchmark, not once per view. How it was checked: ``docs/contact_graspnet.md``.

Input frame: points in metres, z-up world frame (the table top horizontal, up = +z), as in the
scenes the network was trained on and ships as examples; fed a camera-frame cloud it may propose
grasps from behind the object or from below the table.

Pose conversion. cgn-pytorch's grasp transform ``T`` is the Franka (Panda) hand's base frame:
its z axis is the approach (palm towards the object), its x axis the closing direction (the
fingers sit at +-x), y = z x x, and the contact point lies ``CONTACT_DEPTH_M`` = 0.1034 m along
z from its origin (the centre of the finger pads; the fingertips end 0.0088 m further). The
network builds ``T`` from a contact point c on one finger, the baseline (closing) unit vector b,
the approach a and the predicted width w as ``R = [b, a x b, a]``, ``t = c + (w / 2) b - 0.1034
a``. Our grasp pose ``P`` (:func:`cgn_to_grasp_pose`) has its origin between the fingertips,
``t + 0.1034 a``, z = approach a, y = closing direction b, x = y x z = b x a = -(a x b): the
columns of P's rotation are (-y_T, x_T, z_T), i.e. ``R_P = R_T @ Rz(-90 deg)``.
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import os
from pathlib import Path
import select
import shutil
import subprocess
import tempfile
from types import TracebackType
from typing import Any, NoReturn

import numpy as np
import numpy.typing as npt

REPO_ROOT = Path(__file__).resolve().parents[3]
#: The Python of the environment tools/cgn/make_venv.sh makes.
DEFAULT_PYTHON = REPO_ROOT / '.venv-cgn' / 'bin' / 'python'
#: The server that runs inside that environment.
SERVER = REPO_ROOT / 'tools' / 'cgn' / 'server.py'
#: Panda hand base frame to the centre of the finger pads along the approach, metres: where
#: cgn-pytorch puts the contact point, and where our grasp pose has its origin.
CONTACT_DEPTH_M = 0.1034
#: Our rotation = cgn-pytorch's rotation @ this (a turn of -90 degrees about the approach):
#: x_ours = -y_cgn, y_ours = x_cgn, z_ours = z_cgn.
CGN_TO_OURS = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


class ContactGraspNetUnavailable(RuntimeError):  # noqa: N818 (the name the benchmark uses)
    """The Contact-GraspNet environment is missing or its server cannot start or answer."""


@dataclass(frozen=True)
class Proposal:
    """
    One grasp proposed by Contact-GraspNet, in our convention.

    :ivar pose: 4x4 in the input's (world) frame: origin between the fingertips, z = approach
        (palm towards the object), y = closing direction, x = y x z; metres.
    :ivar width: the opening the network predicted, metres (0 to 0.08).
    :ivar score: the network's confidence that the grasp succeeds, 0 to 1.
    """

    pose: npt.NDArray[np.float64]
    width: float
    score: float


def cgn_to_grasp_pose(
    transforms: npt.ArrayLike, contact_depth_m: float = CONTACT_DEPTH_M
) -> npt.NDArray[np.float64]:
    """Convert cgn-pytorch grasp transforms (..., 4, 4) to our grasp poses (module docstring)."""
    t = np.asarray(transforms, dtype=np.float64)
    if t.shape[-2:] != (4, 4):
        raise ValueError(f'grasp transforms must be (..., 4, 4), not {t.shape}')
    pose = np.zeros_like(t)
    pose[..., :3, :3] = t[..., :3, :3] @ CGN_TO_OURS
    pose[..., :3, 3] = t[..., :3, 3] + contact_depth_m * t[..., :3, 2]
    pose[..., 3, 3] = 1.0
    return pose


def grasp_pose_to_cgn(
    poses: npt.ArrayLike, contact_depth_m: float = CONTACT_DEPTH_M
) -> npt.NDArray[np.float64]:
    """Convert our grasp poses (..., 4, 4) to cgn-pytorch grasp transforms: the inverse."""
    p = np.asarray(poses, dtype=np.float64)
    if p.shape[-2:] != (4, 4):
        raise ValueError(f'grasp poses must be (..., 4, 4), not {p.shape}')
    t = np.zeros_like(p)
    t[..., :3, :3] = p[..., :3, :3] @ CGN_TO_OURS.T
    t[..., :3, 3] = p[..., :3, 3] - contact_depth_m * p[..., :3, 2]
    t[..., 3, 3] = 1.0
    return t


def _points(name: str, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    array = np.array(points, dtype=np.float64)  # a copy: the caller's array is never touched
    if array.ndim != 2 or array.shape[1] != 3:
        raise ValueError(f'{name} must be (N, 3) metres, not {array.shape}')
    if not np.all(np.isfinite(array)):
        raise ValueError(f'{name} holds non-finite values')
    return array


class ContactGraspNet:
    """
    Contact-GraspNet's grasps for point clouds, from a server in ``.venv-cgn`` (context manager).

    The server starts on entering the context (or on the first :meth:`grasps`) and stops on
    :meth:`close`. Each view is seeded with ``seed``, so the same view gives the same grasps.
    """

    def __init__(
        self,
        python: Path | None = None,
        *,
        threads: int | None = None,
        seed: int = 0,
        min_score: float = 0.5,
        start_timeout_s: float = 600.0,
        answer_timeout_s: float = 600.0,
    ) -> None:
        """
        Find the environment; raise :class:`ContactGraspNetUnavailable` when it is missing.

        :param python: the environment's Python (default ``<repo>/.venv-cgn/bin/python``).
        :param threads: torch threads in the server (None: torch's default).
        :param seed: seeds torch and numpy before each view.
        :param min_score: grasps scoring at or below this are dropped (0.5, as cgn-pytorch does).
        """
        self.python = Path(python) if python is not None else DEFAULT_PYTHON
        if not self.python.exists():
            raise ContactGraspNetUnavailable(
                f'no Contact-GraspNet environment at {self.python}: run tools/cgn/make_venv.sh '
                'to make .venv-cgn (torch CPU and cgn-pytorch, apart from the project .venv)'
            )
        if not SERVER.exists():
            raise ContactGraspNetUnavailable(f'the server {SERVER} is missing from this checkout')
        self.threads = threads
        self.seed = seed
        self.min_score = min_score
        self.start_timeout_s = start_timeout_s
        self.answer_timeout_s = answer_timeout_s
        #: The server's last answer: grasps found, seconds and CPU seconds it spent on the view.
        self.last_answer: dict[str, Any] | None = None
        self._process: subprocess.Popen[str] | None = None
        self._workdir: Path | None = None
        self._count = 0

    def __enter__(self) -> ContactGraspNet:
        """Start the server (loads the model once)."""
        self.start()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Stop the server."""
        self.close()

    def start(self) -> None:
        """Start the server and wait until it has loaded the model; no-op when running."""
        if self._process is not None:
            return
        self._workdir = Path(tempfile.mkdtemp(prefix='mvbb-cgn-'))
        env = {k: v for k, v in os.environ.items() if k not in ('PYTHONPATH', 'PYTHONHOME')}
        command = [str(self.python), str(SERVER), '--threads', str(self.threads or 0)]
        with open(self._workdir / 'server.log', 'w') as log:
            self._process = subprocess.Popen(
                command,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=log,
                text=True,
                env=env,
            )
        ready = self._read_line(self.start_timeout_s, 'start')
        if not ready.get('ready'):
            self._fail(f'the server did not say it was ready: {ready}')

    def close(self) -> None:
        """Stop the server and remove its files."""
        process, self._process = self._process, None
        if process is not None:
            try:
                if process.stdin is not None:
                    process.stdin.write(json.dumps({'quit': True}) + '\n')
                    process.stdin.close()
                process.wait(timeout=10)
            except (OSError, subprocess.TimeoutExpired):
                process.kill()
                process.wait()
            if process.stdout is not None:
                process.stdout.close()
        if self._workdir is not None:
            shutil.rmtree(self._workdir, ignore_errors=True)
            self._workdir = None

    def grasps(
        self,
        scene_points: npt.ArrayLike,
        object_points: npt.ArrayLike | None = None,
        max_grasps: int = 100,
    ) -> list[Proposal]:
        """
        Grasps for one view, best first (at most `max_grasps`, those above `min_score`).

        :param scene_points: (N, 3) metres, z-up world frame (table top at z = 0).
        :param object_points: (M, 3) the segmented object, same frame; when given, the scene is
            cut to a region around it and only grasps whose contact lies on it are returned.
        :return: poses in our convention (module docstring), widths, scores.
        """
        scene = _points('scene_points', scene_points)
        target = None if object_points is None else _points('object_points', object_points)
        self.start()
        assert self._workdir is not None and self._process is not None
        self._count += 1
        request_path = self._workdir / f'view{self._count}.npz'
        answer_path = self._workdir / f'grasps{self._count}.npz'
        if target is None:
            np.savez(request_path, scene=scene)
        else:
            np.savez(request_path, scene=scene, object=target)
        request = {
            'points': str(request_path),
            'out': str(answer_path),
            'max_grasps': int(max_grasps),
            'min_score': float(self.min_score),
            'seed': int(self.seed),
        }
        try:
            assert self._process.stdin is not None
            self._process.stdin.write(json.dumps(request) + '\n')
            self._process.stdin.flush()
        except OSError:
            self._fail('the server stopped taking requests')
        answer = self._read_line(self.answer_timeout_s, 'answer')
        request_path.unlink(missing_ok=True)
        if not answer.get('ok'):
            raise ValueError(f'Contact-GraspNet refused the view: {answer.get("error")}')
        self.last_answer = answer
        with np.load(answer_path) as data:
            poses = cgn_to_grasp_pose(data['transforms'])
            widths, scores = data['widths'], data['scores']
        answer_path.unlink(missing_ok=True)
        return [
            Proposal(pose=pose, width=float(width), score=float(score))
            for pose, width, score in zip(poses, widths, scores, strict=True)
        ]

    def _read_line(self, timeout_s: float, stage: str) -> dict[str, Any]:
        """Read the server's next JSON line, failing clearly if it dies or says nothing."""
        assert self._process is not None and self._process.stdout is not None
        ready, _, _ = select.select([self._process.stdout], [], [], timeout_s)
        if not ready:
            self._fail(f'the Contact-GraspNet server was silent {timeout_s:.0f} s at {stage}')
        line = self._process.stdout.readline()
        if not line:  # end of its output: it has exited or is exiting
            self._fail(f'the Contact-GraspNet server exited at {stage}')
        try:
            parsed: dict[str, Any] = json.loads(line)
        except json.JSONDecodeError:
            self._fail(f'the server wrote a line that is not JSON: {line[:200]!r}')
        return parsed

    def _fail(self, message: str) -> NoReturn:
        log = ''
        if self._workdir is not None and (self._workdir / 'server.log').exists():
            lines = (self._workdir / 'server.log').read_text(errors='replace').splitlines()
            log = '\n'.join(lines[-15:])
        self.close()
        raise ContactGraspNetUnavailable(f'{message}; its log ends:\n{log}')
