"""
What the grasp refinement is told: its settings and what it knows of the view and the gripper.

:class:`RefinementSettings` is the refinement stage's settings object (a field of
:class:`~mvbb_ros.pipeline.settings.PipelineSettings`), off by default as in the paper;
:class:`GraspView` carries what the stage takes from the view and from the grasp stage's settings
(the opening, the standoff, the up direction, the viewpoint). The pad gripper's check
(:mod:`mvbb_ros.geometry.grasping.contacts`) and the refinement
(:mod:`mvbb_ros.geometry.grasping.refine`) read both.
"""

from __future__ import annotations

from dataclasses import dataclass

from mvbb_ros.arrays import FloatArray
from mvbb_ros.geometry.grasping.hypotheses import ApproachAxis, Strategy

#: Defaults (metres): the judge's pads, finger depths past the first contact, width margin.
DEFAULT_PAD_SIZE = 0.02
DEFAULT_FINGER_DEPTH = 0.03
DEFAULT_FRICTION = 0.5
DEFAULT_WIDTH_MARGIN = 0.01
DEFAULT_HYSTERESIS = 0.3
DEFAULT_PREFERENCE = 0.1
#: The pad model keeps its pads this far above the support (metres).
DEFAULT_SUPPORT_CLEARANCE = 0.005
#: Finger depths tried, as fractions of the finger depth (the deepest is the finger depth).
DEPTH_FRACTIONS: tuple[float, ...] = (1.0 / 3.0, 2.0 / 3.0, 1.0)


@dataclass(frozen=True)
class RefinementSettings:
    """
    The settings of the refinement stage; off by default (the paper).

    Read by the pad gripper's check (:mod:`~mvbb_ros.geometry.grasping.contacts`) and by
    :func:`~mvbb_ros.geometry.grasping.refine.refine_grasps`.

    :ivar enabled: refine and score the hypotheses on the points; off: the paper's hypotheses.
    :ivar friction: Coulomb friction coefficient mu of the pads (the cone's half-angle is
        atan(mu)).
    :ivar pad_size: side of the square finger pads, along the approach and across it.
    :ivar finger_depth: the deepest the fingertips go past the first contact; shallower depths
        (:data:`DEPTH_FRACTIONS`) are tried too.
    :ivar width_margin: added to the opening the object needs, for the published width.
    :ivar hysteresis: the previous frame's top grasp stays on top while its score is within this
        of the best new one.
    :ivar preference: weight of the task strategy in the score (the rest is the quality).
    :ivar depth_fractions: the finger depths tried, as fractions of `finger_depth`.
    :ivar finger_length: length of the fingers' pads along the approach (the palm is this far
        behind the fingertips); 0: `pad_size`.
    :ivar finger_thickness: thickness of each finger outside the opening (with `up`: the open
        fingers stay above the support).
    :ivar palm_width: width of the palm along the closing direction; 0: no palm (nothing stops
        the fingers but the points between them).
    :ivar palm_depth: depth of the palm across the closing direction.
    :ivar palm_height: height of the palm along the approach (behind the fingers).
    :ivar support_clearance: with `up`, the fingers' and the palm's lowest point stays this far
        above the support (metres): the table when the scene stage found it, else the object's
        observed base.
    """

    enabled: bool = False
    friction: float = DEFAULT_FRICTION
    pad_size: float = DEFAULT_PAD_SIZE
    finger_depth: float = DEFAULT_FINGER_DEPTH
    width_margin: float = DEFAULT_WIDTH_MARGIN
    hysteresis: float = DEFAULT_HYSTERESIS
    preference: float = DEFAULT_PREFERENCE
    depth_fractions: tuple[float, ...] = DEPTH_FRACTIONS
    finger_length: float = 0.0
    finger_thickness: float = 0.0
    palm_width: float = 0.0
    palm_depth: float = 0.0
    palm_height: float = 0.0
    support_clearance: float = DEFAULT_SUPPORT_CLEARANCE

    def __post_init__(self) -> None:
        for name in (
            'friction',
            'width_margin',
            'hysteresis',
            'finger_length',
            'finger_thickness',
            'palm_width',
            'palm_depth',
            'palm_height',
            'support_clearance',
        ):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f'{name} must be >= 0, got {getattr(self, name)}')
        for name in ('pad_size', 'finger_depth'):
            if not getattr(self, name) > 0.0:
                raise ValueError(f'{name} must be > 0, got {getattr(self, name)}')
        if not self.depth_fractions or min(self.depth_fractions) <= 0.0:
            raise ValueError(f'depth_fractions must be > 0, got {self.depth_fractions}')
        if not 0.0 <= self.preference <= 1.0:
            raise ValueError(f'preference must be in [0, 1], got {self.preference}')


@dataclass(frozen=True)
class GraspView:
    """
    What the refinement knows of the view and the gripper beyond its settings.

    :ivar gripper_max_width: the gripper's opening.
    :ivar standoff: pre-grasp distance before the first contact.
    :ivar approach_axis: the gripper pose convention (``docs/grasp_rules.md``).
    :ivar strategy: the task strategy whose preference reorders close scores.
    :ivar up: unit up direction, or None.
    :ivar viewpoint: (3,) the sensor position, or None when the points are no single view.
    :ivar far_side: allow approaches from the far side of the object (seen from the viewpoint).
    :ivar max_approach_elevation_deg: approaches rising more than this above the horizontal
        are removed (with `up`).
    :ivar support_clearance: with `up`, the hand's lowest point stays this far above the
        support (:attr:`RefinementSettings.support_clearance`).
    :ivar max_grasps: at most this many grasps (0: all distinct ones).
    """

    gripper_max_width: float
    standoff: float
    approach_axis: ApproachAxis = 'z'
    strategy: Strategy = 'largest'
    up: FloatArray | None = None
    viewpoint: FloatArray | None = None
    far_side: bool = True
    max_approach_elevation_deg: float = 45.0
    support_clearance: float = 0.0
    max_grasps: int = 0
