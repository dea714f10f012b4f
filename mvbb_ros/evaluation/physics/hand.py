"""
The hand of the physics trial: a parallel-jaw gripper with the Franka Hand's geometry.

Frame of a grasp (the node's convention, README "Grasp pose convention"): the origin is the
point between the fingertips, +z the approach (from the palm towards the fingertips), y the
closing direction (the fingers move along +-y), x = y x z. Each finger is a box `pad_width`
(x) by `finger_thickness` (y) by `finger_depth` (z) whose inner face is the pad; the fingertips
are at z = 0. The palm is a box `palm_depth` (x) by `palm_width` (y) by `palm_height` (z)
behind the fingers (z from -finger_depth - palm_height to -finger_depth).

The Franka Hand's sizes are read from the collision meshes of the Panda in pybullet_data
(``franka_panda/meshes/collision/hand.obj`` and ``finger.obj``): a palm 0.063 x 0.204 m, fingers
0.021 m wide reaching 0.054 m past the palm; the grip force limit is the datasheet's continuous
force (70 N). All lengths in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Hand:
    """
    A parallel-jaw hand (metres, newtons); the Franka Hand's geometry by default.

    :ivar max_opening: largest gap between the two pads.
    :ivar finger_depth: finger length past the palm, along the approach.
    :ivar pad_width: finger (pad) size across, along the grasp's x axis.
    :ivar finger_thickness: finger size along the closing direction.
    :ivar palm_width: palm size along the closing direction (y).
    :ivar palm_depth: palm size along x.
    :ivar palm_height: palm size along the approach (z).
    :ivar max_force: grip force limit of each finger (N).
    """

    max_opening: float = 0.08
    finger_depth: float = 0.054
    pad_width: float = 0.021
    finger_thickness: float = 0.012
    palm_width: float = 0.204
    palm_depth: float = 0.063
    palm_height: float = 0.06
    max_force: float = 70.0

    def __post_init__(self) -> None:
        sizes = (
            self.max_opening,
            self.finger_depth,
            self.pad_width,
            self.finger_thickness,
            self.palm_width,
            self.palm_depth,
            self.palm_height,
            self.max_force,
        )
        if not all(size > 0.0 for size in sizes):
            raise ValueError(f'every hand size and the force limit must be > 0: {self}')
        if self.palm_width < self.max_opening + 2.0 * self.finger_thickness:
            raise ValueError('the palm must be as wide as the open fingers')


#: The Franka Hand: 8 cm between the pads.
FRANKA = Hand()
#: The same hand opening to 14 cm (the single-view benchmark's gripper opening); the palm
#: widened by the extra opening.
WIDE = replace(FRANKA, max_opening=0.14, palm_width=FRANKA.palm_width + 0.06)
#: The hands by name (``--hand`` of the benchmark).
HANDS: dict[str, Hand] = {'franka': FRANKA, 'wide': WIDE}
