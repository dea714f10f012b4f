"""
Relative links and pictures in the README, the changelog and docs/ resolve.

A link ``[text](path)`` or ``![alt](path)`` to a file must name a file of the repository; a link
with ``#anchor`` must name a heading of its target, spelt as GitHub spells anchors. Links to
other sites are not followed.
"""

from collections import Counter
from pathlib import Path
import re

import pytest

REPO_ROOT = next(
    path for path in Path(__file__).resolve().parents if (path / 'package.xml').is_file()
)
PAGES = sorted(
    [REPO_ROOT / 'README.md', REPO_ROOT / 'CHANGELOG.md', *(REPO_ROOT / 'docs').glob('*.md')]
)
LINK = re.compile(r'!?\[[^\]]*\]\(([^)\s]+)\)')
FENCE = re.compile(r'^(```|~~~)')
HEADING = re.compile(r'^(#{1,6})\s+(.*?)\s*#*\s*$')


def _prose_lines(text: str) -> list[str]:
    """Return the lines of a Markdown page outside fenced code blocks."""
    lines = []
    fenced = False
    for line in text.splitlines():
        if FENCE.match(line.strip()):
            fenced = not fenced
            continue
        if not fenced:
            lines.append(line)
    return lines


def github_anchor(heading: str) -> str:
    """Return GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', heading).lower()
    text = ''.join(char for char in text if char.isalnum() or char in ' -_')
    return text.replace(' ', '-')


def anchors(page: Path) -> set[str]:
    """Return every anchor of a page's headings, duplicates numbered as GitHub numbers them."""
    seen: Counter[str] = Counter()
    found = set()
    for line in _prose_lines(page.read_text()):
        match = HEADING.match(line)
        if not match:
            continue
        anchor = github_anchor(match.group(2))
        found.add(anchor if not seen[anchor] else f'{anchor}-{seen[anchor]}')
        seen[anchor] += 1
    return found


def relative_links(page: Path) -> list[str]:
    """Return the targets of a page's links that are not on another site."""
    targets = []
    for line in _prose_lines(page.read_text()):
        line = re.sub(r'`[^`]*`', '', line)
        for target in LINK.findall(line):
            if not re.match(r'[a-z][a-z0-9+.-]*:', target):
                targets.append(target)
    return targets


def test_anchors_are_spelt_as_github_spells_them():
    """The slug rule on headings of these pages: code, dots and parentheses go, case folds."""
    assert github_anchor('Box fit: `benchmarks/mvbb.py`') == 'box-fit-benchmarksmvbbpy'
    assert github_anchor('Setting `up_direction`') == 'setting-up_direction'
    assert github_anchor("The paper's Table I") == 'the-papers-table-i'


def test_a_broken_link_is_found(tmp_path: Path):
    """The check itself: a missing file and a missing heading are both reported."""
    page = tmp_path / 'page.md'
    page.write_text('# Title\n\n[a](missing.md) [b](#no-such-heading) [c](#title)\n')
    assert relative_links(page) == ['missing.md', '#no-such-heading', '#title']
    assert anchors(page) == {'title'}


@pytest.mark.parametrize('page', PAGES, ids=lambda page: str(page.relative_to(REPO_ROOT)))
def test_relative_links_resolve(page: Path):
    """Every relative link names an existing file, and its anchor a heading of that file."""
    broken = []
    for target in relative_links(page):
        path, _, anchor = target.partition('#')
        resolved = (page.parent / path).resolve() if path else page
        if not resolved.exists():
            broken.append(f'{target}: no file {resolved}')
        elif anchor and resolved.suffix == '.md' and anchor not in anchors(resolved):
            broken.append(f'{target}: no heading #{anchor} in {resolved.name}')
    assert not broken, f'{page.name}: ' + '; '.join(broken)


def test_every_picture_in_docs_is_shown_somewhere():
    """A picture under docs/ that no page shows is stale: draw it into a page or delete it."""
    shown = set()
    for page in PAGES:
        for target in relative_links(page):
            shown.add((page.parent / target.partition('#')[0]).resolve())
    pictures = {path.resolve() for path in (REPO_ROOT / 'docs').glob('*.png')}
    assert not pictures - shown, sorted(str(path.name) for path in pictures - shown)
