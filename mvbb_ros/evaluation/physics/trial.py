"""
The physics trial of a grasp: approach, close, lift, shake, in MuJoCo.

World frame: z up, the table top is z = 0. A grasp pose is a 4x4 in the world frame whose origin
is the point between the fingertips, z the approach and y the closing direction (the node's
convention; :mod:`mvbb_ros.evaluation.physics.hand`). The stages, and the failure each names:

1. **Pre-grasp**: the open hand (gap `width`, or the hand's opening) is put `standoff` back along
   -z from the grasp pose. Touching the table or the object there is a ``collision``.
2. **Approach** along +z to the grasp pose at `approach_speed`. A ``collision`` when a palm or
   finger touches the table at any step, when the hand is held back (more than `block_tolerance`
   from where it is driven), or when it pushes the object (by more than `push_tolerance` or
   `push_angle`). Grazing the object without moving it is allowed. With ``approach =
   'until_contact'`` (the paper's GraspIt! execution, for a pose that names only the approach
   line) the hand instead stops at the first step where any part of it touches the object (at
   most `standoff` plus the finger depth past the pre-grasp pose, so that the palm can reach the
   given point), retreats `contact_retreat` and closes there.
3. **Close** both fingers with the force limit. ``missed`` when the two pads do not both touch the
   object (or the fingers shut: gap under 2 mm).
4. **Lift** `lift_height` straight up and hold. ``slipped`` when the object is no longer held.
5. **Shake**: the hand oscillates along world x, y and z and turns about world x and y through the
   fingertips' centre (:class:`TrialSettings`). ``dropped`` when the object is no longer held.

Held means both pads touch the object and the object has risen by at least half the lift.
Otherwise the grasp ``lifted``: success. The engine runs single-threaded from a reset state, so a
trial's verdict depends only on its inputs; :func:`settle` draws its drop orientation from its
seed.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import time
from typing import Literal

import mujoco
from mvbb_ros.arrays import FloatArray
from mvbb_ros.evaluation.physics.hand import FRANKA, Hand
from mvbb_ros.evaluation.physics.model import (
    build_scene,
    CLOSE_OVERSHOOT,
    PhysicsOptions,
    Scene,
    TABLE_HALF_SIZE,
)
from mvbb_ros.evaluation.physics.objects import PhysicsObject
import numpy as np
from numpy.typing import ArrayLike

Stage = Literal['lifted', 'collision', 'missed', 'slipped', 'dropped']
#: How the hand approaches: to the given pose, or along its line until it touches the object.
Approach = Literal['to_pose', 'until_contact']
APPROACHES: tuple[Approach, ...] = ('to_pose', 'until_contact')
#: The stage names, success first.
STAGES: tuple[Stage, ...] = ('lifted', 'collision', 'missed', 'slipped', 'dropped')
#: A closed hand whose pads are nearer than this (metres) holds nothing.
MIN_GAP = 0.002
#: The fingers close for at least their whole stroke's time and this much more, seconds (a
#: wide hand's fingers stopped short of a thin object when given the 8 cm hand's time).
CLOSE_SLACK_SECONDS = 0.2
#: A held object is one both pads touched within this time (seconds): a contact can come and go
#: for a step while the grip is sound.
GRIP_MEMORY = 0.1
#: Roles of the geoms, as bits, to tell what a contact joins.
_PALM, _LEFT, _RIGHT, _OBJECT, _TABLE = 1, 2, 4, 8, 16
_HAND = _PALM | _LEFT | _RIGHT


@dataclass(frozen=True)
class TrialSettings:
    """
    How a trial runs (metres, seconds, radians, m/s).

    :ivar friction: Coulomb friction of every contact (pads, object, table), one setting, the
        middle of the 0.5-1.0 range of rubber pads on household goods.
    :ivar torsional_friction: MuJoCo's torsional friction (metres), its default.
    :ivar timestep: the engine's step. MuJoCo's contacts are soft with a time constant of two
        steps, relative to the bodies' masses: with 2 ms the full grip sank the pads 5-7 mm into
        objects of a few grams, which then squirted out. A quarter millisecond keeps them under
        half a millimetre (:attr:`TrialResult.penetration`; ``docs/proving_ground.md``).
    :ivar noslip_iterations: iterations of MuJoCo's no-slip pass, which removes the creep the
        soft friction model lets a gripped object make although its friction holds it (a light
        object turned out of a full grip without it); sliding beyond the friction stays.
    :ivar standoff: pre-grasp distance back along the approach.
    :ivar approach_speed: hand speed on the approach.
    :ivar closing_speed: speed of each finger while closing (set by the joints' damping).
    :ivar close_seconds: time given to the fingers to close (at least their whole stroke's
        time and :data:`CLOSE_SLACK_SECONDS`).
    :ivar lift_height: how far the hand lifts.
    :ivar lift_seconds: time of the lift (a smooth start and stop).
    :ivar hold_seconds: still time after the lift and after the shake.
    :ivar shake_amplitude: amplitude of the shake along each axis.
    :ivar shake_frequency: frequency of the shake along each axis (one period per axis).
    :ivar shake_angle: amplitude of the turns about world x and y.
    :ivar turn_frequency: frequency of the turns (one period per axis).
    :ivar push_tolerance: object displacement on the approach that counts as a collision.
    :ivar push_angle: object rotation on the approach that counts as a collision.
    :ivar block_tolerance: distance from the driven pose at which the hand counts as held back.
    :ivar drop_height: gap under the object when :func:`settle` lets it go.
    :ivar settle_seconds: longest time :func:`settle` waits for the object to come to rest.
    :ivar rest_speed: speed (m/s, and rad/s over 10) under which the object is at rest.
    :ivar approach: ``'to_pose'``: the fingers close at the given pose; ``'until_contact'``: the
        hand moves along the pose's approach line until any part of it touches the object, then
        retreats `contact_retreat` and closes (Huebner et al. 2008, section IV: "We let the hand
        approach along the normal until a contact is detected. After contact, the hand retreats
        a small distance before we call GraspIt!'s auto-grasp function").
    :ivar contact_retreat: how far the hand backs off after the contact (``'until_contact'``;
        the paper says only "a small distance").
    """

    friction: float = 0.75
    torsional_friction: float = 0.005
    timestep: float = 0.00025
    noslip_iterations: int = 10
    standoff: float = 0.10
    approach_speed: float = 0.2
    closing_speed: float = 0.1
    close_seconds: float = 0.6
    lift_height: float = 0.15
    lift_seconds: float = 1.0
    hold_seconds: float = 0.25
    shake_amplitude: float = 0.02
    shake_frequency: float = 2.0
    shake_angle: float = 0.35
    turn_frequency: float = 1.0
    push_tolerance: float = 0.01
    push_angle: float = 0.17
    block_tolerance: float = 0.005
    drop_height: float = 0.005
    settle_seconds: float = 4.0
    rest_speed: float = 0.002
    approach: Approach = 'to_pose'
    contact_retreat: float = 0.005

    def __post_init__(self) -> None:
        positive = (
            self.timestep,
            self.standoff,
            self.approach_speed,
            self.closing_speed,
            self.close_seconds,
            self.lift_height,
            self.lift_seconds,
            self.settle_seconds,
            self.rest_speed,
        )
        if (
            not all(value > 0.0 for value in positive)
            or not 0.0 <= self.friction <= 2.0
            or self.noslip_iterations < 0
        ):
            raise ValueError(f'trial settings out of range: {self}')
        if self.approach not in APPROACHES or not self.contact_retreat >= 0.0:
            raise ValueError(
                f'approach must be one of {APPROACHES} and contact_retreat >= 0: {self}'
            )

    @property
    def options(self) -> PhysicsOptions:
        """Return the engine's part of the settings."""
        return PhysicsOptions(
            self.friction,
            self.torsional_friction,
            self.timestep,
            self.closing_speed,
            self.noslip_iterations,
        )


DEFAULT_SETTINGS = TrialSettings()


@dataclass(frozen=True)
class TrialResult:
    """
    The verdict on one grasp.

    :ivar success: the object was still held after the shake.
    :ivar stage: ``'lifted'`` on success, else the failure (module docstring).
    :ivar detail: what happened, in words.
    :ivar gap: distance between the pads after closing (metres; NaN when the trial stopped before).
    :ivar displacement: how far the object moved during the approach (metres).
    :ivar rise: how far the object rose from where it rested, at the end (metres).
    :ivar seconds: wall time of the trial (seconds).
    :ivar advance: where the fingers closed, along the approach from the given pose (metres:
        0 with ``approach='to_pose'``; negative when an ``'until_contact'`` hand stopped short of
        it; NaN when the trial stopped before the approach ended).
    :ivar penetration: the deepest a pad sank into the object while it was lifted and shaken
        (metres, sampled with the grip checks; 0 when the object was not lifted): how rigid the
        engine kept the contact.
    """

    success: bool
    stage: Stage
    detail: str
    gap: float
    displacement: float
    rise: float
    seconds: float
    advance: float = math.nan
    penetration: float = 0.0


def _position(start: int) -> slice:
    """Return the position's place in the qpos of a free joint starting at `start`."""
    return slice(start, start + 3)


def _orientation(start: int) -> slice:
    """Return the quaternion's place in the qpos of a free joint starting at `start`."""
    return slice(start + 3, start + 7)


def _velocity(start: int) -> slice:
    """Return the velocities (linear, angular) of a free joint whose dofs start at `start`."""
    return slice(start, start + 6)


def _quat(rotation: FloatArray) -> FloatArray:
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation, dtype=np.float64).ravel())
    return quat


