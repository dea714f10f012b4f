"""Compare output folders byte for byte."""

import filecmp
from pathlib import Path


def same_tree(left: Path, right: Path) -> bool:
    """Tell whether two flat folders hold the same file names with the same bytes."""
    names = sorted(path.name for path in left.iterdir())
    if names != sorted(path.name for path in right.iterdir()):
        return False
    return all(filecmp.cmp(left / name, right / name, shallow=False) for name in names)
