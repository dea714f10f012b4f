"""
Write the parameter files of config/ from the settings table (SPECS).

Run from the repository root after changing a setting in mvbb_ros/pipeline/specs.py::

    .venv/bin/python tools/make_config.py

``test/pipeline/test_settings.py`` fails while a file is out of date.
"""

from pathlib import Path
import sys

from mvbb_ros.pipeline.settings_text import config_files

CONFIG = Path(__file__).resolve().parents[1] / 'config'


def main() -> int:
    """Write every out-of-date file of config/ and name it."""
    for name, text in config_files().items():
        path = CONFIG / name
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
            print(f'wrote {path}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
