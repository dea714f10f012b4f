"""
The MuJoCo scene of the physics trial: a static table, the object as a free body, the hand.

The table is a box whose top is z = 0. The object is a free body with one convex mesh geom per
part (MuJoCo collides with each part's hull); each part's density is scaled so that the body's mass
is the object's density times the volume of the union of its parts (overlapping parts would
otherwise count twice). The hand is a free body (gravity compensated) welded to a mocap body that
the trial moves, with two slide fingers under position actuators whose force is limited to the
hand's grip force and whose joints are damped so that they close at the stated speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
from mvbb_ros.arrays import FloatArray
from mvbb_ros.evaluation.physics.hand import Hand
from mvbb_ros.evaluation.physics.objects import PhysicsObject
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

#: Parts smaller than this (m^3, one cubic millimetre) are left out of the collision model.
MIN_PART_VOLUME = 1e-9
#: Masses (kg) of the palm and of each finger (the Franka Hand weighs about 0.7 kg).
PALM_MASS = 0.6
FINGER_MASS = 0.03
#: Inertia (kg) the finger drive adds to each finger joint (its gearing). Without it the light
#: fingers ring against a stiff contact and let go of the object for a step now and then.
FINGER_ARMATURE = 0.1
#: How far past closed (metres) the finger targets go when closing, so that the grip force is the
#: force limit whatever the object's width.
CLOSE_OVERSHOOT = 0.02
#: Half the size (metres) of the square table and its thickness.
TABLE_HALF_SIZE = 0.6
TABLE_THICKNESS = 0.04


@dataclass(frozen=True)
class PhysicsOptions:
    """The engine's settings shared by the settling and the trial (see :class:`TrialSettings`)."""

    friction: float
    torsional_friction: float
    timestep: float
    closing_speed: float
    noslip_iterations: int = 0


@dataclass
class Scene:
    """A compiled scene and the ids the trial reads."""

    model: mujoco.MjModel
    data: mujoco.MjData
    object_body: int
    object_qpos: int
    object_dof: int
    table_geom: int
    hand_body: int = -1
    hand_qpos: int = -1
    mocap: int = -1
    hand_geoms: tuple[int, ...] = ()
    left_geom: int = -1
    right_geom: int = -1
    left_qpos: int = -1
    right_qpos: int = -1


def _numbers(values: ArrayLike) -> str:
    return ' '.join(f'{value:.9g}' for value in np.asarray(values, dtype=np.float64).ravel())


def _part_volume(vertices: FloatArray) -> float:
    try:
        return float(ConvexHull(vertices).volume)
    except (QhullError, ValueError):
        return 0.0


def _object_xml(obj: PhysicsObject) -> tuple[str, str]:
    volumes = [_part_volume(vertices) for vertices, _ in obj.parts]
    kept = [i for i, volume in enumerate(volumes) if volume >= MIN_PART_VOLUME]
    if not kept:
        raise ValueError(f'{obj.name}: no convex part of 1 mm^3 or more')
    density = obj.density * obj.volume / sum(volumes[i] for i in kept)
    assets = ''.join(
        f'<mesh name="part{i}" vertex="{_numbers(obj.parts[i][0])}" inertia="convex"/>\n'
        for i in kept
    )
    geoms = ''.join(
        f'<geom name="part{i}" type="mesh" mesh="part{i}" density="{density:.9g}"/>\n'
        for i in kept
    )
    body = f'<body name="object" pos="0 0 0.5"><freejoint name="object"/>\n{geoms}</body>\n'
    return assets, body


