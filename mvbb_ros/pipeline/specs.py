"""
The table of every tunable the node exposes (:data:`SPECS`), one :class:`SettingSpec` each.

Each setting is listed once: its flat parameter name (the ROS parameter and the ``mvbb`` flag,
e.g. ``gain_threshold``), the stage field it sets, its type, range or choices, its description
and, where the node's default differs from the stage's, the node's default. The node declares
its ROS parameters from it, ``config/decomposer.yaml`` is generated from it
(:mod:`~mvbb_ros.pipeline.settings_text`, which also reads assignments and parameter files), the
``mvbb`` command builds its flags from it, and
:func:`~mvbb_ros.pipeline.settings.validate_setting` checks every value against it, so a bad
value is refused with the same reason wherever it comes from. No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, MISSING
from typing import Any

from mvbb_ros.common.workers import MAX_WORKERS
from mvbb_ros.geometry.decomposition.result import DecompositionSettings, PART_SEARCHES
from mvbb_ros.geometry.decomposition.split import SPLIT_MEASURES
from mvbb_ros.geometry.grasping.hypotheses import APPROACH_AXES, GraspSettings, STRATEGIES
from mvbb_ros.geometry.grasping.refinement_settings import RefinementSettings
from mvbb_ros.geometry.views.completion import COMPLETIONS
from mvbb_ros.pipeline.scene import SceneSettings, SUPPORT_MODES
from mvbb_ros.pipeline.stage_settings import (
    ExecutionSettings,
    FilterSettings,
    INPUT_RELIABILITIES,
    NodeSettings,
    ViewSettings,
)

#: What the range checks accept: (low, high) inclusive; None for no bound.
Range = tuple[float | None, float | None]


class _StageDefault:
    """Marker: a setting's node default is its stage's own default."""

    def __repr__(self) -> str:
        return 'the stage default'


#: The default of :attr:`SettingSpec.node_default`: take the stage's default.
STAGE_DEFAULT: Any = _StageDefault()


@dataclass(frozen=True)
class SettingSpec:
    """
    One tunable: its parameter name, the stage field it sets, type, range, and description.

    :ivar name: the ROS parameter name, which is also the ``mvbb`` flag (``--gain-threshold``).
    :ivar stage: the stage's settings class (a field type of
        :class:`~mvbb_ros.pipeline.settings.PipelineSettings`).
    :ivar kind: the parameter type: bool, int, float, str, or list (a vector of floats).
    :ivar description: one or two sentences for ``ros2 param describe``, the YAML and ``--help``.
    :ivar value_range: inclusive (low, high) for numbers.
    :ivar choices: the accepted strings (a choice list defined once, next to its stage).
    :ivar vector_length: the length of a vector; an empty vector turns the feature off where
        the stage's default is empty or `unset` is ``()``, and is refused otherwise.
    :ivar read_only: only settable at start-up (a ROS read-only parameter).
    :ivar field: the stage field, when its name differs from `name`.
    :ivar node_default: the node's default, when it differs from the stage's own.
    :ivar unset: the parameter value that stands for None in the stage field (0, or ``()`` for
        an empty vector); None when the field is never None.
    :ivar smallest_on: for a number whose 0 turns a feature off, the smallest other value (the
        work below it cannot be bounded); None when every value of the range is accepted.
    :ivar machine_default: what the default is when it depends on the machine (the parameter
        files then name it instead of writing this machine's value); None otherwise.
    """

    name: str
    stage: type
    kind: type
    description: str
    value_range: Range | None = None
    choices: tuple[str, ...] | None = None
    vector_length: int | None = None
    read_only: bool = False
    field: str | None = None
    node_default: Any = STAGE_DEFAULT
    unset: Any = None
    smallest_on: float | None = None
    machine_default: str | None = None

    @property
    def attribute(self) -> str:
        """Return the name of the stage field this setting sets."""
        return self.field or self.name

    @property
    def default(self) -> Any:
        """Return the node's default as a parameter value (lists for vectors)."""
        if self.node_default is not STAGE_DEFAULT:
            return self.node_default
        return self.stage_default

    @property
    def stage_default(self) -> Any:
        """Return the stage's own (library) default as a parameter value."""
        stage_field = next(f for f in fields(self.stage) if f.name == self.attribute)
        assert stage_field.default is not MISSING, f'{self.name}: the stage field has no default'
        return self.to_parameter(stage_field.default)

    def to_field(self, value: Any) -> Any:
        """Convert a (valid) parameter value to the stage field's value."""
        if self.unset is not None and _same(value, self.unset):
            return None
        if self.kind is list:
            return tuple(float(v) for v in value)
        if self.kind is float:
            return float(value)
        return value

    def to_parameter(self, value: Any) -> Any:
        """Convert a stage field's value to the parameter value (None becomes `unset`)."""
        if value is None:
            return list(self.unset) if isinstance(self.unset, tuple) else self.unset
        if isinstance(value, tuple):
            return [float(v) for v in value]
        return value


def _same(value: Any, unset: Any) -> bool:
    if isinstance(unset, tuple):
        return isinstance(value, list | tuple) and len(value) == 0
    return value == unset and not isinstance(value, bool)


#: Every tunable of the node, in the order of ``config/decomposer.yaml`` and ``mvbb --help``.
SPECS: tuple[SettingSpec, ...] = (
    # Decomposition (paper Section III).
    SettingSpec(
        'gain_threshold',
        DecompositionSettings,
        float,
        "Accept a split while the volume gain Theta* is below this (the paper's t); "
        'lower means fewer boxes.',
        (0.0, 1.0),
    ),
    SettingSpec(
        'min_points',
        DecompositionSettings,
        int,
        'Boxes with fewer points than this are dropped as noise.',
        (1, 1_000_000),
        node_default=25,
    ),
    SettingSpec(
        'max_boxes',
        DecompositionSettings,
        int,
        'Upper bound on the number of leaf boxes; 0: no bound (the paper has none).',
        (0, 256),
        node_default=16,
        unset=0,
    ),
    SettingSpec(
        'split_measure',
        DecompositionSettings,
        str,
        "Split measure theta: 'area' is the paper's 2D projection measure, 'volume' "
        "uses the product of the parts' three extents.",
        choices=SPLIT_MEASURES,
    ),
    SettingSpec(
        'rescore_cuts',
        DecompositionSettings,
        int,
        'Re-score the best K cuts with real box fits (0 = the paper).',
        (0, 32),
        # The paper's cut: the node's grasps lift as often with it as with the best of three
        # cuts, at less than half the decomposition's time (docs/single_views.md, "Which cut").
    ),
    SettingSpec(
        'part_search',
        DecompositionSettings,
        str,
        "How the parts' boxes are searched: 'full' (the default search, within 1 % of the best "
        "box) or 'light' (about half the time, up to 5 % larger on one part in 200).",
        choices=PART_SEARCHES,
        # Issue 41: every box within 1 % of the best known (docs/performance.md).
        node_default='full',
    ),
    SettingSpec(
        'seed',
        DecompositionSettings,
        int,
        'Random seed of the box fit (results are deterministic).',
        (0, 2**31 - 1),
    ),
    # Filtering (compiled crop, voxel grid and statistical outliers: Open3D's results).
    SettingSpec(
        'voxel_size',
        FilterSettings,
        float,
        'Voxel down-sampling edge length in metres, at least 0.0001; 0 turns it off.',
        (0.0, 10.0),
        node_default=0.005,
        smallest_on=1e-4,
    ),
    SettingSpec(
        'object_voxel_cells',
        ViewSettings,
        int,
        'An object less than this many voxels across is sampled again from the cloud, '
        'finer: its largest extent over this many (at least min_voxel_size); 0 turns it off.',
        (0, 10_000),
        node_default=20,
    ),
    SettingSpec(
        'min_voxel_size',
        ViewSettings,
        float,
        'The finest voxel edge (metres) object_voxel_cells gives a small object.',
        (1e-4, 10.0),
    ),
    SettingSpec(
        'outlier_neighbors',
        FilterSettings,
        int,
        'Neighbours of the statistical outlier removal; 0 turns it off.',
        (0, 1000),
        node_default=20,
    ),
    SettingSpec(
        'outlier_std_ratio',
        FilterSettings,
        float,
        'Statistical outlier removal: drop points whose mean neighbour distance is this '
        'many standard deviations above the mean.',
        (0.01, 100.0),
    ),
    SettingSpec(
        'crop_min',
        FilterSettings,
        list,
        'Lower corner (x, y, z) of a crop box in metres in the cloud frame; empty '
        'leaves the box open below (both corners empty: no crop).',
        vector_length=3,
    ),
    SettingSpec(
        'crop_max',
        FilterSettings,
        list,
        'Upper corner (x, y, z) of the crop box in metres; empty leaves it open above.',
        vector_length=3,
    ),
    # The scene: the support plane and what stands on it (pipeline/scene.py).
    SettingSpec(
        'roi_max_distance',
        SceneSettings,
        float,
        'Drop points farther than this from the viewpoint (metres) before anything else, so '
        'a room-sized cloud is cut down to the work surface; 0 keeps every point.',
        (0.0, 1000.0),
        node_default=3.0,
    ),
    SettingSpec(
        'support_plane',
        SceneSettings,
        str,
        "The plane the objects stand on: 'auto' fits it and keeps what stands on it when the "
        "cloud is a table-top scene (a segmented object passes unchanged), 'none' treats the "
        "cloud as one segmented object (the paper), 'fixed' uses support_coefficients.",
        choices=SUPPORT_MODES,
        node_default='auto',
    ),
    SettingSpec(
        'support_coefficients',
        SceneSettings,
        list,
        'The fixed support plane (a, b, c, d): a x + b y + c z + d = 0 in the cloud frame, '
        "(a, b, c) pointing up out of the table; used with support_plane 'fixed'.",
        vector_length=4,
    ),
    SettingSpec(
        'support_distance',
        SceneSettings,
        float,
        "Points this close to the support plane (metres) are the table: the fit's inlier "
        'band, and what stands on the table starts this high.',
        (1e-4, 1.0),
    ),
    SettingSpec(
        'support_max_height',
        SceneSettings,
        float,
        'Keep what stands at most this high above the support plane (metres).',
        (1e-3, 100.0),
    ),
    SettingSpec(
        'support_margin',
        SceneSettings,
        float,
        "Keep what stands at least this far inside the table's outline (metres): the foot of "
        'a wall behind the table is dropped.',
        (0.0, 1.0),
    ),
    SettingSpec(
        'support_min_fraction',
        SceneSettings,
        float,
        "support_plane 'auto': the table holds at least this share of the points, else the "
        'cloud is a segmented object.',
        (0.0, 1.0),
    ),
    # The sensor view: objects and their hidden side (docs/single_views.md).
    SettingSpec(
        'viewpoint',
        ViewSettings,
        list,
        'Sensor position (x, y, z) in the cloud frame, metres: the origin for camera and '
        'laser frames; set it when the cloud was transformed into another frame.',
        vector_length=3,
    ),
    SettingSpec(
        'up_direction',
        ViewSettings,
        list,
        'Up vector (x, y, z) in the cloud frame: vertical mirror planes, a support under '
        'the object, no approaches from below. Empty: unknown.',
        vector_length=3,
        field='up',
        unset=(),
    ),
    SettingSpec(
        'cluster_tolerance',
        ViewSettings,
        float,
        'Points closer than this (metres) are one object; each object is decomposed on its '
        'own. 0 treats the whole cloud as one object.',
        (0.0, 10.0),
        node_default=0.02,
    ),
    SettingSpec(
        'max_objects',
        ViewSettings,
        int,
        'The largest objects of a cloud that are decomposed and grasped; the rest are left '
        'out and the diagnostics say so. 0 keeps every object.',
        (0, 1000),
        node_default=16,
    ),
    SettingSpec(
        'view_edge_margin_deg',
        ViewSettings,
        float,
        "On a frame with a support plane, an object closer than this (degrees) to the frame's "
        "edge as the sensor sees it is cut by the view: its grasps come after whole objects'. "
        '0: off.',
        (0.0, 45.0),
        node_default=0.5,
    ),
    SettingSpec(
        'shape_completion',
        ViewSettings,
        str,
        "How each object's hidden side is estimated: 'mirror' (symmetric about the plane "
        "the view contradicts least), 'extrude' (away from the sensor to the box's far side) "
        "or 'none' (the observed points only, the paper).",
        choices=COMPLETIONS,
        field='completion',
        node_default='mirror',
    ),
    SettingSpec(
        'min_box_thickness',
        DecompositionSettings,
        float,
        'No split may leave a box thinner than this (metres): plates of sensor thickness '
        'are not shapes. 0: no floor (the paper).',
        (0.0, 10.0),
        field='min_thickness',
        node_default=0.01,
    ),
    # Grasps (paper Section IV-B).
    SettingSpec(
        'gripper_max_width',
        GraspSettings,
        float,
        'Largest gripper opening in metres; faces needing more are ungraspable.',
        (1e-4, 10.0),
    ),
    SettingSpec(
        'standoff',
        GraspSettings,
        float,
        'Pre-grasp distance of the gripper from the face centre in metres.',
        (0.0, 10.0),
    ),
    SettingSpec(
        'approach_axis',
        GraspSettings,
        str,
        'Gripper frame axis that points along the approach direction.',
        choices=APPROACH_AXES,
    ),
    SettingSpec(
        'grasp_strategy',
        GraspSettings,
        str,
        'Ranking: largest box first, smallest, outermost from the centroid, or nearest '
        'to the sensor.',
        choices=STRATEGIES,
        field='strategy',
    ),
    SettingSpec(
        'far_side_grasps',
        GraspSettings,
        bool,
        'Offer grasps that approach from the far side of the object as seen from the '
        'viewpoint (the hand moving back towards the sensor, through what it cannot see).',
        field='far_side',
        node_default=False,
    ),
    # Grasps checked, refined and scored on the points (docs/grasp_rules.md).
    SettingSpec(
        'grasp_refinement',
        RefinementSettings,
        bool,
        "Check, refine and score the paper's face hypotheses on the points (observed and "
        'estimated): contacts on both sides within the opening, inside the friction cones. '
        "Off: the paper's hypotheses as they are.",
        field='enabled',
        node_default=True,
    ),
    SettingSpec(
        'grasp_friction',
        RefinementSettings,
        float,
        'Friction coefficient mu of the finger pads: the contact line must lie within '
        'atan(mu) of both surface normals.',
        (0.0, 10.0),
        field='friction',
    ),
    SettingSpec(
        'finger_pad_size',
        RefinementSettings,
        float,
        'Side of the square finger pads in metres, along the approach and across it.',
        (1e-4, 1.0),
        field='pad_size',
    ),
    SettingSpec(
        'finger_depth',
        RefinementSettings,
        float,
        'How far past the first contact the fingertips may go, metres (shallower depths are '
        'tried too).',
        (1e-4, 1.0),
    ),
    SettingSpec(
        'finger_length',
        RefinementSettings,
        float,
        'Length of the finger pads along the approach, metres: the palm is this far behind '
        'the fingertips. 0: finger_pad_size (no palm).',
        (0.0, 1.0),
        node_default=0.054,
    ),
    SettingSpec(
        'finger_thickness',
        RefinementSettings,
        float,
        'Thickness of each finger outside the opening, metres: the open fingers must clear '
        'the support.',
        (0.0, 1.0),
        node_default=0.012,
    ),
    SettingSpec(
        'palm_width',
        RefinementSettings,
        float,
        'Width of the palm along the closing direction, metres: no point may stand in front '
        'of it closer than finger_length. 0: no palm.',
        (0.0, 2.0),
        node_default=0.204,
    ),
    SettingSpec(
        'palm_depth',
        RefinementSettings,
        float,
        'Depth of the palm across the closing direction, metres.',
        (0.0, 2.0),
        node_default=0.063,
    ),
    SettingSpec(
        'palm_height',
        RefinementSettings,
        float,
        'Height of the palm along the approach, behind the fingers, metres.',
        (0.0, 2.0),
        node_default=0.06,
    ),
    SettingSpec(
        'support_clearance',
        RefinementSettings,
        float,
        'With an up direction, the lowest point of the open fingers and the palm stays this '
        'far above the support, metres: the table when the scene stage found it, else the '
        "object's observed base (its lowest 1 % of points).",
        (0.0, 0.1),
        node_default=0.002,
    ),
    SettingSpec(
        'grasp_width_margin',
        RefinementSettings,
        float,
        'Added to the opening the object needs along the closing line for the published '
        'width, metres (the width never exceeds gripper_max_width).',
        (0.0, 1.0),
        field='width_margin',
    ),
    SettingSpec(
        'grasp_hysteresis',
        RefinementSettings,
        float,
        "The previous cloud's top grasp stays on top while it still holds and scores within "
        'this of the best new grasp (0: always the best).',
        (0.0, 1.0),
        field='hysteresis',
        node_default=0.5,
    ),
    SettingSpec(
        'grasp_preference',
        RefinementSettings,
        float,
        'Weight of grasp_strategy in the score of refined grasps; the rest is the contact '
        'quality, so the strategy reorders grasps of close quality.',
        (0.0, 1.0),
        field='preference',
    ),
    SettingSpec(
        'max_grasps',
        GraspSettings,
        int,
        'Publish at most this many grasps, best first; 0 publishes all. With the grasp '
        'refinement a bounded list is also cheaper: only the lines that can reach it are '
        'checked against pose errors.',
        (0, 10000),
        node_default=32,
    ),
    # How the pipeline runs.
    SettingSpec(
        'workers',
        ExecutionSettings,
        int,
        'Threads that process one cloud (the same results with any number); 1 runs it all on '
        'one thread. Default: the cores the process may use, at most 8.',
        (1, MAX_WORKERS),
        machine_default='the cores this process may use, at most 8',
    ),
    # Node behaviour.
    SettingSpec(
        'publish_tree',
        NodeSettings,
        bool,
        'Also publish the non-leaf boxes of the hierarchy on ~/tree.',
    ),
    SettingSpec(
        'input_reliability',
        NodeSettings,
        str,
        "Reliability of the cloud_in subscription: 'auto' is reliable while every publisher "
        'offers reliable delivery and best effort otherwise (checked again as publishers come '
        "and go), 'reliable' or 'best_effort' force it; a change re-creates the subscription.",
        choices=INPUT_RELIABILITIES,
    ),
    SettingSpec(
        'input_depth',
        NodeSettings,
        int,
        'Queue depth of the cloud_in subscription (keep last N): 1 always works on the newest '
        'cloud; more (with a reliable input) processes every cloud of a bag.',
        (1, 1000),
    ),
    SettingSpec(
        'stale_after',
        NodeSettings,
        float,
        'The diagnostics warn when no cloud arrived for this many seconds (wall clock); '
        '0 never warns.',
        (0.0, 86400.0),
    ),
    SettingSpec(
        'frame_time_budget',
        NodeSettings,
        float,
        'Seconds of pipeline time per frame; after a frame over it the next ones run lighter, '
        'in this order: coarser voxels, fewer objects, fewer grasp candidates (the notes and '
        'diagnostics say so). 0: off.',
        (0.0, 3600.0),
    ),
)

SPEC_BY_NAME: dict[str, SettingSpec] = {spec.name: spec for spec in SPECS}
