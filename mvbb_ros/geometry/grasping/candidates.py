"""
The refinement's candidate grasp lines: each a point, an approach and a closing direction.

Each seed of :func:`~mvbb_ros.geometry.grasping.refine.refine_grasps` gives its own line
(through its face centre); each box gives lines closing along every box axis, approaching along
the other axes (the paper's faces and turns between them), from above and from the sensor, each
rolled a little and slid over its face. :func:`_feasible` keeps the allowed approaches (none from
below, none from the far side); :func:`_faces_and_rolls` gives a line's box face and roll, as the
paper's hypotheses have them. The rules: ``docs/grasp_rules.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

from mvbb_ros.arrays import BoolArray, cross, FloatArray, IndexArray
from mvbb_ros.geometry.box import Box
from mvbb_ros.geometry.grasping.hypotheses import FAR_SIDE_MARGIN_DEG, Grasp
from mvbb_ros.geometry.grasping.refinement_settings import GraspView
from mvbb_ros.geometry.grasping.surface import SurfaceModel
import numpy as np

#: Slides of the grasp centre over the face, as fractions of the face's extent across the pads.
SLIDES: tuple[float, ...] = (-0.3, -0.15, 0.0, 0.15, 0.3)
#: Approaches per closing axis, evenly turned about it from the next box axis (4: the faces).
APPROACHES_PER_AXIS = 12
#: Rolls of the closing direction about the approach, degrees.
ROLLS: tuple[float, ...] = (-20.0, 0.0, 20.0)


@dataclass
class _Candidates:
    """Candidate grasp lines, in batches: origins, approach and closing directions, box index."""

    origins: list[FloatArray] = field(default_factory=list)
    approaches: list[FloatArray] = field(default_factory=list)
    closings: list[FloatArray] = field(default_factory=list)
    boxes: list[IndexArray] = field(default_factory=list)

    def add(
        self, origins: FloatArray, approaches: FloatArray, closings: FloatArray, box: int
    ) -> None:
        """Add rows (broadcast to the origins' count)."""
        count = len(origins)
        self.origins.append(origins)
        self.approaches.append(np.broadcast_to(approaches, (count, 3)))
        self.closings.append(np.broadcast_to(closings, (count, 3)))
        self.boxes.append(np.full(count, box, dtype=np.intp))

    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, IndexArray]:
        """Return (origins, approaches, closings, boxes) as contiguous arrays."""
        if not self.origins:
            empty = np.zeros((0, 3))
            return empty, empty, empty, np.zeros(0, dtype=np.intp)
        return (
            np.ascontiguousarray(np.concatenate(self.origins)),
            np.ascontiguousarray(np.concatenate(self.approaches)),
            np.ascontiguousarray(np.concatenate(self.closings)),
            np.concatenate(self.boxes),
        )


def _unit_rows(vectors: FloatArray) -> FloatArray:
    norms = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors / np.where(norms > 0.0, norms, 1.0)


#: The turns of the approaches about each closing axis (cosine, sine), as columns.
_TURNS = np.deg2rad(np.arange(0.0, 360.0, 360.0 / APPROACHES_PER_AXIS))
_TURN_COS = np.array([math.cos(angle) for angle in _TURNS])[:, None]
_TURN_SIN = np.array([math.sin(angle) for angle in _TURNS])[:, None]


def _frames(
    box: Box, up: FloatArray | None, view: FloatArray | None
) -> tuple[FloatArray, FloatArray]:
    """
    Return the (approach, closing) pairs of one box, (P, 3) each: closing along each box axis.

    Approaches: along the other two axes, both senses (the paper's faces), then from above
    (against `up`) and along the viewing direction `view`, each made perpendicular to the
    closing axis (skipped when nearly parallel to it).
    """
    axes = box.rotation.T
    approaches = []
    closings = []
    for k in range(3):
        closing = axes[k]
        first, second = axes[(k + 1) % 3], axes[(k + 2) % 3]
        # Each turn's products and sum, element by element, as one vector at a time would.
        turned = _TURN_COS * first + _TURN_SIN * second
        approaches.append(turned)
        closings.append(np.broadcast_to(closing, turned.shape))
        for direction in (None if up is None else -up, view):
            if direction is None:
                continue
            flat = direction - (direction @ closing) * closing
            norm = float(np.linalg.norm(flat))
            if norm >= 0.3:
                approaches.append((flat / norm)[None, :])
                closings.append(closing[None, :])
    return np.concatenate(approaches), np.concatenate(closings)


