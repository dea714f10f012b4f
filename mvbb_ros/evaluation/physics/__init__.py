"""
The proving ground's physics trial (issue 36, ``docs/proving_ground.md``): grasps tried in MuJoCo.

:mod:`~mvbb_ros.evaluation.physics.hand` (the parallel-jaw hand, Franka geometry),
:mod:`~mvbb_ros.evaluation.physics.objects` (the objects: pybullet_data's random objects, the
shared meshes, any mesh folder; convex parts by CoACD, cached),
:mod:`~mvbb_ros.evaluation.physics.model` (the MuJoCo scene) and
:mod:`~mvbb_ros.evaluation.physics.trial` (settling an object on the table; approach, close, lift,
shake). MuJoCo is the engine; nothing here integrates physics itself.
"""

from mvbb_ros.evaluation.physics.hand import FRANKA, Hand, HANDS, WIDE
from mvbb_ros.evaluation.physics.objects import (
    convex_parts,
    DEFAULT_DENSITY,
    mesh_folder_objects,
    PhysicsObject,
    random_object,
    random_object_split,
    shared_mesh_objects,
)
from mvbb_ros.evaluation.physics.trial import (
    DEFAULT_SETTINGS,
    settle,
    STAGES,
    TrialResult,
    TrialSettings,
    try_grasp,
    try_grasps,
)

__all__ = [
    'DEFAULT_DENSITY',
    'DEFAULT_SETTINGS',
    'FRANKA',
    'HANDS',
    'STAGES',
    'WIDE',
    'Hand',
    'PhysicsObject',
    'TrialResult',
    'TrialSettings',
    'convex_parts',
    'mesh_folder_objects',
    'random_object',
    'random_object_split',
    'settle',
    'shared_mesh_objects',
    'try_grasp',
    'try_grasps',
]
