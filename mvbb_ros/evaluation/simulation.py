"""
Simulate parallel-jaw grasps on a mesh by ray casting: approach, retreat, close, then score.

:func:`evaluate_grasps` moves the gripper along each grasp's approach until its palm touches the
object (a finger touching first is a collision), backs off, and closes each finger along the
closing direction until it touches; the two contacts are scored by
:mod:`mvbb_ros.evaluation.wrench`. Every step runs for all grasps in one Open3D ``cast_rays``
call. The exact protocol and its simplifications are in ``docs/evaluation_protocol.md``.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
import time
from typing import Any

from mvbb_ros.arrays import BoolArray, cross, FloatArray
from mvbb_ros.evaluation.gripper import ParallelJawGripper
from mvbb_ros.evaluation.mesh import GraspTarget
from mvbb_ros.evaluation.wrench import (
    contact_wrenches,
    DEFAULT_CONE_EDGES,
    DEFAULT_FRICTION,
    line_in_friction_cones,
    unit_rows,
    wrench_space_quality,
)
import numpy as np
from numpy.typing import NDArray

#: Outcome of a simulated grasp, :attr:`GraspEvaluation.status` indexes this tuple.
STATUS_NAMES: tuple[str, ...] = ('grasped', 'missed', 'collision', 'no_contact')
GRASPED, MISSED, COLLISION, NO_CONTACT = range(4)


@dataclass(frozen=True)
class GraspQuality:
    """
    Quality of one simulated grasp.

    :ivar epsilon: Ferrari-Canny epsilon (0 when not force-closure).
    :ivar volume: volume V of the grasp wrench space hull.
    :ivar force_closure: ``epsilon > 0``.
    :ivar status: ``'grasped'``, ``'missed'``, ``'collision'`` or ``'no_contact'``.
    :ivar contacts: (2, 3) contact points (NaN when not grasped).
    :ivar normals: (2, 3) inward contact normals (NaN when not grasped).
    :ivar travel: how far the hand moved along the approach before closing (NaN if missed).
    """

    epsilon: float
    volume: float
    force_closure: bool
    status: str
    contacts: FloatArray
    normals: FloatArray
    travel: float


@dataclass
class GraspEvaluation:
    """
    Qualities of many grasps on one object, arrays in input order.

    :ivar epsilon: (G,) Ferrari-Canny epsilon.
    :ivar volume: (G,) wrench-space hull volume V (NaN when skipped by the closure
        prefilter of :func:`evaluate_grasps`).
    :ivar status: (G,) index into :data:`STATUS_NAMES`.
    :ivar contacts: (G, 2, 3) contact points (NaN when not grasped).
    :ivar normals: (G, 2, 3) inward normals (NaN when not grasped).
    :ivar travel: (G,) approach travel (NaN when missed).
    :ivar seconds: wall time of the evaluation.
    """

    epsilon: FloatArray
    volume: FloatArray
    status: NDArray[np.int8]
    contacts: FloatArray
    normals: FloatArray
    travel: FloatArray
    seconds: float = 0.0

    @property
    def force_closure(self) -> BoolArray:
        """(G,) whether each grasp is force-closure (epsilon > 0)."""
        return self.epsilon > 0.0

    def __len__(self) -> int:
        return len(self.epsilon)

    def status_counts(self) -> dict[str, int]:
        """Return how many grasps ended in each status."""
        counts = np.bincount(self.status, minlength=len(STATUS_NAMES))
        return {name: int(count) for name, count in zip(STATUS_NAMES, counts, strict=True)}

    def item(self, index: int) -> GraspQuality:
        """Return grasp `index` as a :class:`GraspQuality`."""
        return GraspQuality(
            epsilon=float(self.epsilon[index]),
            volume=float(self.volume[index]),
            force_closure=bool(self.epsilon[index] > 0.0),
            status=STATUS_NAMES[int(self.status[index])],
            contacts=self.contacts[index].copy(),
            normals=self.normals[index].copy(),
            travel=float(self.travel[index]),
        )


def _grasp_arrays(grasps: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Return (positions, approaches, closings) of Grasp-like objects or an array triple."""
    if isinstance(grasps, tuple) and len(grasps) == 3 and not hasattr(grasps[0], 'position'):
        arrays = [np.asarray(part, dtype=np.float64).reshape(-1, 3) for part in grasps]
    else:
        items = list(grasps) if isinstance(grasps, Iterable) else [grasps]
        arrays = [
            np.array([np.asarray(getattr(g, name), dtype=np.float64) for g in items]).reshape(
                -1, 3
            )
            for name in ('position', 'approach', 'closing')
        ]
    if not len(arrays[0]) == len(arrays[1]) == len(arrays[2]):
        raise ValueError('positions, approaches and closings must have the same length')
    return arrays[0], arrays[1], arrays[2]


