"""
Command-line flags of the pipeline settings, made from :data:`~mvbb_ros.pipeline.specs.SPECS`.

Every setting gets one flag named like its ROS parameter: ``--gain-threshold`` and
``--gain_threshold`` both set ``gain_threshold``, with the parameter's type, range (checked
by the same validation as the node's) and description. Around them: ``--preset`` (``node``,
the node's defaults, or ``paper``), ``--params-file`` (a ROS parameter YAML file such as
``config/decomposer.yaml``) and ``-p name:=value`` (as ``ros2 run ... -p``). They apply in that
order, then the flags, so the later one wins.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from mvbb_ros.pipeline.settings import PipelineSettings, PRESETS
from mvbb_ros.pipeline.settings_text import parse_assignments, read_params_file
from mvbb_ros.pipeline.specs import SettingSpec, SPECS
from mvbb_ros.pipeline.stage_settings import NodeSettings

#: Short aliases of a few flags.
SHORT_FLAGS: dict[str, str] = {'gain_threshold': '-t'}


def _flags(spec: SettingSpec) -> list[str]:
    dashed = '--' + spec.name.replace('_', '-')
    names = [dashed] if dashed == '--' + spec.name else [dashed, '--' + spec.name]
    if spec.name in SHORT_FLAGS:
        names.insert(1, SHORT_FLAGS[spec.name])
    return names


def _help(spec: SettingSpec) -> str:
    text = spec.description.rstrip('.')
    default, paper = spec.default, PRESETS['paper'].value(spec.name)
    shown = 'unset' if default == [] else default
    extra = '' if paper == default else f'; paper: {"unset" if paper == [] else paper}'
    return f'{text} (default {shown}{extra})'.replace('%', '%%')


def _argument_options(spec: SettingSpec) -> dict[str, Any]:
    """Return the add_argument keywords of a setting's flag (its type, choices and help)."""
    options: dict[str, Any] = {'dest': spec.name, 'default': argparse.SUPPRESS}
    options['help'] = _help(spec)
    if spec.kind is bool:
        options['action'] = argparse.BooleanOptionalAction
    elif spec.kind is list:
        options.update(type=float, nargs='*', metavar='V')
        options['help'] += f'; {spec.vector_length} numbers, or none to turn it off'
    elif spec.choices:
        options['choices'] = spec.choices
    else:
        options.update(type=spec.kind, metavar='N' if spec.kind is int else 'X')
    return options


def add_settings_options(
    parser: argparse.ArgumentParser, *, node: bool = False, without: tuple[str, ...] = ()
) -> None:
    """
    Add ``--preset``, ``--params-file``, ``-p`` and one flag per setting to `parser`.

    :param parser: the subcommand's parser.
    :param node: also add the node's own settings (``publish_tree``, ``reliable_input``).
    :param without: settings that get no flag (the subcommand has a flag of that name for
        something else); ``-p name:=value`` still sets them.
    """
    parser.set_defaults(settings_without_flags=without)
    group = parser.add_argument_group(
        'settings',
        "the node's parameters (config/decomposer.yaml); --preset, then --params-file, then "
        '-p, then the flags apply, the later one winning',
    )
    group.add_argument(
        '--preset',
        choices=tuple(PRESETS),
        default='node',
        help="start from the node's defaults (node, the default) or the paper's algorithm "
        '(paper: no filters, min_points 10, no box cap)',
    )
    group.add_argument(
        '--params-file',
        type=Path,
        help='a ROS parameter YAML file (like config/decomposer.yaml)',
    )
    group.add_argument(
        '-p',
        '--param',
        action='append',
        default=[],
        metavar='NAME:=VALUE',
        help='set a parameter, as ros2 run ... -p does (repeatable)',
    )
    for spec in SPECS:
        if (spec.stage is NodeSettings and not node) or spec.name in without:
            continue
        group.add_argument(*_flags(spec), **_argument_options(spec))


def settings_from_args(args: argparse.Namespace) -> PipelineSettings:
    """
    Return the settings the options of :func:`add_settings_options` describe.

    :raises ValueError: naming a bad or unknown setting (or file).
    :raises OSError: when the parameter file cannot be read.
    """
    settings = PRESETS[args.preset]
    if args.params_file is not None:
        settings = settings.updated(read_params_file(args.params_file))
    settings = settings.updated(parse_assignments(args.param))
    without = getattr(args, 'settings_without_flags', ())
    flags = {
        spec.name: getattr(args, spec.name)
        for spec in SPECS
        if hasattr(args, spec.name) and spec.name not in without
    }
    return settings.updated(flags)
