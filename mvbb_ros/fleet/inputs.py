"""
The bags of a fleet run and the settings of a sweep.

Inputs are bag paths (a rosbag2 directory, a ``.bag``, ``.db3`` or ``.mcap`` file), globs, folders
(searched for bags, not entering a bag) or manifest files (one input per line, ``#`` comments,
relative paths taken from the manifest's folder). A path that does not exist stays in the list:
the run reports it as a failed bag and goes on with the others.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
import glob
import itertools
import os
from pathlib import Path

from mvbb_ros.pipeline.settings import PipelineSettings
from mvbb_ros.pipeline.settings_text import parse_assignments

#: File suffixes of bags (a rosbag2 bag may also be a directory with metadata.yaml).
BAG_SUFFIXES = ('.bag', '.db3', '.mcap')
_GLOB_CHARACTERS = frozenset('*?[')


class InputError(Exception):
    """The inputs or the sweep cannot be used: the message says which and why."""


def is_bag(path: Path) -> bool:
    """Return whether `path` looks like a bag: a rosbag2 directory or a bag file."""
    if path.is_dir():
        return (path / 'metadata.yaml').is_file()
    return path.is_file() and path.suffix in BAG_SUFFIXES


def _bags_in_folder(folder: Path) -> list[Path]:
    found = []
    for root, directories, files in os.walk(folder):
        here = Path(root)
        if (here / 'metadata.yaml').is_file():
            found.append(here)
            directories.clear()  # a bag's own files are not bags
            continue
        directories.sort()
        found += [here / name for name in sorted(files) if Path(name).suffix in BAG_SUFFIXES]
    return found


def _read_manifest(path: Path) -> list[str]:
    entries = []
    for line in path.read_text().splitlines():
        text = line.split('#', 1)[0].strip()
        if text:
            entry = Path(text).expanduser()
            entries.append(str(entry if entry.is_absolute() else path.parent / entry))
    return entries


def expand_inputs(inputs: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """
    Return the bags that `inputs` name, in the order given, each once.

    :raises InputError: when a glob matches nothing, a folder holds no bag, or a manifest
        cannot be read (a path that does not exist is kept, to be reported per bag).
    """
    bags: list[Path] = []
    pending = [str(item) for item in inputs]
    pending.reverse()
    seen_manifests: set[Path] = set()
    while pending:
        text = pending.pop()
        path = Path(text).expanduser()
        if is_bag(path):
            bags.append(path)
        elif path.is_dir():
            inside = _bags_in_folder(path)
            if not inside:
                raise InputError(
                    f'the folder {path} holds no bag (rosbag2 folder, .bag, .db3, .mcap)'
                )
            bags += inside
        elif path.is_file():
            if path.resolve() in seen_manifests:
                raise InputError(f'the manifest {path} includes itself')
            seen_manifests.add(path.resolve())
            try:
                entries = _read_manifest(path)
            except (OSError, UnicodeDecodeError) as error:
                raise InputError(f'cannot read the manifest {path}: {error}') from error
            pending += reversed(entries)
        elif _GLOB_CHARACTERS & set(text):
            matches = sorted(glob.glob(os.path.expanduser(text)))
            if not matches:
                raise InputError(f'{text} matches nothing')
            pending += reversed(matches)
        else:
            bags.append(path)  # missing: reported per bag, the others go on
    unique: dict[Path, Path] = {}
    for bag in bags:
        unique.setdefault(bag.resolve(), bag)
    return list(unique.values())


def bag_name(path: Path) -> str:
    """Return the name of a bag's output folder: the folder's name, or the file's stem."""
    resolved = path.resolve()
    return resolved.name if path.is_dir() or not resolved.suffix else resolved.stem


def bag_names(bags: Sequence[Path]) -> list[str]:
    """
    Return each bag's output name.

    :raises InputError: when two bags would write to the same output folder.
    """
    names = [bag_name(bag) for bag in bags]
    clashes: dict[str, list[str]] = {}
    for name, bag in zip(names, bags, strict=True):
        clashes.setdefault(name, []).append(str(bag))
    doubles = {name: paths for name, paths in clashes.items() if len(paths) > 1}
    if doubles:
        text = '; '.join(f'{name}: {", ".join(paths)}' for name, paths in doubles.items())
        raise InputError(f'bags with the same name would write to the same output: {text}')
    return names


@dataclass(frozen=True)
class Setting:
    """
    One point of a sweep: its label (a folder name and the summary's column) and its settings.

    :ivar label: ``name=value,name=value`` as given, or '' without a sweep.
    :ivar settings: the run's settings with the sweep's values applied.
    """

    label: str
    settings: PipelineSettings


def sweep_settings(base: PipelineSettings, sweeps: Sequence[str]) -> list[Setting]:
    """
    Return the grid of settings that ``--sweep NAME=V1,V2,...`` options describe.

    Each option names one parameter (any of the node's) and its values; several options make a
    grid, every combination once, in the order given. No option: the base settings alone.

    :raises InputError: for a malformed option or a bad parameter name or value.
    """
    axes: list[list[str]] = []
    names: list[str] = []
    for option in sweeps:
        name, separator, values = option.partition('=')
        name = name.strip()
        if not separator or not name or not values.strip():
            raise InputError(f'--sweep takes NAME=V1,V2,..., got {option!r}')
        if name in names:
            raise InputError(f'--sweep names {name} twice')
        names.append(name)
        axes.append([value.strip() for value in values.split(',') if value.strip()])
    if not axes:
        return [Setting('', base)]
    grid = []
    for combination in itertools.product(*axes):
        label = ','.join(f'{name}={value}' for name, value in zip(names, combination, strict=True))
        try:
            assignments = parse_assignments(
                [f'{name}:={value}' for name, value in zip(names, combination, strict=True)]
            )
            settings = base.updated(assignments)
        except ValueError as error:
            raise InputError(f'--sweep {label}: {error}') from error
        grid.append(Setting(label, settings))
    return grid