def _may_be_force_closure(
    contacts: FloatArray, normals: FloatArray, friction: float, torsion: float
) -> BoolArray:
    """
    Return, per two-contact grasp, False when it is certainly not force-closure.

    Nguyen's test (:func:`~mvbb_ros.evaluation.wrench.line_in_friction_cones`): two soft-finger
    contacts are force-closure only when the segment between them lies strictly inside both
    (circular) friction cones; the linearised wrench sets are inside the exact ones, so failing
    the test (or hard contacts, torsion 0) rules force closure out. Passing it does not prove
    force closure; the hull decides.
    """
    if torsion <= 0.0:
        return np.zeros(len(contacts), dtype=bool)
    return line_in_friction_cones(contacts, normals, friction)


def grasp_axes(grasps: Any) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """
    Return the hand frames of grasps: positions, unit approaches, closings and sides (G, 3) each.

    The closing direction is made orthogonal to the approach; ``side = approach x closing``.

    :param grasps: grasp-like objects (``.position``, ``.approach``, ``.closing``) or a
        ``(positions, approaches, closings)`` triple of (G, 3) arrays.
    :raises ValueError: when a grasp has no approach or a closing direction along it.
    """
    positions, approaches, closings = _grasp_arrays(grasps)
    approach = unit_rows(approaches)
    closing = closings - np.einsum('ij,ij->i', closings, approach)[:, None] * approach
    closing = unit_rows(closing)
    if len(positions) and (
        np.any(np.linalg.norm(approach, axis=1) == 0.0)
        or np.any(np.linalg.norm(closing, axis=1) == 0.0)
    ):
        raise ValueError('every grasp needs an approach and a closing direction not along it')
    return positions, approach, closing, cross(approach, closing)


def evaluate_grasps(
    mesh: Any,
    grasps: Any,
    *,
    gripper: ParallelJawGripper | None = None,
    friction: float = DEFAULT_FRICTION,
    cone_edges: int = DEFAULT_CONE_EDGES,
    contact_radius: float | None = None,
    closure_prefilter: bool = False,
) -> GraspEvaluation:
    """
    Simulate and score many grasps on one mesh, vectorised (``docs/evaluation_protocol.md``).

    :param mesh: a :class:`GraspTarget` or anything :meth:`GraspTarget.from_mesh` accepts.
    :param grasps: a sequence of grasp-like objects (``.position``, ``.approach``,
        ``.closing``, e.g. :class:`mvbb_ros.geometry.grasping.hypotheses.Grasp`), or a
        ``(positions, approaches, closings)`` triple of (G, 3) arrays.
    :param gripper: the gripper; default :meth:`ParallelJawGripper.for_object` of the mesh's
        diameter.
    :param friction: Coulomb friction coefficient mu (default 0.5).
    :param cone_edges: friction cone edges (default 8).
    :param contact_radius: soft-contact radius r for torsional friction (mesh units); default a
        quarter of the finger width; 0 for hard point contacts.
    :param closure_prefilter: skip the hull of grasps that Nguyen's two-contact test proves
        not force-closure (the contact line outside a friction cone): their epsilon is 0 as
        always and their volume is NaN (not computed). Several times faster on large sets; the
        epsilons and the force-closure grasps' volumes are unchanged.
    :return: the qualities, in input order.
    """
    start = time.perf_counter()
    target = GraspTarget.from_mesh(mesh)
    hand = gripper or ParallelJawGripper.for_object(target.diameter)
    radius = hand.default_contact_radius() if contact_radius is None else float(contact_radius)
    if not radius >= 0.0:
        raise ValueError(f'contact_radius must be >= 0, got {contact_radius}')
    torsion = 2.0 / 3.0 * friction * radius
    positions, approach, closing, side = grasp_axes(grasps)
    count = len(positions)
    if count == 0:
        nothing = np.zeros((0, 2, 3))
        return GraspEvaluation(
            epsilon=np.zeros(0),
            volume=np.zeros(0),
            status=np.zeros(0, dtype=np.int8),
            contacts=nothing,
            normals=nothing.copy(),
            travel=np.zeros(0),
            seconds=time.perf_counter() - start,
        )
    half = hand.max_width / 2.0

    # 1-2. Approach: palm grid and fingertips, all along the approach direction.
    across = np.linspace(-half, half, hand.palm_rays)
    if hand.width_rays == 1:
        sideways = np.zeros(1)
    else:
        sideways = np.linspace(-hand.finger_width / 2, hand.finger_width / 2, hand.width_rays)
    palm_origins = (
        (positions - hand.finger_depth * approach)[:, None, None, :]
        + across[None, :, None, None] * closing[:, None, None, :]
        + sideways[None, None, :, None] * side[:, None, None, :]
    )
    palm_origins = palm_origins.reshape(count, -1, 3)
    finger_sign = np.array([1.0, -1.0])
    tip_origins = (
        positions[:, None, None, :]
        + finger_sign[None, :, None, None] * half * closing[:, None, None, :]
        + sideways[None, None, :, None] * side[:, None, None, :]
    ).reshape(count, -1, 3)
    origins = np.concatenate([palm_origins, tip_origins], axis=1)
    directions = np.broadcast_to(approach[:, None, :], origins.shape)
    t_hit, _ = target.cast(origins, directions)
    n_palm = palm_origins.shape[1]
    palm_hit = t_hit[:, :n_palm].min(axis=1) if count else np.zeros(0)
    tip_hit = t_hit[:, n_palm:].min(axis=1) if count else np.zeros(0)
    missed = ~np.isfinite(palm_hit)
    travel = np.where(missed, np.nan, palm_hit - hand.retreat)
    collision = ~missed & (tip_hit < travel)

    status = np.full(count, GRASPED, dtype=np.int8)
    status[missed] = MISSED
    status[collision] = COLLISION
    contacts = np.full((count, 2, 3), np.nan)
    normals = np.full((count, 2, 3), np.nan)

    # 3. Close: one ray per finger from its open position at the pad centres' depth.
    live = np.flatnonzero(status == GRASPED)
    if len(live):
        pads = positions[live] + (travel[live] - hand.finger_depth / 2.0)[:, None] * approach[live]
        close_dirs = -finger_sign[None, :, None] * closing[live][:, None, :]  # (L, 2, 3)
        close_origins = pads[:, None, :] - half * close_dirs
        distance, ids = target.cast(close_origins, close_dirs)
        touched = np.all(np.isfinite(distance) & (distance <= hand.max_width), axis=1)
        status[live[~touched]] = NO_CONTACT
        good = live[touched]
        points = close_origins[touched] + distance[touched][..., None] * close_dirs[touched]
        contacts[good] = points
        normals[good] = target.inward_normals(ids[touched], close_dirs[touched])

    # Quality.
    epsilon = np.zeros(count)
    volume = np.zeros(count)
    good = np.flatnonzero(status == GRASPED)
    if closure_prefilter and len(good):
        hopeful = _may_be_force_closure(contacts[good], normals[good], friction, torsion)
        volume[good[~hopeful]] = np.nan
        good = good[hopeful]
    if len(good):
        wrenches = contact_wrenches(
            contacts[good],
            normals[good],
            center=target.center_of_mass,
            scale=target.radius,
            friction=friction,
            cone_edges=cone_edges,
            torsion=torsion,
            references=np.broadcast_to(approach[good][:, None, :], contacts[good].shape),
        )
        for row, index in enumerate(good):
            epsilon[index], volume[index] = wrench_space_quality(wrenches[row])
    return GraspEvaluation(
        epsilon=epsilon,
        volume=volume,
        status=status,
        contacts=contacts,
        normals=normals,
        travel=travel,
        seconds=time.perf_counter() - start,
    )


