"""The documents that describe the tree agree with it: the README layout, architecture.md."""

from __future__ import annotations

import re

from support.data import REPO_ROOT

PACKAGE = REPO_ROOT / 'mvbb_ros'

#: A table row naming a package folder in its first cell: | `mvbb_ros/geometry/boxfit/` | ... |
FOLDER_ROW = re.compile(r'^\|\s*`(mvbb_ros/(?:[\w]+/)*)`\s*\|', re.M)


def _package_folders() -> set[str]:
    """Return every package folder below mvbb_ros/, as ``mvbb_ros/geometry/boxfit/``."""
    return {
        f'{path.parent.relative_to(REPO_ROOT).as_posix()}/'
        for path in PACKAGE.rglob('__init__.py')
        if path.parent != PACKAGE
    }


def _section(text: str, heading: str) -> str:
    """Return the text under a ``## `` heading, up to the next heading of that level."""
    match = re.search(rf'^## {re.escape(heading)}\s*$(.*?)(?=^## |\Z)', text, re.M | re.S)
    assert match, f'no "## {heading}" section'
    return match.group(1)


def _table_folders(section: str) -> set[str]:
    """Return the package folders the section's table rows name (mvbb_ros/ itself left out)."""
    return set(FOLDER_ROW.findall(section)) - {'mvbb_ros/'}


def test_the_folder_row_pattern_reads_a_table():
    table = (
        '| folder | what |\n| --- | --- |\n| `mvbb_ros/` | the public names |\n'
        '| `mvbb_ros/geometry/boxfit/` | the box fit |\n| `test/` | tests |\n'
    )
    assert _table_folders(table) == {'mvbb_ros/geometry/boxfit/'}
    assert 'mvbb_ros/geometry/boxfit/' in _package_folders()


def test_the_readme_layout_table_has_one_row_per_package_folder():
    section = _section((REPO_ROOT / 'README.md').read_text(), 'Layout')
    rows = FOLDER_ROW.findall(section)
    assert len(rows) == len(set(rows)), f'folders listed twice: {sorted(rows)}'
    assert _table_folders(section) == _package_folders()


def test_the_architecture_tables_name_every_layer_and_subsystem():
    text = (REPO_ROOT / 'docs' / 'architecture.md').read_text()
    named = set(re.findall(r'^\|\s*`((?:\w+/)?\w+/)`\s*\|', _section(text, 'Layers'), re.M))
    folders = {folder.removeprefix('mvbb_ros/') for folder in _package_folders()}
    assert named == folders


def test_the_architecture_tables_name_only_files_that_exist():
    """Each file a row names is in the row's folder (or the package's top level, or box.py)."""
    text = (REPO_ROOT / 'docs' / 'architecture.md').read_text()
    rows = re.findall(r'^\|\s*`((?:\w+/)?\w+/)`\s*\|(.*)$', text, re.M)
    assert len(rows) >= 10
    for folder, rest in rows:
        for name in re.findall(r'`(\w+\.py)`', rest):
            places = (PACKAGE / folder / name, PACKAGE / name, PACKAGE / 'geometry' / name)
            assert any(place.is_file() for place in places), f'{folder}: {name}'