def _pose_matrix(position: FloatArray, quat: FloatArray) -> FloatArray:
    matrix = np.empty(9)
    mujoco.mju_quat2Mat(matrix, quat)
    pose = np.eye(4)
    pose[:3, :3] = matrix.reshape(3, 3)
    pose[:3, 3] = position
    return pose


def _check_pose(pose: ArrayLike, what: str) -> FloatArray:
    matrix = np.asarray(pose, dtype=np.float64)
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise ValueError(f'{what} must be a finite 4x4 matrix, got shape {matrix.shape}')
    rotation = matrix[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        raise ValueError(f'{what} must hold a proper rotation')
    return matrix


def place_object(scene: Scene, pose: FloatArray) -> None:
    """Put the object of `scene` at the 4x4 world `pose`, still."""
    qpos = scene.data.qpos
    qpos[_position(scene.object_qpos)] = pose[:3, 3]
    qpos[_orientation(scene.object_qpos)] = _quat(pose[:3, :3])
    scene.data.qvel[_velocity(scene.object_dof)] = 0.0


def _object_pose(scene: Scene) -> FloatArray:
    qpos = scene.data.qpos
    return _pose_matrix(
        qpos[_position(scene.object_qpos)].copy(),
        qpos[_orientation(scene.object_qpos)].copy(),
    )


def settle(
    obj: PhysicsObject, seed: int, settings: TrialSettings = DEFAULT_SETTINGS
) -> FloatArray:
    """
    Return the 4x4 world pose of `obj` at rest on the table (its top at z = 0).

    The object is dropped from an orientation drawn uniformly from the rotations
    (``numpy.random.default_rng([seed])``), its lowest point `drop_height` above the table, and the
    engine runs until it has been at rest for 0.2 s (speed under `rest_speed`, turning under ten
    times that in rad/s) or `settle_seconds` have passed. The pose is then moved in x and y so
    that the object's box is centred on x = y = 0 (the table is the same everywhere).
    """
    if float(obj.extent.max()) > TABLE_HALF_SIZE:
        raise ValueError(
            f'{obj.name} is {obj.extent.max():.2f} m long, more than the table allows '
            f'({TABLE_HALF_SIZE} m): are its units right?'
        )
    scene = build_scene(obj, None, settings.options)
    rng = np.random.default_rng([seed])
    quat = rng.normal(size=4)
    quat /= np.linalg.norm(quat)
    start = _pose_matrix(np.zeros(3), quat)
    world = obj.vertices @ start[:3, :3].T
    start[:3, 3] = [0.0, 0.0, settings.drop_height - float(world[:, 2].min())]
    mujoco.mj_resetData(scene.model, scene.data)
    place_object(scene, start)
    model, data = scene.model, scene.data
    still_steps = int(round(0.2 / settings.timestep))
    still = 0
    velocity = data.qvel[_velocity(scene.object_dof)]
    for _ in range(int(math.ceil(settings.settle_seconds / settings.timestep))):
        mujoco.mj_step(model, data)
        at_rest = (
            np.linalg.norm(velocity[:3]) < settings.rest_speed
            and np.linalg.norm(velocity[3:]) < 10.0 * settings.rest_speed
        )
        still = still + 1 if at_rest else 0
        if still >= still_steps:
            break
    pose = _object_pose(scene)
    world = obj.vertices @ pose[:3, :3].T + pose[:3, 3]
    low, high = world.min(axis=0), world.max(axis=0)
    pose[:2, 3] -= (low[:2] + high[:2]) / 2.0
    return pose


class _Trial:
    """One compiled scene of an object and a hand, on which grasps are tried in turn."""

    def __init__(self, obj: PhysicsObject, hand: Hand, settings: TrialSettings) -> None:
        self.obj, self.hand, self.settings = obj, hand, settings
        self.scene = build_scene(obj, hand, settings.options)
        scene = self.scene
        self.roles = np.zeros(scene.model.ngeom, dtype=np.int64)
        self.roles[scene.model.geom_bodyid == scene.object_body] = _OBJECT
        self.roles[scene.table_geom] = _TABLE
        self.roles[list(scene.hand_geoms)] = _PALM
        self.roles[scene.left_geom] = _LEFT
        self.roles[scene.right_geom] = _RIGHT
        self.step = 0
        self.gripped_step = -(10**9)
        self.watch_grip = False
        self.penetration = 0.0
        # Views into the engine's arrays, made once: the bindings build a new view per access.
        self.mocap_pos = scene.data.mocap_pos[scene.mocap]
        self.mocap_quat = scene.data.mocap_quat[scene.mocap]

    # -- what touches what ------------------------------------------------------------------
    def _touch_mask(self) -> np.ndarray:
        """Return, per contact, the bitwise or of its two geoms' roles (:data:`_ROLES`)."""
        data = self.scene.data
        roles = self.roles[np.asarray(data.contact.geom[: data.ncon])]
        return np.bitwise_or(roles[:, 0], roles[:, 1]) if len(roles) else roles[:, 0]

    def _hand_on_table(self) -> bool:
        mask = self._touch_mask()
        return bool(np.any(((mask & _TABLE) != 0) & ((mask & _HAND) != 0)))

    def _hand_on_object(self) -> bool:
        mask = self._touch_mask()
        return bool(np.any(((mask & _OBJECT) != 0) & ((mask & _HAND) != 0)))

    def _pad_depth(self) -> float:
        """Return how deep the deepest pad-object contact is (metres, 0 when none)."""
        mask = self._touch_mask()
        pads = ((mask & _OBJECT) != 0) & ((mask & (_LEFT | _RIGHT)) != 0)
        if not pads.any():
            return 0.0
        distances = np.asarray(self.scene.data.contact.dist[: len(mask)])
        return max(0.0, -float(distances[pads].min()))

    def _pads_on_object(self) -> bool:
        mask = self._touch_mask()
        return bool(np.any(mask == _LEFT | _OBJECT) and np.any(mask == _RIGHT | _OBJECT))

    # -- moving the hand ----------------------------------------------------------------------
    def _drive(self, position: FloatArray, quat: FloatArray) -> None:
        self.mocap_pos[:] = position
        self.mocap_quat[:] = quat
        mujoco.mj_step(self.scene.model, self.scene.data)
        self.step += 1
        if self.watch_grip and self.step % 5 == 0:
            if self._pads_on_object():
                self.gripped_step = self.step
            self.penetration = max(self.penetration, self._pad_depth())

    def _hold(self, seconds: float, position: FloatArray, quat: FloatArray) -> None:
        for _ in range(int(round(seconds / self.settings.timestep))):
            self._drive(position, quat)

    def _steps(self, seconds: float) -> int:
        return max(1, int(math.ceil(seconds / self.settings.timestep)))

    def _lag(self) -> float:
        data, scene = self.scene.data, self.scene
        return float(np.linalg.norm(data.xpos[scene.hand_body] - data.mocap_pos[scene.mocap]))

    def _held(self, rest_z: float) -> bool:
        """Both pads touched the object within `GRIP_MEMORY` and it has risen half the lift."""
        rise = float(self.scene.data.xpos[self.scene.object_body][2]) - rest_z
        recent = self.step - self.gripped_step <= GRIP_MEMORY / self.settings.timestep
        return recent and rise >= self.settings.lift_height / 2.0

    # -- the trial ----------------------------------------------------------------------------
    def run(self, object_pose: FloatArray, grasp: FloatArray, width: float | None) -> TrialResult:
        started = time.perf_counter()
        settings, scene, hand = self.settings, self.scene, self.hand
        model, data = scene.model, scene.data
        gap = hand.max_opening if width is None else float(np.clip(width, 0.0, hand.max_opening))
        mujoco.mj_resetData(model, data)
        self.step, self.gripped_step, self.watch_grip = 0, -(10**9), False
        self.penetration = 0.0
        place_object(scene, object_pose)
        approach = grasp[:3, 2]
        quat = _quat(grasp[:3, :3])
        start = grasp[:3, 3] - settings.standoff * approach
        data.qpos[_position(scene.hand_qpos)] = start
        data.qpos[_orientation(scene.hand_qpos)] = quat
        data.mocap_pos[scene.mocap] = start
        data.mocap_quat[scene.mocap] = quat
        data.qpos[scene.left_qpos] = data.qpos[scene.right_qpos] = gap / 2.0
        data.ctrl[:] = gap / 2.0
        mujoco.mj_forward(model, data)
        rest_position = data.xpos[scene.object_body].copy()
        rest_rotation = data.xmat[scene.object_body].reshape(3, 3).copy()

        pushed = [math.nan]  # the object's displacement on the approach, once known
        advance = [math.nan]  # where the fingers close, along the approach, once known

        def verdict(stage: Stage, detail: str, closed: float = math.nan) -> TrialResult:
            now = data.xpos[scene.object_body]
            moved = (
                pushed[0]
                if not math.isnan(pushed[0])
                else float(np.linalg.norm(now - rest_position))
            )
            return TrialResult(
                success=stage == 'lifted',
                stage=stage,
                detail=detail,
                gap=closed,
                displacement=moved,
                rise=float(now[2] - rest_position[2]),
                seconds=time.perf_counter() - started,
                advance=advance[0],
                penetration=self.penetration,
            )

        if self._hand_on_table():
            return verdict('collision', 'the hand touches the table at the pre-grasp pose')
        if self._hand_on_object():
            return verdict('collision', 'the hand touches the object at the pre-grasp pose')
        guarded = settings.approach == 'until_contact'
        travel = settings.standoff + (hand.finger_depth if guarded else 0.0)
        steps = self._steps(travel / settings.approach_speed)
        reached = travel
        for step in range(1, steps + 1):
            self._drive(start + travel * step / steps * approach, quat)
            if self._hand_on_table():
                return verdict(
                    'collision', 'a finger or the palm touched the table on the approach'
                )
            if guarded and self._hand_on_object():
                # Where the hand is, not where it is driven: the weld trails the drive.
                reached = float((data.xpos[scene.hand_body] - start) @ approach)
                break
        if guarded:
            # Back off from the contact as the paper's hand did, at the approach speed.
            back = min(settings.contact_retreat, reached)
            retreat = self._steps(back / settings.approach_speed)
            for step in range(1, retreat + 1):
                self._drive(start + (reached - back * step / retreat) * approach, quat)
            reached -= back
        # The given pose itself when the hand goes to it (bit for bit: verdicts do not change).
        closing_point = start + reached * approach if guarded else grasp[:3, 3].copy()
        advance[0] = reached - settings.standoff if guarded else 0.0
        self._hold(0.05, closing_point, quat)
        displacement = float(np.linalg.norm(data.xpos[scene.object_body] - rest_position))
        pushed[0] = displacement
        turn = data.xmat[scene.object_body].reshape(3, 3) @ rest_rotation.T
        angle = math.acos(float(np.clip((np.trace(turn) - 1.0) / 2.0, -1.0, 1.0)))
        if displacement > settings.push_tolerance or angle > settings.push_angle:
            return verdict(
                'collision',
                f'the hand pushed the object {displacement * 1000:.0f} mm, '
                f'{math.degrees(angle):.0f} deg on the approach',
            )
        if self._lag() > settings.block_tolerance:
            return verdict(
                'collision', f'the hand was held back {self._lag() * 1000:.0f} mm short'
            )

        data.ctrl[:] = -CLOSE_OVERSHOOT
        # At least the time a finger takes to travel its whole stroke, and a little more.
        stroke = hand.max_opening / 2.0 / settings.closing_speed + CLOSE_SLACK_SECONDS
        for _ in range(self._steps(max(settings.close_seconds, stroke))):
            self._drive(closing_point, quat)
            if self._hand_on_table():
                return verdict('collision', 'a finger touched the table while closing')
        closed = float(data.qpos[scene.left_qpos] + data.qpos[scene.right_qpos])
        if closed < MIN_GAP or not self._pads_on_object():
            return verdict('missed', 'the pads did not both close on the object', closed)

        self.watch_grip = True
        base = closing_point.copy()
        steps = self._steps(settings.lift_seconds)
        for step in range(1, steps + 1):
            ramp = 0.5 - 0.5 * math.cos(math.pi * step / steps)
            self._drive(base + [0.0, 0.0, settings.lift_height * ramp], quat)
        top = base + [0.0, 0.0, settings.lift_height]
        self._hold(settings.hold_seconds, top, quat)
        if not self._held(rest_position[2]):
            return verdict('slipped', 'the object was not held after the lift', closed)

        if not self._shake(top, quat, float(rest_position[2])):
            return verdict('dropped', 'the object was lost in the shake', closed)
        self._hold(settings.hold_seconds, top, quat)
        if not self._held(rest_position[2]):
            return verdict('dropped', 'the object was lost after the shake', closed)
        return verdict('lifted', 'held through the lift and the shake', closed)

    def _shake(self, top: FloatArray, quat: FloatArray, rest_z: float) -> bool:
        """Shake the lifted hand; return False as soon as the object is no longer held."""
        settings = self.settings
        for axis in range(3):
            steps = self._steps(1.0 / settings.shake_frequency)
            for step in range(1, steps + 1):
                offset = np.zeros(3)
                offset[axis] = settings.shake_amplitude * math.sin(2.0 * math.pi * step / steps)
                self._drive(top + offset, quat)
            if not self._held(rest_z):
                return False
        for axis in range(2):
            steps = self._steps(1.0 / settings.turn_frequency)
            for step in range(1, steps + 1):
                angle = settings.shake_angle * math.sin(2.0 * math.pi * step / steps)
                turn, turned = np.zeros(4), np.zeros(4)
                mujoco.mju_axisAngle2Quat(turn, np.eye(3)[axis], angle)
                mujoco.mju_mulQuat(turned, turn, quat)
                self._drive(top, turned)
            if not self._held(rest_z):
                return False
        return True


def try_grasps(
    obj: PhysicsObject,
    object_pose: ArrayLike,
    grasp_poses: ArrayLike,
    hand: Hand = FRANKA,
    settings: TrialSettings = DEFAULT_SETTINGS,
    widths: ArrayLike | None = None,
) -> list[TrialResult]:
    """
    Try each grasp on `obj` resting at `object_pose`, each from the same start; one scene built.

    :param obj: the object.
    :param object_pose: 4x4 world pose of the object (from :func:`settle`).
    :param grasp_poses: (K, 4, 4) world poses where the fingers close (module docstring).
    :param hand: the hand.
    :param settings: the trial's settings.
    :param widths: (K,) opening of the hand on the approach (metres, at most the hand's opening;
        NaN or None for the hand's full opening).
    :return: one :class:`TrialResult` per grasp, in order.
    """
    pose = _check_pose(object_pose, 'object_pose')
    grasps = np.asarray(grasp_poses, dtype=np.float64).reshape(-1, 4, 4)
    openings = (
        np.full(len(grasps), np.nan)
        if widths is None
        else np.asarray(widths, dtype=np.float64).reshape(len(grasps))
    )
    checked = [_check_pose(grasp, f'grasp {i}') for i, grasp in enumerate(grasps)]
    if not checked:
        return []
    trial = _Trial(obj, hand, settings)
    return [
        trial.run(pose, grasp, None if math.isnan(opening) else float(opening))
        for grasp, opening in zip(checked, openings, strict=True)
    ]


def try_grasp(
    obj: PhysicsObject,
    object_pose: ArrayLike,
    grasp_pose: ArrayLike,
    hand: Hand = FRANKA,
    settings: TrialSettings = DEFAULT_SETTINGS,
    width: float | None = None,
) -> TrialResult:
    """Try one grasp (:func:`try_grasps`); `width` is the opening on the approach (None: full)."""
    widths = None if width is None else [width]
    grasps = np.asarray(grasp_pose, dtype=np.float64)[np.newaxis]
    return try_grasps(obj, object_pose, grasps, hand, settings, widths)[0]