def grasp_quality(
    mesh: Any,
    grasp: Any,
    *,
    gripper: ParallelJawGripper | None = None,
    max_width: float | None = None,
    finger_depth: float | None = None,
    friction: float = DEFAULT_FRICTION,
    cone_edges: int = DEFAULT_CONE_EDGES,
    contact_radius: float | None = None,
) -> GraspQuality:
    """
    Simulate one parallel-jaw grasp on a mesh and return its wrench-space quality.

    The gripper, placed at the grasp's pre-grasp pose, approaches until its palm touches,
    retreats, and closes; the two contacts with soft-finger friction give the grasp wrench
    space, scored by the Ferrari-Canny epsilon and the hull volume V
    (``docs/evaluation_protocol.md``).

    :param mesh: a :class:`GraspTarget`, an Open3D triangle mesh, ``(vertices, triangles)``, or
        a mesh file path. Prepare a :class:`GraspTarget` once when scoring many grasps.
    :param grasp: an object with ``.position``, ``.approach`` and ``.closing`` (for example a
        :class:`mvbb_ros.geometry.grasping.hypotheses.Grasp`), all in the mesh's frame and units.
    :param gripper: the gripper; default :meth:`ParallelJawGripper.for_object` of the mesh's
        diameter, with `max_width` and `finger_depth` replacing its values when given.
    :param max_width: maximum opening (mesh units), when `gripper` is not given.
    :param finger_depth: finger length (mesh units), when `gripper` is not given.
    :param friction: Coulomb friction coefficient (default 0.5).
    :param cone_edges: friction cone edges (default 8).
    :param contact_radius: soft-contact radius (default a quarter finger width; 0 = hard).
    :return: epsilon, volume, force_closure, status, contacts and normals.
    """
    target = GraspTarget.from_mesh(mesh)
    if gripper is None:
        gripper = ParallelJawGripper.for_object(target.diameter)
        if max_width is not None or finger_depth is not None:
            gripper = ParallelJawGripper(
                max_width=gripper.max_width if max_width is None else max_width,
                finger_depth=gripper.finger_depth if finger_depth is None else finger_depth,
                finger_width=gripper.finger_width,
                retreat=gripper.retreat,
                palm_rays=gripper.palm_rays,
                width_rays=gripper.width_rays,
            )
    elif max_width is not None or finger_depth is not None:
        raise ValueError('give either gripper or max_width/finger_depth, not both')
    result = evaluate_grasps(
        target,
        [grasp],
        gripper=gripper,
        friction=friction,
        cone_edges=cone_edges,
        contact_radius=contact_radius,
    )
    return result.item(0)
