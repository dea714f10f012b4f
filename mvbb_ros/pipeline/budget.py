"""
The per-frame time budget (``frame_time_budget``): lighter settings after frames that overran.

A :class:`FrameBudget` follows the pipeline time of each frame of a stream. After a frame that
took longer than the budget the next frame runs one level lighter; after a frame that took less
than :data:`RECOVER_FRACTION` of it, one level less light. The levels degrade in a stated order,
each keeping the ones before it (:func:`degraded`):

1. coarser voxels: ``voxel_size`` doubled (from :data:`BASE_VOXEL_M` when the grid is off), and
   small objects sampled at half as many voxels across (``object_voxel_cells`` halved: the
   same objects as before get their own finer voxels, so no new one is sampled again; turning
   them off instead cost a fifth of the grasps that lift an object, ``docs/performance.md``);
2. fewer objects: ``max_objects`` halved (from :data:`BASE_CAP` when every object is kept);
3. fewer grasp candidates: ``max_boxes`` halved (from :data:`BASE_CAP` when unbounded): each
   leaf box gives at most six face candidates;

then the same three again with a factor of four (levels 4 to 6, :data:`MAX_LEVEL`). The level
depends only on the budget and the frame times recorded, so a stream of frame times always
gives the same settings; the times are measured, so the outputs then depend on the machine.
The settings in force (the node's parameters) are never changed: each frame gets a lighter copy,
and the result's notes say what was lightened and why.
"""

from __future__ import annotations

from dataclasses import replace

from mvbb_ros.pipeline.settings import PipelineSettings

#: The lightest level: each of the three steps applied twice.
MAX_LEVEL = 6
#: A frame faster than this share of the budget takes one level back.
RECOVER_FRACTION = 0.5
#: Voxel edge (metres) the first level starts from when the voxel grid is off.
BASE_VOXEL_M = 0.005
#: Objects or boxes the halving starts from when the setting has no bound (0).
BASE_CAP = 16
#: The steps, in the order they are taken.
STEPS = ('coarser voxels', 'fewer objects', 'fewer grasp candidates')


def degraded(settings: PipelineSettings, level: int) -> tuple[PipelineSettings, list[str]]:
    """
    Return `settings` lightened to `level` (0 to :data:`MAX_LEVEL`) and what changed.

    :return: the settings and one ``name old -> new`` entry per changed setting.
    """
    if not 0 <= level <= MAX_LEVEL:
        raise ValueError(f'level must be in [0, {MAX_LEVEL}], got {level}')
    rounds = [(level + len(STEPS) - 1 - step) // len(STEPS) for step in range(len(STEPS))]
    changes = []
    filtering, view = settings.filtering, settings.view
    decomposition = settings.decomposition
    if rounds[0]:
        old = filtering.voxel_size
        new = (old if old > 0.0 else BASE_VOXEL_M) * 2 ** rounds[0]
        filtering = replace(filtering, voxel_size=new)
        changes.append(f'voxel_size {old:g} -> {new:g} m')
        if view.object_voxel_cells:
            cells = view.object_voxel_cells >> rounds[0]
            changes.append(f'object_voxel_cells {view.object_voxel_cells} -> {cells}')
            view = replace(view, object_voxel_cells=cells)
    if rounds[1]:
        old_objects = view.max_objects
        new_objects = max(1, (old_objects or BASE_CAP) >> rounds[1])
        view = replace(view, max_objects=new_objects)
        changes.append(f'max_objects {old_objects} -> {new_objects}')
    if rounds[2]:
        old_boxes = decomposition.max_boxes
        new_boxes = max(1, (old_boxes or BASE_CAP) >> rounds[2])
        decomposition = replace(decomposition, max_boxes=new_boxes)
        changes.append(f'max_boxes {old_boxes or 0} -> {new_boxes}')
    lighter = replace(settings, filtering=filtering, view=view, decomposition=decomposition)
    return lighter, changes


class FrameBudget:
    """
    The level of one stream: which lighter settings the next frame runs with.

    :param budget_s: the budget of one frame's pipeline time, seconds; 0 turns it off.
    """

    def __init__(self, budget_s: float = 0.0) -> None:
        self.budget_s = budget_s
        self.level = 0
        #: The pipeline time of the last frame recorded, seconds (None before the first).
        self.last_s: float | None = None

    def settings(self, settings: PipelineSettings) -> tuple[PipelineSettings, str | None]:
        """
        Return the settings for the next frame and the note that says why they are lighter.

        The budget in force is ``settings.node.frame_time_budget``; when it changes (a
        parameter set on the running node) the level starts again from 0.
        """
        budget_s = settings.node.frame_time_budget
        if budget_s != self.budget_s:
            self.budget_s, self.level, self.last_s = budget_s, 0, None
        if self.budget_s <= 0.0 or self.level == 0:
            return settings, None
        lighter, changes = degraded(settings, self.level)
        last = '' if self.last_s is None else f', the last took {self.last_s * 1e3:.0f} ms'
        note = (
            f'frame_time_budget: level {self.level} of {MAX_LEVEL} after frames over the '
            f'{self.budget_s * 1e3:.0f} ms budget{last}: {", ".join(changes)}'
        )
        return lighter, note

    def record(self, seconds: float) -> None:
        """Record one frame's pipeline time (seconds) and move the level for the next."""
        self.last_s = seconds
        if self.budget_s <= 0.0:
            return
        if seconds > self.budget_s:
            self.level = min(MAX_LEVEL, self.level + 1)
        elif seconds < RECOVER_FRACTION * self.budget_s:
            self.level = max(0, self.level - 1)
