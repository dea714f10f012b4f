"""
numba's cache of the kernels: the one log line of a first run, and a read-only package.

A colcon install space belongs to whoever built it, so numba cannot write its cache beside the
modules; it then caches in the user's cache directory (``~/.cache/numba``). The test runs a copy
of the package that is really read-only (a read-only bind mount in a private mount namespace
when the tests run as root, who may write anywhere; plain file modes otherwise) in a new Python
with its own HOME and without NUMBA_CACHE_DIR, twice: the first run compiles and says so in one
line, the second finds everything in the user's cache.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys

from mvbb_ros import kernels
import pytest
from support.data import REPO_ROOT
from support.mounts import read_only_command

#: What the child prints: where the package came from, whether it could write there, the lines.
CHILD = """
import json, os
import mvbb_ros
from mvbb_ros.kernels import warm_up_logged
from mvbb_ros.kernels import announce_cold_start
lines = []
announce_cold_start(lines.append)
report = warm_up_logged(lines.append)
folder = os.path.dirname(mvbb_ros.__file__)
print(json.dumps({'package': folder, 'writable': os.access(folder, os.W_OK), 'lines': lines,
                  'compiled': len(report.compiled)}))
"""


@pytest.mark.slow
def test_a_read_only_package_caches_in_the_users_cache_directory(tmp_path):
    install = tmp_path / 'install'
    shutil.copytree(
        REPO_ROOT / 'mvbb_ros', install / 'mvbb_ros', ignore=shutil.ignore_patterns('__pycache__')
    )
    home = tmp_path / 'home'
    home.mkdir()
    environment = {
        key: value
        for key, value in os.environ.items()
        if key not in ('NUMBA_CACHE_DIR', 'XDG_CACHE_HOME', 'PYTHONPATH')
    }
    environment.update(HOME=str(home), PYTHONPATH=str(install), PYTHONDONTWRITEBYTECODE='1')
    command = [*read_only_command(install), sys.executable, '-c', CHILD]

    def run() -> dict:
        result = subprocess.run(
            command,
            cwd=tmp_path,  # not the work tree, whose package `python -c` would find first
            env=environment,
            capture_output=True,
            text=True,
            check=False,
            timeout=600,
        )
        assert result.returncode == 0, result.stderr
        return json.loads(result.stdout.strip().splitlines()[-1])

    first = run()
    assert Path(first['package']) == install / 'mvbb_ros' and not first['writable']
    assert first['compiled'] > 0
    assert len(first['lines']) == 2
    assert first['lines'][0].startswith('compiling geometry kernels before the first cloud')
    assert re.fullmatch(
        r'compiling geometry kernels, first run only \(\d+\.\d s\)', first['lines'][1]
    )
    cache = home / '.cache' / 'numba'
    index = {path.name.split('.')[0] for path in cache.rglob('*.nbi')}
    assert {'filtering', 'outliers', 'decode', 'objects', 'mirror', 'fill'} <= index
    assert list(cache.rglob('*.nbc')), 'the machine code is cached too'
    assert not list(install.rglob('__pycache__')), 'nothing written into the package'

    second = run()
    assert second['compiled'] == 0 and second['lines'] == [], 'the second run starts warm'


def test_every_kernel_module_is_listed_and_warms():
    report = kernels.warm_up()
    assert report.seconds >= 0.0 and report.compile_seconds >= 0.0
    for name in kernels.KERNEL_MODULES:
        assert callable(getattr(sys.modules[name], 'warm_up', None)), name
    package = REPO_ROOT / 'mvbb_ros'
    with_kernels = {
        '.'.join(path.relative_to(REPO_ROOT).with_suffix('').parts)
        for path in package.rglob('*.py')
        if re.search(r'^@(nb\.)?njit\(.*cache=True', path.read_text(), re.MULTILINE | re.DOTALL)
    }
    assert with_kernels <= set(kernels.KERNEL_MODULES), 'a module with cached kernels is unlisted'


_PIPELINE_AFTER_WARM_UP = """
import importlib, json, sys
sys.path.insert(0, sys.argv[1])
from mvbb_ros import kernels
from mvbb_ros.evaluation.synthetic import segmented_object_cloud
from mvbb_ros.pipeline.process import process_points
from mvbb_ros.pipeline.settings import PipelineSettings
from support.shapes import l_shape_points

kernels.warm_up()
def signatures():
    return {
        name: set(map(str, dispatcher.signatures))
        for module in kernels.KERNEL_MODULES
        for name, dispatcher in kernels._dispatchers(importlib.import_module(module))
    }
before = signatures()
up = PipelineSettings().updated({'up_direction': [0.0, -0.8191520, -0.5735764]})
for cloud in (l_shape_points(), segmented_object_cloud('mug', seed=1)):
    for settings in (PipelineSettings(), up):
        process_points(cloud, settings)
after = signatures()
new = {name: sorted(after[name] - before[name]) for name in after}
print(json.dumps({name: types for name, types in new.items() if types}))
"""


@pytest.mark.slow
def test_the_warm_up_compiles_what_the_pipeline_runs():
    """
    After :func:`kernels.warm_up` a cloud through the pipeline compiles nothing more.

    numba compiles each new argument type apart (read-only arrays too): a kernel the warm-up
    calls with other types than the pipeline compiles on the first cloud, for seconds (the CLI
    then said "compiling geometry kernels" after set-up had warmed everything).
    """
    completed = subprocess.run(
        [sys.executable, '-c', _PIPELINE_AFTER_WARM_UP, str(REPO_ROOT / 'test')],
        capture_output=True,
        text=True,
        timeout=600,
        check=True,
    )
    assert json.loads(completed.stdout.strip().splitlines()[-1]) == {}


COLD = """
import json
from mvbb_ros import kernels
lines = []
said = kernels.announce_cold_start(lines.append)
print(json.dumps({'cold': kernels.cold_modules(), 'said': said, 'lines': lines}))
"""


def test_a_first_start_is_announced_before_anything_compiles(tmp_path):
    install = tmp_path / 'install'
    shutil.copytree(
        REPO_ROOT / 'mvbb_ros', install / 'mvbb_ros', ignore=shutil.ignore_patterns('__pycache__')
    )
    environment = {key: value for key, value in os.environ.items() if key != 'NUMBA_CACHE_DIR'}
    environment.update(HOME=str(tmp_path), PYTHONPATH=str(install))
    result = subprocess.run(
        [sys.executable, '-c', COLD],
        cwd=tmp_path,
        env=environment,
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    answer = json.loads(result.stdout)
    assert answer['cold'] == list(kernels.KERNEL_MODULES) and answer['said']
    assert len(answer['lines']) == 1 and 'first start' in answer['lines'][0]
    assert not kernels.cold_modules(), 'the work tree is warm (set-up warmed it)'
