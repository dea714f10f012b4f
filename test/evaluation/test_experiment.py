"""The grasp-set comparison (evaluation.experiment) with its report's table and plot."""

from __future__ import annotations

import json

from mvbb_ros.evaluation.experiment import compare_grasp_sets
from mvbb_ros.evaluation.report import format_comparison, plot_quality_space
from support.grasp_targets import l_shape_mesh


def test_compare_grasp_sets_table_and_plot(tmp_path):
    comparison = compare_grasp_sets(l_shape_mesh(), name='L', thresholds=(0.9,), spherical_step=45)
    names = [result.name for result in comparison.sets]
    assert names == ['spherical', 'root box', 't=0.90']
    assert comparison.sets[1].candidates == 24
    rows = comparison.summary()
    assert rows[0]['candidates'] == 2 * 8 + 3 * 8 * 8
    for row in rows[1:]:
        assert 'holds' in row and 'quality_ratio' in row
    table = format_comparison(comparison)
    assert table.count('\n') == 1 + len(rows)
    json.dumps(comparison.to_dict())  # JSON-ready
    path = plot_quality_space(comparison, tmp_path / 'fig.png')
    assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert [p.name for p in tmp_path.iterdir()] == ['fig.png']  # no temporary left behind