def _hand_xml(hand: Hand, options: PhysicsOptions) -> tuple[str, str, str]:
    half_finger = (hand.pad_width / 2.0, hand.finger_thickness / 2.0, hand.finger_depth / 2.0)
    palm = (hand.palm_depth / 2.0, hand.palm_width / 2.0, hand.palm_height / 2.0)
    palm_z = -hand.finger_depth - hand.palm_height / 2.0
    damping = hand.max_force / options.closing_speed
    kp = hand.max_force / CLOSE_OVERSHOOT
    travel = hand.max_opening / 2.0

    def finger(name: str, sign: int) -> str:
        return (
            f'<body name="{name}" gravcomp="1">'
            f'<joint name="{name}" type="slide" axis="0 {sign} 0" range="0 {travel:.9g}" '
            f'damping="{damping:.9g}" armature="{FINGER_ARMATURE}"/>'
            f'<geom name="{name}" type="box" size="{_numbers(half_finger)}" '
            f'pos="0 {sign * half_finger[1]:.9g} {-half_finger[2]:.9g}" mass="{FINGER_MASS}"/>'
            '</body>\n'
        )

    body = (
        '<body name="mocap" mocap="true" pos="0 0 1"/>\n'
        '<body name="hand" pos="0 0 1" gravcomp="1"><freejoint name="hand"/>\n'
        f'<geom name="palm" type="box" size="{_numbers(palm)}" pos="0 0 {palm_z:.9g}" '
        f'mass="{PALM_MASS}"/>\n'
        f'{finger("left", 1)}{finger("right", -1)}</body>\n'
    )
    extra = (
        '<contact><exclude body1="hand" body2="left"/><exclude body1="hand" body2="right"/>'
        '<exclude body1="left" body2="right"/></contact>\n'
        '<equality><weld body1="mocap" body2="hand" solref="0.02 1"/></equality>\n'
    )
    actuators = (
        '<actuator>'
        f'<position name="left" joint="left" kp="{kp:.9g}" forcerange="{-hand.max_force:.9g} '
        f'{hand.max_force:.9g}"/>'
        f'<position name="right" joint="right" kp="{kp:.9g}" forcerange="{-hand.max_force:.9g} '
        f'{hand.max_force:.9g}"/>'
        '</actuator>\n'
    )
    return body, extra, actuators


def scene_xml(obj: PhysicsObject, hand: Hand | None, options: PhysicsOptions) -> str:
    """Return the MJCF text of the table, the object and (unless None) the hand."""
    assets, object_body = _object_xml(obj)
    hand_body, extra, actuators = _hand_xml(hand, options) if hand is not None else ('', '', '')
    friction = f'{options.friction:.9g} {options.torsional_friction:.9g} 0.0001'
    # Contacts and joint limits stiffer than the weld that drives the hand, so that the hand
    # is stopped by what it touches instead of being driven through it.
    stiff = f'{2.0 * options.timestep:.9g} 1'
    return (
        '<mujoco model="trial">\n'
        '<compiler autolimits="true" angle="radian"/>\n'
        f'<option timestep="{options.timestep:.9g}" integrator="implicitfast" cone="elliptic" '
        f'impratio="10" noslip_iterations="{options.noslip_iterations:d}"/>\n'
        f'<default><geom friction="{friction}" condim="4" solref="{stiff}"/>'
        f'<joint solreflimit="{stiff}"/></default>\n'
        f'<asset>\n{assets}</asset>\n'
        '<worldbody>\n'
        f'<geom name="table" type="box" size="{TABLE_HALF_SIZE} {TABLE_HALF_SIZE} '
        f'{TABLE_THICKNESS / 2}" pos="0 0 {-TABLE_THICKNESS / 2}"/>\n'
        f'{object_body}{hand_body}'
        '</worldbody>\n'
        f'{extra}{actuators}'
        '</mujoco>\n'
    )


def build_scene(obj: PhysicsObject, hand: Hand | None, options: PhysicsOptions) -> Scene:
    """Compile the scene of `obj` (and `hand`) and look up the ids the trial needs."""
    model = mujoco.MjModel.from_xml_string(scene_xml(obj, hand, options))
    data = mujoco.MjData(model)
    name = mujoco.mjtObj

    def ident(kind: mujoco.mjtObj, label: str) -> int:
        return int(mujoco.mj_name2id(model, kind, label))

    object_joint = ident(name.mjOBJ_JOINT, 'object')
    scene = Scene(
        model=model,
        data=data,
        object_body=ident(name.mjOBJ_BODY, 'object'),
        object_qpos=int(model.jnt_qposadr[object_joint]),
        object_dof=int(model.jnt_dofadr[object_joint]),
        table_geom=ident(name.mjOBJ_GEOM, 'table'),
    )
    if hand is not None:
        scene.hand_body = ident(name.mjOBJ_BODY, 'hand')
        scene.hand_qpos = int(model.jnt_qposadr[ident(name.mjOBJ_JOINT, 'hand')])
        scene.mocap = int(model.body_mocapid[ident(name.mjOBJ_BODY, 'mocap')])
        scene.left_geom = ident(name.mjOBJ_GEOM, 'left')
        scene.right_geom = ident(name.mjOBJ_GEOM, 'right')
        scene.hand_geoms = (ident(name.mjOBJ_GEOM, 'palm'), scene.left_geom, scene.right_geom)
        scene.left_qpos = int(model.jnt_qposadr[ident(name.mjOBJ_JOINT, 'left')])
        scene.right_qpos = int(model.jnt_qposadr[ident(name.mjOBJ_JOINT, 'right')])
    return scene
