"""
Tables and plots of the Figure 6 experiment (:mod:`mvbb_ros.evaluation.experiment`).

:func:`format_comparison` gives one row per candidate set (Markdown or plain text);
:func:`plot_quality_space` draws the paper's (epsilon, V) scatter plot with matplotlib's Agg
canvas and writes it atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mvbb_ros.common.atomic import atomic_path
from mvbb_ros.evaluation.experiment import QualityComparison
from mvbb_ros.evaluation.wrench import DEFAULT_FRICTION


def _number(value: float | None, digits: int = 4) -> str:
    if value is None:
        return '-'
    return f'{value:.{digits}f}'


def _geometry_text(geometry: dict[str, float] | None) -> str:
    if geometry is None:
        return '-'
    return (
        f'{geometry["separation"]:.2f} / {geometry["offset"]:.2f} / '
        f'{geometry["angle_deg"]:.0f} deg'
    )


def format_comparison(comparison: QualityComparison, *, markdown: bool = True) -> str:
    """
    Return the comparison as a table, one row per candidate set.

    Columns: set, boxes, candidates, force-closure rate, best epsilon (and its V), median
    epsilon over all candidates and over the force-closure ones, rank of the first candidate
    reaching 90 % of the best spherical epsilon (spherical: expected random draws), best epsilon
    as a fraction of the best spherical one, candidates as a fraction of the spherical count,
    whether the claim holds, the expected best epsilon of as many random spherical grasps
    (:func:`~mvbb_ros.evaluation.spherical.expected_best_of`), the best grasp's geometry
    (:meth:`QualityComparison.grasp_geometry`: contact separation and contact line offset from
    the centre of mass, both / rho, and the larger normal-to-line angle), the failures (finger
    collisions / no contact / missed) and time (generation + evaluation).

    :param comparison: the experiment's result.
    :param markdown: a Markdown table (default) or aligned plain text.
    :return: the table.
    """
    header = [
        'set',
        'boxes',
        'cand.',
        'FC rate',
        'best eps',
        'V (best)',
        'median eps',
        'median eps (FC)',
        'to 90 %',
        'eps / sph.',
        'cand. / sph.',
        'claim',
        'sph. same budget',
        'best: sep / off / angle',
        'failures c / n / m',
        'time s',
    ]
    table = []
    for row in comparison.summary():
        to_90 = row.get('to_90')
        if isinstance(to_90, float):
            to_90_text = f'~{to_90:.0f}'
        else:
            to_90_text = '-' if to_90 is None else str(to_90)
        holds = row.get('holds')
        table.append(
            [
                row['set'],
                '-' if row['boxes'] is None else str(row['boxes']),
                str(row['candidates']),
                f'{100 * row["force_closure_rate"]:.1f} %',
                _number(row['best_epsilon']),
                _number(row['best_volume'], 5),
                _number(row['median_epsilon']),
                _number(row['median_epsilon_fc']),
                to_90_text,
                (
                    '-'
                    if row.get('quality_ratio') is None
                    else f'{100 * row["quality_ratio"]:.1f} %'
                ),
                (
                    '-'
                    if row.get('candidate_ratio') is None
                    else f'{100 * row["candidate_ratio"]:.2f} %'
                ),
                '-' if holds is None else ('yes' if holds else 'no'),
                _number(row.get('spherical_same_budget')),
                _geometry_text(row['best_grasp']),
                '{collision} / {no_contact} / {missed}'.format(**row['status']),
                f'{row["generate_seconds"] + row["evaluate_seconds"]:.1f}',
            ]
        )
    if markdown:
        lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
        lines += ['| ' + ' | '.join(cells) + ' |' for cells in table]
        return '\n'.join(lines)
    widths = [max(len(header[i]), *(len(r[i]) for r in table)) for i in range(len(header))]
    lines = ['  '.join(h.rjust(w) for h, w in zip(header, widths, strict=True))]
    lines += ['  '.join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in table]
    return '\n'.join(lines)


#: Marker colours of the box sets in :func:`plot_quality_space`.
_SET_COLOURS = ('tab:red', 'tab:orange', 'tab:green', 'tab:blue', 'tab:purple', 'tab:brown')


def plot_quality_space(
    comparison: QualityComparison, path: str | os.PathLike[str], *, title: str | None = None
) -> Path:
    """
    Write the paper's Figure 6 for one object: the (epsilon, V) quality space.

    Like the paper, only force-closure grasps are drawn: every spherical grasp as a grey cross,
    the best-epsilon spherical grasp as a black square, and for each box set its grasps as small
    dots and its best-epsilon grasp as a large diamond labelled (candidates, set). Written
    atomically with matplotlib's Agg canvas.

    :param comparison: the experiment's result.
    :param path: the PNG file to write.
    :param title: the figure title (default the object's name and the gripper).
    :return: the path written.
    """
    figure = Figure(figsize=(7.5, 5.5), dpi=120)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot(1, 1, 1)
    spherical = comparison.spherical
    if spherical is not None:
        fc = spherical.evaluation.force_closure
        axes.scatter(
            spherical.evaluation.epsilon[fc],
            spherical.evaluation.volume[fc],
            marker='x',
            s=9,
            linewidths=0.5,
            color='0.65',
            label=f'spherical ({int(fc.sum())} FC of {spherical.candidates})',
            zorder=1,
        )
        best = spherical.best_index
        if best is not None:
            axes.scatter(
                [spherical.evaluation.epsilon[best]],
                [spherical.evaluation.volume[best]],
                marker='s',
                s=70,
                color='black',
                label=f'best spherical (eps {spherical.best_epsilon():.4f})',
                zorder=4,
            )
    offsets = ((8, 8), (8, -14), (8, 20), (8, -26), (8, 32), (8, -38))
    for colour, offset, result in zip(_SET_COLOURS, offsets, comparison.box_sets, strict=False):
        fc = result.evaluation.force_closure
        axes.scatter(
            result.evaluation.epsilon[fc],
            result.evaluation.volume[fc],
            marker='.',
            s=22,
            color=colour,
            alpha=0.6,
            zorder=2,
        )
        best = result.best_index
        label = f'{result.name}: {int(fc.sum())} FC of {result.candidates}'
        if best is None:
            axes.scatter([], [], marker='D', color=colour, label=label + ' (none FC)')
            continue
        eps, vol = result.evaluation.epsilon[best], result.evaluation.volume[best]
        axes.scatter(
            [eps],
            [vol],
            marker='D',
            s=70,
            color=colour,
            edgecolors='black',
            label=f'{label}, best eps {eps:.4f}',
            zorder=5,
        )
        axes.annotate(
            f'({result.candidates}, {result.name})',
            (eps, vol),
            textcoords='offset points',
            xytext=offset,
            fontsize=7,
            color=colour,
        )
    hand = comparison.gripper
    axes.set_xlabel('epsilon (Ferrari-Canny, torques / object radius)')
    axes.set_ylabel('V (grasp wrench space volume)')
    axes.set_xlim(left=0.0)
    axes.set_ylim(bottom=0.0)
    axes.grid(True, linewidth=0.3)
    axes.legend(fontsize=7, loc='upper left')
    size = comparison.target.diameter
    axes.set_title(
        title
        or (
            f'{comparison.name}: grasp quality space (only force-closure grasps)\n'
            f'parallel jaw: opening {hand.max_width / size:.2f} D, '
            f'fingers {hand.finger_depth / size:.2f} D; mu = '
            f'{comparison.settings.get("friction", DEFAULT_FRICTION):g}'
        ),
        fontsize=9,
    )
    figure.tight_layout()
    target = Path(path)
    with atomic_path(target) as tmp:
        figure.savefig(tmp, format='png')
    return target