def _box_candidates(
    boxes: Sequence[Box], up: FloatArray | None, views: Sequence[FloatArray | None], pad: float
) -> _Candidates:
    """Return every box's candidate lines: frames x rolls x slides across the pads."""
    out = _Candidates()
    rolls = np.deg2rad(np.array(ROLLS))
    slides = np.array(SLIDES)
    for index, box in enumerate(boxes):
        approaches, closings = _frames(box, up, views[index])  # (P, 3)
        sides = cross(approaches, closings)
        # (P, R, 3): each closing rolled about its approach, and the side axis of each roll.
        turned = (
            np.cos(rolls)[None, :, None] * closings[:, None, :]
            + np.sin(rolls)[None, :, None] * sides[:, None, :]
        )
        across = cross(approaches[:, None, :], turned)
        reach = np.abs(across @ box.rotation) @ box.extents  # (P, R) extent across the pads
        offsets = slides * np.maximum(reach - pad, 0.0)[:, :, None]  # (P, R, S)
        origins = box.center + offsets[..., None] * across[:, :, None, :]  # (P, R, S, 3)
        count = origins.shape[1] * origins.shape[2]
        out.add(
            origins.reshape(-1, 3),
            np.repeat(approaches, count, axis=0),
            np.repeat(turned.reshape(-1, 3), len(slides), axis=0),
            index,
        )
    return out


def _seed_candidates(seeds: Sequence[Grasp], boxes: Sequence[Box], pad: float) -> _Candidates:
    """Return the seeds' own lines (through their face centres), one sense per closing line."""
    out = _Candidates()
    for seed in seeds:
        if seed.roll_deg >= 180:  # the half turn closes on the same line
            continue
        box = boxes[seed.box_index]
        out.add(box.center[None, :], seed.approach, seed.closing, seed.box_index)
    return out


def _feasible(
    approaches: FloatArray, objects: IndexArray, models: Sequence[SurfaceModel], view: GraspView
) -> BoolArray:
    """Tell which approaches are allowed: not from below (with up), not from the far side."""
    keep = np.ones(len(approaches), dtype=bool)
    if view.up is not None:
        limit = math.sin(math.radians(view.max_approach_elevation_deg))
        keep &= approaches @ view.up <= limit + 1e-12
    if not view.far_side and view.viewpoint is not None:
        centers = np.array([model.center for model in models])[objects]
        sight = _unit_rows(centers - view.viewpoint)
        margin = math.sin(math.radians(FAR_SIDE_MARGIN_DEG))
        keep &= np.einsum('ij,ij->i', approaches, sight) >= margin
    return keep


def _faces_and_rolls(
    boxes: Sequence[Box], box_index: IndexArray, approaches: FloatArray, closings: FloatArray
) -> tuple[IndexArray, IndexArray]:
    """Return each line's box face most opposed to its approach and its closing's roll (deg)."""
    faces = np.zeros(len(box_index), dtype=np.intp)
    rolls = np.zeros(len(box_index), dtype=np.intp)
    for number in np.unique(box_index):
        mine = np.flatnonzero(box_index == number)
        box = boxes[int(number)]
        normals = box.face_normals()
        face = np.argmin(approaches[mine] @ normals.T, axis=1)
        edges = box.rotation[:, (face // 2 + 1) % 3].T  # (M, 3)
        turned = cross(-normals[face], edges)
        angle = np.degrees(
            np.arctan2(
                np.einsum('ij,ij->i', closings[mine], turned),
                np.einsum('ij,ij->i', closings[mine], edges),
            )
        )
        faces[mine] = face
        rolls[mine] = np.round(angle).astype(np.intp) % 360
    return faces, rolls
