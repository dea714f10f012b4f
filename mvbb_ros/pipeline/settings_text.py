"""
The settings as text: ``name:=value`` assignments, ROS parameter files and ``config/``.

``mvbb ... -p name:=value`` and the demo read assignments (:func:`parse_assignments`), and
``--params-file`` a ROS parameter file (:func:`read_params_file`), as ROS does: values are
YAML scalars or lists, checked against :data:`~mvbb_ros.pipeline.specs.SPECS`. The files
of ``config/`` are written from the same table (:func:`config_files`, ``tools/make_config.py``).
No ROS import.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
import os
from pathlib import Path
import re
import textwrap
from typing import Any

from mvbb_ros.pipeline.settings import (
    is_number,
    is_ros_parameter,
    PipelineSettings,
    PRESETS,
    unknown_setting_reason,
)
from mvbb_ros.pipeline.specs import SPEC_BY_NAME, SPECS
import yaml


def parse_assignments(assignments: Iterable[str]) -> dict[str, Any]:
    """
    Parse `name:=value` strings (as `ros2 run ... -p` takes) into typed values.

    Values are read as YAML scalars or lists (true, 0.9, 20, [0, 0, 1], area), like ROS does.

    :raises ValueError: for a malformed assignment or an unknown name.
    """
    parsed: dict[str, Any] = {}
    for text in assignments:
        name, separator, raw = text.partition(':=')
        if not separator or not name:
            raise ValueError(f'expected name:=value, got {text!r}')
        if name not in SPEC_BY_NAME:
            raise ValueError(unknown_setting_reason(name))
        value = yaml.safe_load(raw) if raw else ''
        if (
            SPEC_BY_NAME[name].kind is float
            and isinstance(value, int)
            and not isinstance(value, bool)
        ):
            value = float(value)
        parsed[name] = value
    return parsed


def format_assignment(name: str, value: Any) -> str:
    """Return ``name:=value`` that :func:`parse_assignments` (and ROS) reads back as `value`."""
    return f'{name}:={_yaml_value(value)}'


def read_params_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """
    Return the ``ros__parameters`` of a ROS parameter file (the first node entry with some).

    rclpy's own parameters (:func:`is_ros_parameter`, e.g. ``use_sim_time``) are left out; any
    other name that is no setting makes :meth:`PipelineSettings.updated` fail, naming it.

    :raises ValueError: when the file has no ``<node>: ros__parameters:`` mapping.
    :raises OSError: when it cannot be read.
    """
    with open(path) as handle:
        document = yaml.safe_load(handle)
    if isinstance(document, dict):
        for entry in document.values():
            if isinstance(entry, dict) and isinstance(entry.get('ros__parameters'), dict):
                values = {
                    name: value
                    for name, value in entry['ros__parameters'].items()
                    if not is_ros_parameter(str(name))
                }
                for name, value in values.items():
                    spec = SPEC_BY_NAME.get(name)
                    if spec is not None and spec.kind is float and is_number(value):
                        values[name] = float(value)
                return values
    raise ValueError(f'{path} has no <node>: ros__parameters: mapping')


def params_files(arguments: Sequence[str]) -> list[str]:
    """Return the parameter files named by ``--params-file PATH`` in a ROS command line."""
    return [
        arguments[index + 1]
        for index, word in enumerate(arguments[:-1])
        if word == '--params-file'
    ]


def _section_matches(section: str, node: str) -> bool:
    """Tell whether a parameter file's top-level key applies to the fully qualified `node`."""
    key = '/' + section.lstrip('/')
    if key in ('/**', node):
        return True
    pattern = re.escape(key).replace(r'/\*\*', '(/.*)?').replace(r'\*', '[^/]*')
    return re.fullmatch(pattern, node) is not None


def unmatched_params_files(arguments: Sequence[str], node: str) -> list[str]:
    """
    Return one line for each parameter file of `arguments` with no section for `node`.

    ROS applies a file's ``<node>: ros__parameters:`` section only to a node of that name (or
    the wildcards ``/**``, ``*``): a misspelt name leaves every value in the file unused, silently.

    :param arguments: the process's command line (``--params-file PATH`` pairs are read).
    :param node: the node's fully qualified name, e.g. ``/decomposer``.
    """
    lines = []
    for path in params_files(arguments):
        try:
            document = yaml.safe_load(Path(path).read_text(encoding='utf-8'))
        except (OSError, yaml.YAMLError):
            continue  # rclpy says what is wrong with an unreadable or malformed file
        sections = [str(key) for key in document] if isinstance(document, dict) else []
        if sections and not any(_section_matches(section, node) for section in sections):
            lines.append(
                f'parameter file {path} has no section for node {node} (its sections: '
                f'{", ".join(sections)}); none of its values is used'
            )
    return lines


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, list):
        return '[' + ', '.join(repr(float(v)) for v in value) + ']'
    return repr(value) if isinstance(value, float) else str(value)


def parameters_yaml(settings: PipelineSettings, header: str, width: int = 95) -> str:
    """
    Return a ROS parameter file (``/**: ros__parameters:``) of `settings`, every entry described.

    ``config/decomposer.yaml`` (the node's defaults) and ``config/paper.yaml`` are made by it
    (``tools/make_config.py``); a test checks that they are up to date.

    :param settings: the values to write.
    :param header: comment lines (without ``#``) put at the top.
    :param width: the line length to wrap the descriptions at.
    """
    lines = [f'# {line}'.rstrip() for line in header.strip().splitlines()]
    lines += ['/**:', '  ros__parameters:']
    for spec in SPECS:
        lines += textwrap.wrap(
            spec.description, width, initial_indent='    # ', subsequent_indent='    # '
        )
        value = settings.value(spec.name)
        if spec.machine_default is not None and value == spec.default:
            # The same file on every machine: the default is named, not this machine's value.
            lines.append(f'    # {spec.name}: {spec.machine_default}   (unset: the default)')
        elif spec.kind is list and not value:
            placeholder = '[x, y, z]' if spec.vector_length == 3 else '[...]'
            lines.append(f'    # {spec.name}: {placeholder}   (unset: off)')
        else:
            lines.append(f'    {spec.name}: {_yaml_value(value)}')
    return '\n'.join(lines) + '\n'


#: The parameter files in ``config/``: file name -> (preset, header comment).
CONFIG_FILES: dict[str, tuple[str, str]] = {
    'decomposer.yaml': (
        'node',
        """
Default parameters of the mvbb_ros decomposer node (every one is declared with a
description and range; `ros2 param describe /decomposer <name>` shows them).
Use: ros2 run mvbb_ros decomposer --ros-args --params-file <this file>
Made from SPECS in mvbb_ros/pipeline/specs.py by tools/make_config.py (a test checks it).
""",
    ),
    'paper.yaml': (
        'paper',
        """
The paper's algorithm (Huebner et al. 2008) in the decomposer node: no filters, min_points 10,
no cap on the boxes; the same as `mvbb decompose --preset paper` and decompose() in Python.
Use: ros2 run mvbb_ros decomposer --ros-args --params-file <this file>
Made from SPECS in mvbb_ros/pipeline/specs.py by tools/make_config.py (a test checks it).
""",
    ),
}


def config_files() -> dict[str, str]:
    """Return the text of every parameter file of ``config/``, by file name."""
    return {
        name: parameters_yaml(PRESETS[preset], header)
        for name, (preset, header) in CONFIG_FILES.items()
    }
