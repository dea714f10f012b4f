"""
The parallel-jaw gripper of the grasp-quality experiment: two thin fingers and a palm.

Lengths are in the mesh's units; :meth:`ParallelJawGripper.for_object` scales the gripper to an
object's diameter D (opening 1.2 D, fingers 0.5 D deep by default). How it approaches, retreats
and closes is in ``docs/evaluation_protocol.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Default gripper opening and finger depth, as fractions of the object's diameter D.
DEFAULT_WIDTH_FACTOR = 1.2
DEFAULT_DEPTH_FACTOR = 0.5


@dataclass(frozen=True)
class ParallelJawGripper:
    """
    A parallel-jaw gripper; lengths in mesh units (the model: ``docs/evaluation_protocol.md``).

    :ivar max_width: opening between the finger pads when open (> 0).
    :ivar finger_depth: finger length from the palm to the tips, along the approach (> 0).
    :ivar finger_width: finger (and palm) width across the closing direction (>= 0).
    :ivar retreat: how far the hand backs off after the palm touches (>= 0).
    :ivar palm_rays: rays across the opening on the palm (>= 2).
    :ivar width_rays: rays across the finger width, on the palm and on each fingertip (>= 1).
    """

    max_width: float
    finger_depth: float
    finger_width: float = 0.0
    retreat: float = 0.0
    palm_rays: int = 25
    width_rays: int = 3

    def __post_init__(self) -> None:
        if not self.max_width > 0.0:
            raise ValueError(f'max_width must be > 0, got {self.max_width}')
        if not self.finger_depth > 0.0:
            raise ValueError(f'finger_depth must be > 0, got {self.finger_depth}')
        if not self.finger_width >= 0.0:
            raise ValueError(f'finger_width must be >= 0, got {self.finger_width}')
        if not self.retreat >= 0.0:
            raise ValueError(f'retreat must be >= 0, got {self.retreat}')
        if self.palm_rays < 2 or self.width_rays < 1:
            raise ValueError('palm_rays must be >= 2 and width_rays >= 1')

    @classmethod
    def for_object(
        cls,
        size: float,
        *,
        width_factor: float = DEFAULT_WIDTH_FACTOR,
        depth_factor: float = DEFAULT_DEPTH_FACTOR,
        finger_width_factor: float = 0.1,
        retreat_factor: float = 0.01,
    ) -> ParallelJawGripper:
        """
        Return a gripper scaled to an object of the given size (its diameter), in its units.

        The defaults mirror the paper's large-opening five-finger hand with a parallel gripper
        that can span the whole object: opening 1.2 x the object's diameter, fingers half the
        diameter deep and a tenth of it wide, retreat 1 % of it.

        :param size: the object's size (e.g. the diameter of a
            :class:`~mvbb_ros.evaluation.mesh.GraspTarget`), > 0.
        :param width_factor: ``max_width / size``.
        :param depth_factor: ``finger_depth / size``.
        :param finger_width_factor: ``finger_width / size``.
        :param retreat_factor: ``retreat / size``.
        :return: the gripper.
        """
        if not size > 0.0:
            raise ValueError(f'size must be > 0, got {size}')
        return cls(
            max_width=width_factor * size,
            finger_depth=depth_factor * size,
            finger_width=finger_width_factor * size,
            retreat=retreat_factor * size,
        )

    def default_contact_radius(self) -> float:
        """Return the soft-contact radius used when none is given: a quarter finger width."""
        return self.finger_width / 4.0
