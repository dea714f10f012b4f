"""
The fleet summary: one row per cloud as Parquet and CSV, and a picture of the run.

Columns: the sweep setting, the bag, its status (``processed``, ``resumed``, ``failed``,
``skipped``, ``truncated``), the cloud's topic, index, bag time and header stamp (nanoseconds),
frame, finite and filtered points, objects, boxes, grasps, the top grasp's score, the pipeline's
milliseconds, the note (why the outputs are empty, or which filter removed every grasp), the bag's
retries (Ray ran a task again after its worker died), its time ranges and its range re-runs, and
``done_s`` (when the cloud was finished, seconds after the run started; empty for resumed bags). A
failed bag has one row: its status and, in ``note``, the reason. A message skipped because it does
not deserialize (as `bag process` skips it) has a row of its own after its bag's clouds: status
``skipped``, its topic and bag time, and in ``note`` what the deserializer said. A bag whose
storage failed partway (its output holds the clouds before the break, as `bag process` writes them)
has a last row with status ``truncated`` and, in ``note``, where the storage failed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any, TYPE_CHECKING

from mvbb_ros.common.atomic import atomic_path

if TYPE_CHECKING:
    from mvbb_ros.fleet.run import FleetResult

#: (column, Arrow type name) in order.
COLUMNS: tuple[tuple[str, str], ...] = (
    ('setting', 'string'),
    ('bag', 'string'),
    ('status', 'string'),
    ('topic', 'string'),
    ('index', 'int64'),
    ('timestamp_ns', 'int64'),
    ('stamp_ns', 'int64'),
    ('frame_id', 'string'),
    ('points', 'int64'),
    ('filtered', 'int64'),
    ('objects', 'int64'),
    ('boxes', 'int64'),
    ('grasps', 'int64'),
    ('top_score', 'float64'),
    ('ms', 'float64'),
    ('note', 'string'),
    ('retries', 'int64'),
    ('ranges', 'int64'),
    ('reruns', 'int64'),
    ('done_s', 'float64'),
)


@dataclass(frozen=True)
class SummaryPaths:
    """Where the summary was written (`png` None when no picture was asked for)."""

    parquet: Path
    csv: Path
    png: Path | None


def summary_rows(result: FleetResult) -> list[dict[str, Any]]:
    """Return the summary's rows: every cloud of every bag, and one row per failed bag."""
    rows = []
    for report in result.reports:
        job = report.job
        common = {
            'setting': job.label,
            'bag': job.name,
            'status': report.status,
            'retries': report.retries,
            'ranges': report.ranges,
            'reruns': report.reruns,
        }
        if report.status == 'failed':
            rows.append({**common, 'note': report.error})
            continue
        for values in report.rows:
            done = values.get('done_s')
            top = values.get('top_score')
            rows.append(
                {
                    **common,
                    'topic': values['topic'],
                    'index': values['index'],
                    'timestamp_ns': values['timestamp_ns'],
                    'stamp_ns': values['stamp_ns'],
                    'frame_id': values['frame_id'],
                    'points': values['points'],
                    'filtered': values['filtered'],
                    'objects': values['objects'],
                    'boxes': values['boxes'],
                    'grasps': values['grasps'],
                    'top_score': math.nan if top is None else top,
                    'ms': values['milliseconds'],
                    'note': values['note'],
                    'done_s': (
                        done - result.start_time
                        if report.status == 'processed' and done is not None
                        else None
                    ),
                }
            )
        rows += [{**common, **skipped, 'status': 'skipped'} for skipped in report.skipped]
        if report.storage_error:
            rows.append({**common, 'status': 'truncated', 'note': report.storage_error})
    return rows


def summary_table(rows: Sequence[dict[str, Any]]) -> Any:
    """Return the rows as a ``pyarrow.Table`` with the :data:`COLUMNS` schema."""
    import pyarrow as pa

    schema = pa.schema([(name, getattr(pa, kind)()) for name, kind in COLUMNS])
    columns = {name: [row.get(name) for row in rows] for name, _ in COLUMNS}
    return pa.table(columns, schema=schema)


def write_summary(result: FleetResult, output: Path, *, picture: bool = True) -> SummaryPaths:
    """Write ``summary.parquet``, ``summary.csv`` and (with `picture`) ``summary.png``."""
    import pyarrow.csv as pa_csv
    import pyarrow.parquet as pq

    rows = summary_rows(result)
    table = summary_table(rows)
    paths = SummaryPaths(
        output / 'summary.parquet',
        output / 'summary.csv',
        output / 'summary.png' if picture else None,
    )
    with atomic_path(paths.parquet) as tmp:
        pq.write_table(table, tmp)
    with atomic_path(paths.csv) as tmp:
        pa_csv.write_csv(table, tmp)
    if paths.png is not None:
        draw_summary(rows, result, paths.png)
    return paths


def draw_summary(rows: Sequence[dict[str, Any]], result: FleetResult, path: Path) -> None:
    """
    Draw the run: clouds per second over the run, and boxes and grasps per cloud.

    One line or bar colour per sweep setting.
    """
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np

    clouds = [row for row in rows if row['status'] not in ('failed', 'skipped', 'truncated')]
    settings = sorted({row['setting'] for row in clouds}) or ['']
    figure, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    finished = [row['done_s'] for row in clouds if row.get('done_s') is not None]
    span = max(max(finished, default=0.0), 1.0)
    window = max(1.0, span / 15.0)  # seconds over which the rate is counted
    grid = np.linspace(0.0, span, 300)
    for setting in settings:
        times = np.sort(
            [
                r['done_s']
                for r in clouds
                if r['setting'] == setting and r.get('done_s') is not None
            ]
        )
        if times.size:
            inside = np.searchsorted(times, grid, 'right') - np.searchsorted(times, grid - window)
            axes[0].plot(grid, inside / window, label=setting or 'all bags')
    axes[0].set_xlabel('seconds since the start of the run')
    axes[0].set_ylabel(f'clouds finished per second ({window:.0f} s window)')
    axes[0].set_title(f'throughput, {result.workers} workers ({len(finished)} clouds processed)')
    for axis, key in ((axes[1], 'boxes'), (axes[2], 'grasps')):
        values = [np.array([r[key] for r in clouds if r['setting'] == s]) for s in settings]
        top = max((int(v.max()) for v in values if v.size), default=1)
        if top <= 40:
            bins = np.arange(0, top + 2) - 0.5
        else:  # lidar scenes give hundreds of boxes, table-tops a few: a log axis shows both
            bins = np.concatenate([[0.0], np.unique(np.geomspace(1, top + 1, 30).round())])
            axis.set_xscale('symlog', linthresh=1.0)
            axis.set_xlim(0.0, bins[-1] * 1.5)
        for setting, data in zip(settings, values, strict=True):
            axis.hist(data, bins=bins, histtype='step', linewidth=1.5, label=setting or 'all bags')
        axis.set_xlabel(f'{key} per cloud')
        axis.set_ylabel('clouds')
        axis.set_title(f'{key} per cloud across the fleet')
    for axis in axes:
        if settings != ['']:
            axis.legend(fontsize=8)
    failed = len(result.failed)
    figure.suptitle(
        f'{len(clouds)} clouds from {len(result.reports) - failed} bag runs'
        + (f', {failed} failed' if failed else '')
    )
    figure.tight_layout()
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format='png', dpi=90)
    plt.close(figure)
