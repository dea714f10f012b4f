"""The installed `mvbb` command as a shell runs it (exit codes, stderr), and `mvbb evaluate`."""

from __future__ import annotations

import json
from pathlib import Path
import signal
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

from mvbb_ros.cli.main import main
import numpy as np
import open3d as o3d
import pytest
from support.grasp_targets import l_shape_mesh

MVBB = Path(sys.executable).parent / 'mvbb'


@pytest.fixture
def cloud(tmp_path: Path) -> Path:
    """Return a .npy file of a 10 x 6 x 6 cm block of points 0.7 m in front of the camera."""
    rng = np.random.default_rng(5)
    path = tmp_path / 'block.npy'
    points = rng.uniform([-0.05, -0.03, 0.7], [0.05, 0.03, 0.76], size=(3000, 3))
    np.save(path, points.astype(np.float32))
    return path


@pytest.mark.slow
def test_a_reader_that_goes_away_ends_the_command_quietly(cloud):
    """`mvbb decompose FILE | head -0`: no traceback, the shell's code for SIGPIPE."""
    command = subprocess.Popen(
        [str(MVBB), 'decompose', str(cloud)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert command.stdout is not None and command.stderr is not None
    command.stdout.close()  # the reader is gone before the first line is written
    errors = command.stderr.read().decode()
    assert command.wait(timeout=120) == 128 + signal.SIGPIPE, errors
    assert 'Traceback' not in errors and 'BrokenPipeError' not in errors, errors
    assert errors == ''


@pytest.mark.slow
def test_the_same_command_with_a_reader_prints_the_report(cloud):
    result = subprocess.run(
        [str(MVBB), 'decompose', str(cloud)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert 'grasp hypotheses' in result.stdout


@pytest.mark.slow
def test_version_is_the_package_version():
    """`mvbb --version` prints the version package.xml declares (setup.py must agree)."""
    manifest = ElementTree.parse(Path(__file__).resolve().parents[2] / 'package.xml')
    declared = manifest.getroot().findtext('version')
    result = subprocess.run([str(MVBB), '--version'], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ['mvbb', declared]


def test_evaluate_command(tmp_path, capsys):
    mesh_path = tmp_path / 'l_shape.ply'
    assert o3d.io.write_triangle_mesh(str(mesh_path), l_shape_mesh())
    code = main(
        [
            'evaluate',
            str(mesh_path),
            '--spherical-step',
            '60',
            '-t',
            '0.94',
            '--json',
            str(tmp_path / 'out.json'),
            '--png',
            str(tmp_path / 'out.png'),
        ]
    )
    assert code == 0
    output = capsys.readouterr().out
    assert 'spherical' in output and 'root box' in output and 't=0.94' in output
    document = json.loads((tmp_path / 'out.json').read_text())
    assert [row['set'] for row in document['sets']] == ['spherical', 'root box', 't=0.94']
    assert (tmp_path / 'out.png').stat().st_size > 0


def test_evaluate_command_reports_bad_input(tmp_path, capsys):
    assert main(['evaluate', str(tmp_path / 'missing.ply')]) == 1
    assert 'missing.ply' in capsys.readouterr().err


@pytest.mark.slow
def test_an_output_that_cannot_be_written_is_one_line(cloud, tmp_path):
    """Not a folder (as a read-only or full disk): one line naming the path, nothing written."""
    blocker = tmp_path / 'not_a_folder'
    blocker.write_text('a file where the output folder should be')
    result = subprocess.run(
        [str(MVBB), 'decompose', str(cloud), '--json', str(blocker / 'result.json')],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 1
    assert 'Traceback' not in result.stderr
    errors = [line for line in result.stderr.splitlines() if 'error' in line]
    assert len(errors) == 1 and 'not_a_folder' in errors[0], result.stderr
    assert blocker.read_text() == 'a file where the output folder should be'


@pytest.mark.parametrize('scene', [True, False])
def test_a_scenes_picture_stands_on_its_table_and_an_objects_on_its_box(
    scene, monkeypatch, tmp_path
):
    """With a table found the views look down onto it; a segmented object keeps its box frame."""
    from mvbb_ros.cli import commands, render
    from mvbb_ros.evaluation.synthetic import segmented_object_cloud, table_top_frame
    from mvbb_ros.pipeline.settings import PipelineSettings

    frames = []
    monkeypatch.setattr(render, 'render_boxes', lambda *_, **options: frames.append(options))
    if scene:
        grid = table_top_frame(1, 2)
        points = grid.points.reshape(-1, 3)
        points = points[np.isfinite(points).all(axis=1)]
    else:
        points = segmented_object_cloud('mug', seed=0)
    commands.decompose_and_report(
        points, PipelineSettings(), json_path=None, png_path=tmp_path / 'p.png', title='t'
    )
    (frame,) = [options['frame'] for options in frames]
    if scene:
        truth = grid.table_plane[:3] / np.linalg.norm(grid.table_plane[:3])
        assert np.degrees(np.arccos(min(1.0, float(frame[:, 2] @ truth)))) < 2.0
    else:
        assert frame == 'box'
