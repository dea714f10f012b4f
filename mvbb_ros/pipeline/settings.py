"""
Pipeline settings: the settings object the table of tunables fills, its presets and its checks.

Each stage owns a frozen settings dataclass whose defaults are the library's own: the paper's
for the geometry, "off" for the filters. :class:`PipelineSettings` composes them, one field per
stage:

* ``filtering``: :class:`~mvbb_ros.pipeline.stage_settings.FilterSettings`; its defaults filter
  nothing;
* ``scene``: :class:`~mvbb_ros.pipeline.scene.SceneSettings`; no support plane, no region of
  interest (the cloud is one segmented object, as in the paper);
* ``view``: :class:`~mvbb_ros.pipeline.stage_settings.ViewSettings`; the sensor at the frame's
  origin, the whole cloud one object, the observed points alone;
* ``decomposition``: :class:`~mvbb_ros.geometry.decomposition.result.DecompositionSettings`; the
  paper's defaults;
* ``grasps``: :class:`~mvbb_ros.geometry.grasping.hypotheses.GraspSettings`; the library's
  defaults;
* ``refinement``: :class:`~mvbb_ros.geometry.grasping.refinement_settings.RefinementSettings`; off
  (the paper);
* ``execution``: :class:`~mvbb_ros.pipeline.stage_settings.ExecutionSettings`: how many threads
  process a cloud (the results are the same with any);
* ``node``: :class:`~mvbb_ros.pipeline.stage_settings.NodeSettings`: what only the node uses.

Every tunable is a row of :data:`~mvbb_ros.pipeline.specs.SPECS`, with its parameter name, the
stage field it sets and, where it differs, the node's default; :func:`validate_setting` checks
every value against its row, so a bad value is refused with the same reason wherever it comes
from. No ROS import.

Presets (:data:`PRESETS`): ``'node'`` is :class:`PipelineSettings()`, the node's defaults;
``'paper'`` (:meth:`PipelineSettings.paper`) is every stage at its own defaults, the paper's
algorithm on the raw points. ``docs/architecture.md`` shows where each setting lives and how to
add one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
import difflib
import math
import typing
from typing import Any

from mvbb_ros.geometry.decomposition.result import DecompositionSettings
from mvbb_ros.geometry.grasping.hypotheses import GraspSettings
from mvbb_ros.geometry.grasping.refinement_settings import RefinementSettings
from mvbb_ros.pipeline.scene import SceneSettings
from mvbb_ros.pipeline.specs import SettingSpec, SPEC_BY_NAME, SPECS, STAGE_DEFAULT
from mvbb_ros.pipeline.stage_settings import (
    ExecutionSettings,
    FilterSettings,
    NodeSettings,
    ViewSettings,
)


def _node_defaults(stage: type) -> Any:
    """Return the stage's settings with the node's defaults (its own where SPECS says none)."""
    values = {
        spec.attribute: spec.to_field(spec.node_default)
        for spec in SPECS
        if spec.stage is stage and spec.node_default is not STAGE_DEFAULT
    }
    return stage(**values)


@dataclass(frozen=True)
class PipelineSettings:
    """
    Every setting of the pipeline, by stage; ``PipelineSettings()`` holds the node's defaults.

    :ivar filtering: crop, voxel grid and outlier removal.
    :ivar scene: the region of interest, the support plane and what stands on it.
    :ivar view: the sensor's position and up, objects and their hidden side.
    :ivar decomposition: the fit-and-split decomposition (``decompose``'s arguments).
    :ivar grasps: the grasp hypotheses (``grasp_hypotheses``' arguments).
    :ivar refinement: the hypotheses checked, refined and scored on the points.
    :ivar execution: how many threads process a cloud (not what comes out).
    :ivar node: what only the node uses (the tree topic, the input QoS).
    """

    filtering: FilterSettings = field(default_factory=lambda: _node_defaults(FilterSettings))
    scene: SceneSettings = field(default_factory=lambda: _node_defaults(SceneSettings))
    view: ViewSettings = field(default_factory=lambda: _node_defaults(ViewSettings))
    decomposition: DecompositionSettings = field(
        default_factory=lambda: _node_defaults(DecompositionSettings)
    )
    grasps: GraspSettings = field(default_factory=lambda: _node_defaults(GraspSettings))
    refinement: RefinementSettings = field(
        default_factory=lambda: _node_defaults(RefinementSettings)
    )
    execution: ExecutionSettings = field(default_factory=lambda: _node_defaults(ExecutionSettings))
    node: NodeSettings = field(default_factory=lambda: _node_defaults(NodeSettings))

    @classmethod
    def paper(cls) -> PipelineSettings:
        """Return the paper's algorithm: every stage at its own defaults (no filters, no cap)."""
        return cls(
            filtering=FilterSettings(),
            scene=SceneSettings(),
            view=ViewSettings(),
            decomposition=DecompositionSettings(),
            grasps=GraspSettings(),
            refinement=RefinementSettings(),
            execution=ExecutionSettings(),
            node=NodeSettings(),
        )

    def value(self, name: str) -> Any:
        """Return the parameter value of setting `name` (lists for vectors, 0 or [] for None)."""
        spec = SPEC_BY_NAME[name]
        stage = getattr(self, _STAGE_FIELD[spec.stage])
        return spec.to_parameter(getattr(stage, spec.attribute))

    def parameters(self) -> dict[str, Any]:
        """Return every setting as a parameter value, by name, in :data:`SPECS` order."""
        return {spec.name: self.value(spec.name) for spec in SPECS}

    def updated(self, changes: Mapping[str, Any]) -> PipelineSettings:
        """
        Return a copy with `changes` (parameter name -> value) applied, each validated first.

        :raises ValueError: naming the first invalid setting and why.
        """
        by_stage: dict[str, dict[str, Any]] = {}
        for name, value in changes.items():
            reason = validate_setting(name, value)
            if reason is not None:
                raise ValueError(reason)
            spec = SPEC_BY_NAME[name]
            by_stage.setdefault(_STAGE_FIELD[spec.stage], {})[spec.attribute] = spec.to_field(
                value
            )
        stages = {
            name: replace(getattr(self, name), **values) for name, values in by_stage.items()
        }
        settings = replace(self, **stages)
        reason = validate_combination(settings)
        if reason is not None:
            raise ValueError(reason)
        return settings


#: The stages of :class:`PipelineSettings`: field name -> settings class, in pipeline order.
STAGES: dict[str, type] = {
    stage.name: typing.get_type_hints(PipelineSettings)[stage.name]
    for stage in fields(PipelineSettings)
}
_STAGE_FIELD: dict[type, str] = {stage: name for name, stage in STAGES.items()}

#: Named starting points: the node's defaults and the paper's algorithm.
PRESETS: dict[str, PipelineSettings] = {
    'node': PipelineSettings(),
    'paper': PipelineSettings.paper(),
}


def is_number(value: Any) -> bool:
    """Tell whether `value` is an int or a float (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


#: Settings that were replaced: old name -> what to write instead.
REPLACED_SETTINGS: dict[str, str] = {
    'reliable_input': (
        "input_reliability ('reliable_input: true' is now 'input_reliability: reliable' with "
        "'input_depth: 50'; the default 'auto' matches the publishers)"
    ),
    'voxel_backend': (
        "nothing: there is one voxel grid, which computes Open3D's centroids exactly (both "
        'former back-ends gave the same points); delete the line'
    ),
}
#: Parameters of every rclpy node that are not ours (and not errors in a parameter file).
ROS_PARAMETERS: tuple[str, ...] = ('use_sim_time', 'start_type_description_service')


def is_ros_parameter(name: str) -> bool:
    """Tell whether `name` is one of rclpy's own parameters (``use_sim_time``, QoS overrides)."""
    return name in ROS_PARAMETERS or name.startswith('qos_overrides.')


def unknown_setting_reason(name: str) -> str:
    """Return why `name` is no setting: what replaced it, or the closest and the known names."""
    if name in REPLACED_SETTINGS:
        return f'{name} was replaced by {REPLACED_SETTINGS[name]}'
    close = difflib.get_close_matches(name, list(SPEC_BY_NAME), n=1)
    hint = f' (did you mean {close[0]}?)' if close else ''
    return f'unknown setting {name!r}{hint}; known: {", ".join(SPEC_BY_NAME)}'


def validate_setting(name: str, value: Any) -> str | None:
    """Return why `value` is not acceptable for setting `name`, or None when it is."""
    spec = SPEC_BY_NAME.get(name)
    if spec is None:
        return unknown_setting_reason(name)
    checks: dict[type, Callable[[SettingSpec, Any], str | None]] = {
        bool: _check_bool,
        int: _check_number,
        float: _check_number,
        str: _check_choice,
        list: _check_vector,
    }
    return checks[spec.kind](spec, value)


def _check_bool(spec: SettingSpec, value: Any) -> str | None:
    if not isinstance(value, bool):
        return f'{spec.name} must be true or false, got {value!r}'
    return None


def _check_number(spec: SettingSpec, value: Any) -> str | None:
    if spec.kind is int and not (isinstance(value, int) and not isinstance(value, bool)):
        return f'{spec.name} must be an integer, got {value!r}'
    if spec.kind is float and not is_number(value):
        return f'{spec.name} must be a number, got {value!r}'
    if not math.isfinite(value):
        return f'{spec.name} must be finite, got {value!r}'
    low, high = spec.value_range or (None, None)
    if (low is not None and value < low) or (high is not None and value > high):
        return f'{spec.name} must be in [{low}, {high}], got {value!r}'
    if spec.smallest_on is not None and 0 < value < spec.smallest_on:
        return f'{spec.name} must be 0 (off) or at least {spec.smallest_on}, got {value!r}'
    return None


def _check_choice(spec: SettingSpec, value: Any) -> str | None:
    if not isinstance(value, str) or (spec.choices and value not in spec.choices):
        return f'{spec.name} must be one of {", ".join(spec.choices or ())}, got {value!r}'
    return None


def _check_vector(spec: SettingSpec, value: Any) -> str | None:
    try:
        values = list(value)
    except TypeError:
        return f'{spec.name} must be a list of {spec.vector_length} numbers, got {value!r}'
    may_be_empty = spec.unset == () or spec.stage_default == []
    lengths = (0, spec.vector_length) if may_be_empty else (spec.vector_length,)
    if len(values) not in lengths or not all(is_number(v) for v in values):
        what = 'empty or ' if may_be_empty else ''
        return f'{spec.name} must be {what}{spec.vector_length} numbers, got {value!r}'
    if not all(math.isfinite(v) for v in values):
        return f'{spec.name} must be finite, got {value!r}'
    if spec.name == 'up_direction' and values and math.hypot(*values) < 1e-9:
        return f'{spec.name} must not be the zero vector'
    return None


def validate_combination(settings: PipelineSettings) -> str | None:
    """Return why settings that are each valid do not fit together, or None."""
    crop_min, crop_max = settings.filtering.crop_min, settings.filtering.crop_max
    scene = settings.scene
    if scene.support_plane == 'fixed' and (
        len(scene.support_coefficients) != 4 or math.hypot(*scene.support_coefficients[:3]) < 1e-9
    ):
        return (
            "support_plane 'fixed' needs support_coefficients (a, b, c, d) with (a, b, c) not "
            f'zero, got {list(scene.support_coefficients)}'
        )
    if (
        crop_min
        and crop_max
        and any(low > high for low, high in zip(crop_min, crop_max, strict=True))
    ):
        return f'crop_min {crop_min} must not exceed crop_max {crop_max}'
    return None


def settings_from_mapping(
    values: Mapping[str, Any], base: PipelineSettings | None = None
) -> PipelineSettings:
    """Build settings from name -> value pairs over `base` (the node's defaults), validated."""
    return (base if base is not None else PipelineSettings()).updated(values)


def defaults() -> dict[str, Any]:
    """Return the node's default value of every setting, by name (lists for vectors)."""
    return PipelineSettings().parameters()
