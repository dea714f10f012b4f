"""
Pipeline settings: one table of every tunable, its type, default, range and meaning.

The node declares one ROS parameter per entry, `mvbb bag process -p name:=value` parses the same
names, and `config/decomposer.yaml` lists the defaults. Validation lives here, so a bad value is
refused with the same reason wherever it comes from. No ROS import.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, fields, replace
import math
from typing import Any

#: What the range checks accept: (low, high) inclusive; None for no bound.
Range = tuple[float | None, float | None]


@dataclass(frozen=True)
class SettingSpec:
    """
    One tunable: name, Python type, inclusive range or choices, and a description.

    Defaults are the field defaults of :class:`PipelineSettings` (one place). `read_only`
    settings can only be given at start-up (ROS read-only parameters).
    """

    name: str
    kind: type
    description: str
    value_range: Range | None = None
    choices: tuple[str, ...] | None = None
    vector_length: int | None = None
    read_only: bool = False


SPECS: tuple[SettingSpec, ...] = (
    # Decomposition (paper Section III).
    SettingSpec(
        'gain_threshold',
        float,
        "Accept a split while the volume gain Theta* is below this (the paper's t); "
        'lower means fewer boxes.',
        (0.0, 1.0),
    ),
    SettingSpec(
        'min_points',
        int,
        'Boxes with fewer points than this are dropped as noise.',
        (1, 1_000_000),
    ),
    SettingSpec('max_boxes', int, 'Upper bound on the number of leaf boxes.', (1, 256)),
    SettingSpec(
        'split_measure',
        str,
        "Split measure theta: 'area' is the paper's 2D projection measure, 'volume' "
        "uses the product of the parts' three extents.",
        choices=('area', 'volume'),
    ),
    SettingSpec(
        'rescore_cuts',
        int,
        'Re-score the best K cuts with real box fits (0 = the paper).',
        (0, 32),
    ),
    SettingSpec(
        'seed', int, 'Random seed of the box fit (results are deterministic).', (0, 2**31 - 1)
    ),
    # Filtering (voxel grid in numpy or Open3D; statistical outliers with Open3D).
    SettingSpec(
        'voxel_size',
        float,
        'Voxel down-sampling edge length in metres; 0 turns it off.',
        (0.0, 10.0),
    ),
    SettingSpec(
        'voxel_backend',
        str,
        "Voxel down-sampling implementation: 'numpy' (default, the same centroids as "
        "Open3D's, computed from the decoded float32 points) or 'open3d'.",
        choices=('numpy', 'open3d'),
    ),
    SettingSpec(
        'outlier_neighbors',
        int,
        'Neighbours of the statistical outlier removal; 0 turns it off.',
        (0, 1000),
    ),
    SettingSpec(
        'outlier_std_ratio',
        float,
        'Statistical outlier removal: drop points whose mean neighbour distance is this '
        'many standard deviations above the mean.',
        (0.01, 100.0),
    ),
    SettingSpec(
        'crop_min',
        list,
        'Lower corner (x, y, z) of a crop box in metres in the cloud frame; empty '
        'turns cropping off.',
        vector_length=3,
    ),
    SettingSpec(
        'crop_max',
        list,
        'Upper corner (x, y, z) of the crop box in metres; empty turns it off.',
        vector_length=3,
    ),
    # Grasps (paper Section IV-B).
    SettingSpec(
        'gripper_max_width',
        float,
        'Largest gripper opening in metres; faces needing more are ungraspable.',
        (1e-4, 10.0),
    ),
    SettingSpec(
        'standoff',
        float,
        'Pre-grasp distance of the gripper from the face centre in metres.',
        (0.0, 10.0),
    ),
    SettingSpec(
        'approach_axis',
        str,
        'Gripper frame axis that points along the approach direction.',
        choices=('z', 'x'),
    ),
    SettingSpec(
        'grasp_strategy',
        str,
        'Ranking: largest box first, smallest, outermost from the centroid, or nearest '
        'to the sensor.',
        choices=('largest', 'smallest', 'outermost', 'nearest'),
    ),
    SettingSpec(
        'up_direction',
        list,
        'Unit up vector (x, y, z) in the cloud frame; approaches from below are removed. '
        'Empty: no support filter.',
        vector_length=3,
    ),
    SettingSpec(
        'max_grasps',
        int,
        'Publish at most this many grasps, best first; 0 publishes all.',
        (0, 10000),
    ),
    # Node behaviour.
    SettingSpec(
        'publish_tree', bool, 'Also publish the non-leaf boxes of the hierarchy on ~/tree.'
    ),
    SettingSpec(
        'reliable_input',
        bool,
        'Subscribe with reliable QoS and a deep queue (lossless bag evaluation) instead '
        'of best effort, keep last 1.',
        read_only=True,
    ),
)

SPEC_BY_NAME: dict[str, SettingSpec] = {spec.name: spec for spec in SPECS}


@dataclass(frozen=True)
class PipelineSettings:
    """Every tunable of the pipeline, with its default; :data:`SPECS` describes each field."""

    gain_threshold: float = 0.94
    min_points: int = 25
    max_boxes: int = 16
    split_measure: str = 'area'
    rescore_cuts: int = 0
    seed: int = 0
    voxel_size: float = 0.005
    voxel_backend: str = 'numpy'
    outlier_neighbors: int = 20
    outlier_std_ratio: float = 2.0
    crop_min: tuple[float, ...] = ()
    crop_max: tuple[float, ...] = ()
    gripper_max_width: float = 0.08
    standoff: float = 0.05
    approach_axis: str = 'z'
    grasp_strategy: str = 'largest'
    up_direction: tuple[float, ...] = ()
    max_grasps: int = 0
    publish_tree: bool = True
    reliable_input: bool = False

    def updated(self, changes: Mapping[str, Any]) -> PipelineSettings:
        """
        Return a copy with `changes` applied after validating each of them.

        :raises ValueError: naming the first invalid setting and why.
        """
        normalised = {}
        for name, value in changes.items():
            reason = validate_setting(name, value)
            if reason is not None:
                raise ValueError(reason)
            normalised[name] = _normalise(SPEC_BY_NAME[name], value)
        settings = replace(self, **normalised)
        reason = validate_combination(settings)
        if reason is not None:
            raise ValueError(reason)
        return settings


def _normalise(spec: SettingSpec, value: Any) -> Any:
    if spec.kind is list:
        return tuple(float(v) for v in value)
    if spec.kind is float:
        return float(value)
    return value


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def validate_setting(name: str, value: Any) -> str | None:
    """Return why `value` is not acceptable for setting `name`, or None when it is."""
    spec = SPEC_BY_NAME.get(name)
    if spec is None:
        return f'unknown setting {name!r}; known: {", ".join(SPEC_BY_NAME)}'
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
    if spec.kind is float and not _is_number(value):
        return f'{spec.name} must be a number, got {value!r}'
    if not math.isfinite(value):
        return f'{spec.name} must be finite, got {value!r}'
    low, high = spec.value_range or (None, None)
    if (low is not None and value < low) or (high is not None and value > high):
        return f'{spec.name} must be in [{low}, {high}], got {value!r}'
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
    if len(values) not in (0, spec.vector_length) or not all(_is_number(v) for v in values):
        return f'{spec.name} must be empty or {spec.vector_length} numbers, got {value!r}'
    if not all(math.isfinite(v) for v in values):
        return f'{spec.name} must be finite, got {value!r}'
    if spec.name == 'up_direction' and values and math.hypot(*values) < 1e-9:
        return f'{spec.name} must not be the zero vector'
    return None


def validate_combination(settings: PipelineSettings) -> str | None:
    """Return why settings that are each valid do not fit together, or None."""
    if bool(settings.crop_min) != bool(settings.crop_max):
        return 'crop_min and crop_max must both be set (3 numbers each) or both empty'
    if settings.crop_min and any(
        low > high for low, high in zip(settings.crop_min, settings.crop_max, strict=True)
    ):
        return f'crop_min {settings.crop_min} must not exceed crop_max {settings.crop_max}'
    return None


def settings_from_mapping(values: Mapping[str, Any]) -> PipelineSettings:
    """Build settings from name -> value pairs (defaults for the rest), validating each."""
    return PipelineSettings().updated(values)


def parse_assignments(assignments: Iterable[str]) -> dict[str, Any]:
    """
    Parse `name:=value` strings (as `ros2 run ... -p` takes) into typed values.

    Values are read as YAML scalars or lists (true, 0.9, 20, [0, 0, 1], area), like ROS does.

    :raises ValueError: for a malformed assignment or an unknown name.
    """
    import yaml

    parsed: dict[str, Any] = {}
    for text in assignments:
        name, separator, raw = text.partition(':=')
        if not separator or not name:
            raise ValueError(f'expected name:=value, got {text!r}')
        if name not in SPEC_BY_NAME:
            raise ValueError(f'unknown setting {name!r}; known: {", ".join(SPEC_BY_NAME)}')
        value = yaml.safe_load(raw) if raw else ''
        if (
            SPEC_BY_NAME[name].kind is float
            and isinstance(value, int)
            and not isinstance(value, bool)
        ):
            value = float(value)
        parsed[name] = value
    return parsed


def defaults() -> dict[str, Any]:
    """Return the default value of every setting, by name (lists for vectors)."""
    base = PipelineSettings()
    return {
        field.name: list(getattr(base, field.name))
        if isinstance(getattr(base, field.name), tuple)
        else getattr(base, field.name)
        for field in fields(base)
    }
