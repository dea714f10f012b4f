"""
Does a parallel-jaw grasp hold on the whole object? A pad gripper closing on the mesh.

Issue 16's judge of grasps from single views, on the object's complete mesh (ray casting on
:class:`~mvbb_ros.evaluation.mesh.GraspTarget`). A grasp (``position``, ``approach``,
``closing``) is tried with a :class:`PadGripper`: two square pads (2 x 2 cm), ``max_width``
apart when open, facing each other across the closing axis. For each finger depth d in
:data:`FINGER_DEPTHS` (0.5 to 3 cm):

1. **Approach.** The hand comes along ``approach`` through ``position`` from outside the
   object (from the object's bounding sphere, so a pre-grasp pose that a box put inside the
   object does not matter: the line and the directions define the grasp). Rays along
   ``approach`` from the area between the pads (``max_width`` by the pad width) give the first
   contact h; no hit: ``'missed'``. The fingertips stop d past it.
2. **Support.** With a support plane (the table), every pad corner must stay above it both at
   the pre-grasp pose (the pads' tips at ``position``) and at the final pose: a hand that would
   go through the table fails (``'support'``).
3. **Fingers.** Rays along ``approach`` from each pad's tip edge: a finger meeting the object
   before the tips reach h + d collides with it (``'collision'``).
4. **Close.** Each pad moves along the closing axis towards the other, sampled by a grid of
   rays over its face (the pad is the last 2 cm of the finger) until it touches; the rays that
   touch within 0.5 mm of the first (a soft pad's give) are its contact patch, whose centroid
   and mean triangle normal are the pad's contact. Both pads must touch within the opening
   (contacts not crossing): else ``'no_contact'``.
5. **Friction.** The line between the two contacts must lie inside both friction cones (mu 0.5;
   :func:`~mvbb_ros.evaluation.wrench.line_in_friction_cones`), else ``'slips'``.

The grasp holds when some depth passes all five. Its status is the furthest step any depth
reached, in the order above (``'holds'`` last).

:func:`same_grasp` tells whether two grasps are the same to a robot (within 1 cm and 15 degrees,
a half turn about the approach counted as the same), for the steadiness of the top grasp over
frames.

Lengths in the mesh's units (metres for the benchmark). Written for this project from the
definitions above; nothing is taken from grasp libraries.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import Any

from mvbb_ros.arrays import BoolArray, FloatArray
from mvbb_ros.evaluation.gripper import ParallelJawGripper
from mvbb_ros.evaluation.mesh import GraspTarget
from mvbb_ros.evaluation.simulation import evaluate_grasps, grasp_axes
from mvbb_ros.evaluation.wrench import DEFAULT_FRICTION, line_in_friction_cones, unit_rows
import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Pad size (square, along the approach and across it), metres.
PAD_SIZE = 0.02
#: Finger depths tried past the first contact, metres (0.5 to 3 cm).
FINGER_DEPTHS: tuple[float, ...] = (0.005, 0.01, 0.015, 0.02, 0.025, 0.03)
#: A pad's contact patch: its rays that touch within this of its first touch (a soft pad's
#: give), metres; the patch's centroid and mean normal are the pad's contact.
PAD_COMPLIANCE = 0.0005
#: How far below the support plane a pad may reach (numerical slack), metres.
SUPPORT_SLACK = 0.001

#: Finger depth of the existing simulator's gripper in :func:`simulated_epsilon`, metres: it
#: closes at half of it below the palm's contact, 2 cm, within the judge's depths.
SIMULATOR_FINGER_DEPTH = 0.04

#: Outcomes, in the order the judge's steps reach them; :attr:`Verdicts.status` indexes this.
STATUS_NAMES: tuple[str, ...] = ('missed', 'support', 'collision', 'no_contact', 'slips', 'holds')
MISSED, SUPPORT, COLLISION, NO_CONTACT, SLIPS, HOLDS = range(len(STATUS_NAMES))


@dataclass(frozen=True)
class PadGripper:
    """
    The judge's hand: two square pads closing along the grasp's closing axis.

    :ivar max_width: opening between the pads, the grasps' ``gripper_max_width``.
    :ivar pad_size: side of each square pad.
    :ivar depths: finger depths past the first contact to try.
    :ivar friction: Coulomb friction coefficient mu.
    :ivar pad_rays: rays per pad side (pad_rays x pad_rays rays per pad face).
    :ivar ray_spacing: largest spacing of the approach rays across the opening.
    """

    max_width: float
    pad_size: float = PAD_SIZE
    depths: tuple[float, ...] = FINGER_DEPTHS
    friction: float = DEFAULT_FRICTION
    pad_rays: int = 5
    ray_spacing: float = 0.004

    def __post_init__(self) -> None:
        if not self.max_width > 0.0 or not self.pad_size > 0.0:
            raise ValueError('max_width and pad_size must be > 0')
        if not self.depths or min(self.depths) <= 0.0:
            raise ValueError('depths must be a non-empty list of lengths > 0')
        if self.pad_rays < 2 or not self.ray_spacing > 0.0 or not self.friction >= 0.0:
            raise ValueError('pad_rays must be >= 2, ray_spacing > 0 and friction >= 0')


@dataclass
class Verdicts:
    """
    The judge's verdicts on many grasps, arrays in input order.

    :ivar status: (G,) index into :data:`STATUS_NAMES`: ``holds`` or how far the grasp got.
    :ivar depth: (G,) the first finger depth that holds (NaN when none does).
    :ivar contacts: (G, 2, 3) the two contacts at that depth, or at the first depth where both
        pads touched (NaN when they never did).
    :ivar normals: (G, 2, 3) the inward normals there.
    """

    status: NDArray[np.int8]
    depth: FloatArray
    contacts: FloatArray
    normals: FloatArray

    @property
    def holds(self) -> BoolArray:
        """(G,) whether each grasp holds."""
        return self.status == HOLDS

    def __len__(self) -> int:
        return len(self.status)

    def status_counts(self) -> dict[str, int]:
        """Return how many grasps ended in each status."""
        counts = np.bincount(self.status, minlength=len(STATUS_NAMES))
        return {name: int(count) for name, count in zip(STATUS_NAMES, counts, strict=True)}


def _grid(half: float, spacing: float) -> FloatArray:
    return np.linspace(-half, half, max(2, math.ceil(2.0 * half / spacing) + 1))


def judge_grasps(
    target: GraspTarget,
    grasps: Any,
    gripper: PadGripper,
    *,
    support: tuple[ArrayLike, float] | None = None,
) -> Verdicts:
    """
    Judge grasps on a whole mesh with the pad gripper (the protocol: module docstring).

    :param target: the whole object.
    :param grasps: grasp-like objects (``.position``, ``.approach``, ``.closing``, e.g.
        :class:`mvbb_ros.geometry.grasping.hypotheses.Grasp`) or a ``(positions, approaches,
        closings)`` triple of (G, 3) arrays, in the mesh's frame.
    :param gripper: the pad gripper.
    :param support: the support plane ``(up, height)``: points p with ``up . p >= height`` are
        above it; None for no support.
    :return: the verdicts, in input order.
    """
    positions, approach, closing, side = grasp_axes(grasps)
    count, depths = len(positions), np.asarray(gripper.depths, dtype=np.float64)
    status = np.full((count, len(depths)), MISSED, dtype=np.int8)
    contacts = np.full((count, len(depths), 2, 3), np.nan)
    normals = np.full((count, len(depths), 2, 3), np.nan)
    if count == 0:
        return Verdicts(
            status=np.zeros(0, dtype=np.int8),
            depth=np.zeros(0),
            contacts=np.zeros((0, 2, 3)),
            normals=np.zeros((0, 2, 3)),
        )
    half, pad = gripper.max_width / 2.0, gripper.pad_size
    across = _grid(pad / 2.0, pad / (gripper.pad_rays - 1))  # along the side axis

    # 1. Approach from outside the bounding sphere, along the grasp's line.
    back = (
        np.maximum(
            np.einsum('ij,ij->i', positions - target.center_of_mass, approach) + target.radius, 0.0
        )
        + 2.0 * pad
    )
    start = positions - back[:, None] * approach
    between = _grid(half, gripper.ray_spacing)
    footprint = (
        start[:, None, None, :]
        + between[None, :, None, None] * closing[:, None, None, :]
        + across[None, None, :, None] * side[:, None, None, :]
    ).reshape(count, -1, 3)
    first, _ = target.cast(footprint, approach[:, None, :])
    reach = first.min(axis=1)  # travel of the fingertips to the first contact
    touched = np.isfinite(reach)
    travel = reach[:, None] + depths[None, :]  # (G, D) fingertip travel from the start
    signs = np.array([1.0, -1.0])  # pad 0 at +half along closing, pad 1 at -half

    # 2. Support: every pad corner above the plane at the pre-grasp and the final pose.
    clear = np.ones((count, len(depths)), dtype=bool)
    if support is not None:
        up = unit_rows(np.asarray(support[0], dtype=np.float64).reshape(1, 3))[0]
        height = float(support[1])
        corner = (
            signs[:, None, None] * half * (closing @ up)[None, None, :]
            + np.array([-0.5, 0.5])[None, :, None] * pad * (side @ up)[None, None, :]
        )  # (2 pads, 2 side corners, G): corner offsets along up from the tip centre line
        lowest = corner.min(axis=(0, 1)) + np.minimum(0.0, -pad * (approach @ up))  # (G,)
        pregrasp = positions @ up + lowest >= height - SUPPORT_SLACK
        final = (start @ up)[:, None] + travel * (approach @ up)[:, None] + lowest[
            :, None
        ] >= height - SUPPORT_SLACK
        clear = pregrasp[:, None] & final
    status[touched[:, None] & clear] = COLLISION
    status[touched[:, None] & ~clear] = SUPPORT

    # 3. Fingers: the tips' edges (at +-half, across the pad) must pass h + d freely.
    tips = (
        start[:, None, None, :]
        + (signs[:, None] * half)[None, :, :, None] * closing[:, None, None, :]
        + across[None, None, :, None] * side[:, None, None, :]
    ).reshape(count, -1, 3)
    tip_free, _ = target.cast(tips, approach[:, None, :])
    free = tip_free.min(axis=1)[:, None] >= travel - 1e-9
    status[(status == COLLISION) & free] = NO_CONTACT

    # 4. Close: a grid of rays over each pad face, from the open pad inwards.
    live = np.argwhere(status == NO_CONTACT)  # (L, 2): grasp, depth
    if len(live):
        g, d = live[:, 0], live[:, 1]
        along = _grid(pad / 2.0, pad / (gripper.pad_rays - 1)) - pad / 2.0  # tip at 0, up -pad
        pad_center = start[g] + travel[g, d][:, None] * approach[g]  # tip centre between pads
        offsets = (
            along[None, :, None, None] * approach[g][:, None, None, :]
            + across[None, None, :, None] * side[g][:, None, None, :]
        ).reshape(len(g), 1, -1, 3)
        push = -signs[None, :, None] * closing[g][:, None, :]  # (L, 2, 3): pad 0 moves -closing
        origins = (pad_center[:, None, :] - half * push)[:, :, None, :] + offsets
        distance, ids = target.cast(origins, push[:, :, None, :])  # (L, 2, R)
        gap = distance.min(axis=2)  # (L, 2): each pad's travel to its first touch
        both = np.all(np.isfinite(gap) & (gap <= gripper.max_width), axis=1)
        both &= gap.sum(axis=1) <= gripper.max_width + 1e-9
        done = live[both]
        # The contact patch: the rays within PAD_COMPLIANCE of the first touch; its centroid
        # and mean inward normal are the pad's contact.
        patch = distance[both] <= gap[both][..., None] + PAD_COMPLIANCE  # (B, 2, R)
        reach_patch = np.where(patch, distance[both], 0.0)
        hits = origins[both] + reach_patch[..., None] * push[both][:, :, None, :]
        hits = np.where(patch[..., None], hits, 0.0)
        ray_normals = np.zeros(hits.shape)
        ray_normals[patch] = target.inward_normals(
            ids[both][patch], np.broadcast_to(push[both][:, :, None, :], hits.shape)[patch]
        )
        weight = patch.sum(axis=2)[..., None]
        points = hits.sum(axis=2) / weight
        contacts[done[:, 0], done[:, 1]] = points
        normals[done[:, 0], done[:, 1]] = unit_rows(ray_normals.sum(axis=2) / weight)
        status[done[:, 0], done[:, 1]] = SLIPS

        # 5. Friction: the contact line inside both cones.
        grips = line_in_friction_cones(points, normals[done[:, 0], done[:, 1]], gripper.friction)
        held = done[grips]
        status[held[:, 0], held[:, 1]] = HOLDS
    return _verdicts(status, depths, contacts, normals)


def _verdicts(
    status: NDArray[np.int8], depths: FloatArray, contacts: FloatArray, normals: FloatArray
) -> Verdicts:
    """Reduce per-depth outcomes (G, D) to one verdict per grasp."""
    count = len(status)
    final = status.max(axis=1)
    holds = status == HOLDS
    first_hold = np.where(holds.any(axis=1), holds.argmax(axis=1), -1)
    touched = status >= SLIPS
    first_touch = np.where(touched.any(axis=1), touched.argmax(axis=1), -1)
    pick = np.where(first_hold >= 0, first_hold, first_touch)
    rows = np.flatnonzero(pick >= 0)
    chosen_contacts = np.full((count, 2, 3), np.nan)
    chosen_normals = np.full((count, 2, 3), np.nan)
    chosen_contacts[rows] = contacts[rows, pick[rows]]
    chosen_normals[rows] = normals[rows, pick[rows]]
    depth = np.full(count, np.nan)
    depth[first_hold >= 0] = depths[first_hold[first_hold >= 0]]
    return Verdicts(
        status=final.astype(np.int8),
        depth=depth,
        contacts=chosen_contacts,
        normals=chosen_normals,
    )


def simulated_epsilon(target: GraspTarget, grasps: Any, max_width: float) -> FloatArray:
    """
    Return the Ferrari-Canny epsilon of grasps with the project's Figure 6 simulator.

    :func:`mvbb_ros.evaluation.simulation.evaluate_grasps` (approach until the palm touches,
    close, soft-finger wrench space) with a gripper like the judge's: opening `max_width`,
    fingers :data:`SIMULATOR_FINGER_DEPTH` deep and as wide as a pad, no retreat. A second
    opinion on the judge's verdict, unit-free (0 when not force-closure).

    :param target: the whole object.
    :param grasps: grasp-like objects or a ``(positions, approaches, closings)`` triple.
    :param max_width: the gripper opening.
    :return: (G,) epsilons.
    """
    gripper = ParallelJawGripper(
        max_width=max_width, finger_depth=SIMULATOR_FINGER_DEPTH, finger_width=PAD_SIZE
    )
    return evaluate_grasps(target, grasps, gripper=gripper).epsilon


# Steadiness --------------------------------------------------------------------------------------

#: Two grasps are the same when their positions are within this distance (metres) ...
SAME_DISTANCE = 0.01
#: ... and their hand frames within this angle (degrees), a half turn about the approach allowed.
SAME_ANGLE_DEG = 15.0


def grasp_angle_deg(first: Any, second: Any) -> float:
    """
    Return the angle (degrees) between two grasps' hand frames, a half turn about approach free.

    The hand frame is (approach, closing, approach x closing); a parallel-jaw hand turned half
    a turn about its approach is the same hand (its fingers swapped), so the smaller of the two
    rotation angles (as is, and with the second turned) is returned.
    """
    _, approach, closing, side = grasp_axes([first, second])
    frames = np.stack([approach, closing, side], axis=-1)  # (2, 3, 3), columns
    turned = frames[1] @ np.diag([1.0, -1.0, -1.0])
    angles = []
    for other in (frames[1], turned):
        cos = (np.trace(frames[0].T @ other) - 1.0) / 2.0
        angles.append(math.degrees(math.acos(min(1.0, max(-1.0, cos)))))
    return min(angles)


def same_grasp(
    first: Any,
    second: Any,
    *,
    distance: float = SAME_DISTANCE,
    angle_deg: float = SAME_ANGLE_DEG,
) -> bool:
    """
    Tell whether two grasps are the same to a robot: close positions and hand frames.

    :param first: a grasp-like object (``.position``, ``.approach``, ``.closing``) or None.
    :param second: another, or None; a missing grasp is never the same as anything.
    :param distance: largest distance between the positions.
    :param angle_deg: largest angle between the hand frames (:func:`grasp_angle_deg`).
    """
    if first is None or second is None:
        return False
    gap = np.linalg.norm(
        np.asarray(first.position, dtype=np.float64) - np.asarray(second.position, dtype=float)
    )
    return bool(gap <= distance) and grasp_angle_deg(first, second) <= angle_deg


def steady_pairs(tops: Sequence[Any]) -> tuple[int, int]:
    """
    Count consecutive pairs of top grasps that are the same (:func:`same_grasp`).

    :param tops: the top grasp of each frame, in order (None for a frame without grasps).
    :return: ``(same, pairs)``.
    """
    pairs = max(len(tops) - 1, 0)
    same = sum(same_grasp(a, b) for a, b in zip(tops[:-1], tops[1:], strict=True))
    return same, pairs
