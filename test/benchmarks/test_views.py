"""benchmarks/views.py: its core on one mesh and one view, its tables, configs and command."""

from __future__ import annotations

import json

import pytest
from support.data import load_benchmark, require_shared_data


@pytest.fixture(scope='module')
def bench():
    return load_benchmark('views')


@pytest.fixture(scope='module')
def lemon_view():
    from mvbb_ros.evaluation.views import load_table_object, MODEL_BY_NAME, single_views

    models = require_shared_data('models', 'household_lemon_mesh.ply').parent
    return next(single_views(load_table_object(models, MODEL_BY_NAME['lemon']), 1))


def test_configurations_are_data_and_unknown_parameters_are_skipped(bench):
    configs = [bench.Config.from_data(label, data) for label, data in bench.CONFIGS.items()]
    assert {'paper', 'node'} <= {c.label for c in configs}
    future = bench.Config.from_data(
        'future', {'preset': 'node', 'params': {'grasp_refinement': 'on'}, 'up': True}
    )
    messages = []
    kept = bench.usable_configs([*configs[:2], future], messages.append)
    assert [c.label for c in kept] == [c.label for c in configs[:2]]
    assert len(messages) == 1 and "'future'" in messages[0] and 'grasp_refinement' in messages[0]
    with pytest.raises(ValueError, match='unknown keys'):
        bench.Config.from_data('typo', {'preset': 'node', 'parms': {}})
    up = bench.Config('up', 'node', {'max_boxes': 4}, up=True)
    settings = up.settings(0.9, (0.0, -1.0, 0.0))
    assert settings.value('up_direction') == [0.0, -1.0, 0.0]
    assert settings.value('gain_threshold') == 0.9 and settings.value('max_boxes') == 4
    assert bench.Config('no', 'node').settings(0.9, (0.0, -1.0, 0.0)).value('up_direction') == []
    assert bench.Config('p', 'paper').settings(0.98).value('min_points') == 10


def test_the_core_measures_one_view_and_prints_every_table(bench, lemon_view):
    configs = [
        bench.Config('node', 'node', up=True),
        bench.Config('future', 'node', {'no_such_parameter': 1}),
    ]
    log = []
    results = bench.run([lemon_view], configs, thresholds=(0.9, 0.94), log=log.append)
    assert results.configs == ['node'] and 'future' in results.skipped
    assert len(results.views) == 2
    for row in results.views:
        assert tuple(row) == bench.VIEW_COLUMNS
        assert row['mesh'] == 'lemon' and row['view'] == 0
        assert 0.0 <= row['coverage'] <= 1.0 and row['volume_ratio'] >= 0.0
        assert 0 <= row['thin'] <= row['boxes'] and row['ms'] > 0.0
    (grasp,) = results.grasps
    assert tuple(grasp) == bench.GRASP_COLUMNS
    assert grasp['pairs'] == bench.STEADY_FRAMES - 1 and 0 <= grasp['same_pairs'] <= 3
    assert grasp['top1'] <= grasp['top5']
    text = results.tables()
    for header in (
        bench.VIEW_TABLE_HEADER,
        bench.GRASP_TABLE_HEADER,
        ('mesh', 'node cov', 'node vol', 'node thin', 'node boxes'),
    ):
        assert '| ' + ' | '.join(header) + ' |' in text
    assert '| node | 0.94 | 1 |' in text and '| lemon |' in text


def test_real_scans_give_boxes_and_plates_per_threshold(bench):
    from mvbb_ros.evaluation.views import RealScan
    import numpy as np

    path = require_shared_data('scans', 'mosd_learn33_obj5.npy')
    scan = RealScan(path.stem, np.load(path))
    rows = bench.measure_scan(scan, bench.Config('node', 'node'), (0.9, 0.98))
    assert [tuple(row) for row in rows] == [bench.SCAN_COLUMNS] * 2
    assert rows[0]['boxes'] <= rows[1]['boxes'] and rows[0]['boxes'] >= 1
    table = bench.scan_table(rows, ['node'])
    assert '| ' + ' | '.join(bench.SCAN_TABLE_HEADER) + ' |' in table


def test_the_command_runs_one_mesh_and_writes_its_rows(bench, tmp_path, capsys):
    require_shared_data('models', 'household_lemon_mesh.ply')
    out = tmp_path / 'rows.json'
    pictures = tmp_path / 'pictures'
    argv = ['--views', '1', '--meshes', 'lemon', '--config', 'node', '--no-scans']
    assert bench.main([*argv, '--no-grasps', '--json', str(out)]) == 0
    printed = capsys.readouterr().out
    assert '## Single views: means over views' in printed and '## Grasps' not in printed
    raw = json.loads(out.read_text())
    assert set(raw['configs']) == {'node'} and len(raw['views']) == 3 and raw['grasps'] == []
    assert bench.main(['--views', '1', '--meshes', 'mug', '--config', 'paper', '--no-scans',
                       '--pictures', str(pictures)]) == 0  # fmt: skip
    assert (pictures / 'mug_0.png').stat().st_size > 10_000
    assert bench.main(['--config', 'nonexistent']) == 2
