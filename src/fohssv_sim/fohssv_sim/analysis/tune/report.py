"""A search reported: the score in words, the summary lines and the figures."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..gainmap.spec import OUTCOME_COLORS, OUTCOME_RANK, OUTCOMES
from .search import TuneResult, _num
from .spec import CHECK_RTOL, OBJECTIVE_TEXT, TuneSpec


# -- reporting -------------------------------------------------------------------------------
def describe_score(s: dict[str, Any], spec: TuneSpec) -> str:
    """One line: worst outcome, scenarios not steady, margin, worst metric."""
    if not s.get('linearised'):
        m = 'n/a (no linearisation)'
    elif math.isnan(_num(s['margin'])):
        m = 'unknown (no equilibrium)'
    else:
        m = f"{_num(s['margin']):.4g}"
    return (f"worst {s['outcome']}, {s['not_steady']}/{s['scenarios']} scenario(s) not steady, "
            f'Matignon margin min(α_c − α) {m}, worst {OBJECTIVE_TEXT[spec.objective]} '
            f"{_num(s['metric']):.4g}")


def summary_lines(result: TuneResult) -> list[str]:
    """What the search found, as text."""
    rec, spec = result.record, result.spec
    opt = rec['optimizer']
    w = rec['winner']
    lines = [f"differential evolution: {opt['generations_run']} generation(s) of "
             f"{opt['population']} ({opt['evaluations']} candidates, budget {spec.budget}), "
             f"seed {spec.seed}; step {rec['step']:g} s, solver {rec['solver']}, "
             f"{len(spec.scenarios())} scenarios; {result.computed_chunks} chunks computed, "
             f'{result.reused_chunks} reused']
    vals = ', '.join(f'{k}={v:.6g}' for k, v in w['values'].items())
    # generations are numbered from 1 where shown (tune.json and the folders count from 0)
    lines.append(f"winner (generation {w['generation'] + 1}, candidate {w['candidate']}): "
                 f'{vals}')
    lines.append('  ' + describe_score(w['score'], spec))
    chk = rec.get('check_step')
    if chk is not None:
        lines.extend(_check_lines(chk, spec))
    return lines


def _check_lines(chk: dict[str, Any], spec: TuneSpec) -> list[str]:
    """The step check's lines of :func:`summary_lines`."""
    head = (f"step check (half step {chk['step']:g} s; flagged: outcome changes, or "
            f"{chk.get('metric', 'the metric')} moves by more than "
            f"{100 * chk.get('metric_rtol', CHECK_RTOL):g} %)")
    worst = _num(chk.get('max_metric_change', math.nan))
    if not chk['flagged']:
        return [f'{head}: every scenario keeps its outcome; largest metric change '
                f'{100 * worst:.2g} %']

    def one(f: dict[str, Any]) -> str:
        change = _num(f.get('metric_change', math.nan))
        moved = '' if math.isnan(change) else f', metric {100 * change:.3g} %'
        return (f"V={f['speed']:g}, α={f['alpha']:g}: {f['outcome']} -> "
                f"{f['half_step_outcome']}{moved}")

    return [f"{head}: {len(chk['flagged'])} scenario(s) not converged, flagged and not "
            'scored: ' + '; '.join(one(f) for f in chk['flagged']),
            f"  over the {chk['converged_scenarios']} converged scenario(s): "
            + describe_score(chk['score_converged'], spec)]


def plot_envelope(record: dict[str, Any], stem: Path, label: str = '') -> list[Path]:
    """The winner's envelope map: class per V-alpha cell, annotated with alpha_c - alpha;
    cells flagged by the step check hatched. PNG and SVG ``<stem>.png/.svg``."""
    from ..figures import pyplot, save, titled
    from ..gainmap.figures import _edges

    plt = pyplot()
    spec = TuneSpec.from_dict(record['spec'])
    w = record['winner']
    rows = w['scenarios']
    speeds, alphas = list(spec.envelope_speeds), list(spec.envelope_alphas)
    flagged = {(f['alpha'], f['speed']) for f in (record.get('check_step') or {}).get(
        'flagged', [])}
    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    xe = _edges(speeds) if len(speeds) > 1 else np.array([speeds[0] - 5.0, speeds[0] + 5.0])
    ye = _edges(alphas) if len(alphas) > 1 else np.array([alphas[0] - 0.05, alphas[0] + 0.05])
    codes = np.full((len(alphas), len(speeds)), np.nan)
    from matplotlib.colors import BoundaryNorm, ListedColormap

    for r in rows:
        i, j = alphas.index(r['alpha']), speeds.index(r['speed'])
        codes[i, j] = OUTCOME_RANK[r['outcome']]
        m = _num(r['alpha_c']) - r['alpha']
        text = r['outcome'] + ('' if math.isnan(m) else f'\nα_c−α={m:+.3f}')
        ax.text(r['speed'], r['alpha'], text, ha='center', va='center', fontsize=7,
                color='w' if r['outcome'] in ('diverged', 'chaotic', 'periodic') else 'k')
        if (r['alpha'], r['speed']) in flagged:
            ax.add_patch(plt.Rectangle((xe[j], ye[i]), xe[j + 1] - xe[j], ye[i + 1] - ye[i],
                                       fill=False, hatch='//', ec='orange', lw=0))
    cmap = ListedColormap([OUTCOME_COLORS[o] for o in OUTCOMES])
    ax.pcolormesh(xe, ye, np.ma.masked_invalid(codes), cmap=cmap, alpha=0.85,
                  norm=BoundaryNorm(np.arange(len(OUTCOMES) + 1) - 0.5, len(OUTCOMES)))
    for o in OUTCOMES:
        if any(r['outcome'] == o for r in rows):
            ax.fill_between([], [], color=OUTCOME_COLORS[o], label=o)
    if flagged:
        ax.fill_between([], [], facecolor='none', hatch='//', edgecolor='orange',
                        label='outcome changes at half step (not scored)')
    ax.set_xlabel('V (m/s)')
    ax.set_ylabel('α')
    items = [f'{k}={v:.4g}' for k, v in w['values'].items()]
    vals = '\n'.join(', '.join(items[i:i + 3]) for i in range(0, len(items), 3))
    ax.set_title(titled(
        f'winner of fohssv tune {spec.controller} over the envelope\n{vals}\n'
        f"{record['model']} model, solver {record['solver']}, step {record['step']:g} s, "
        f'ZOH {spec.control_period or 0:g} s, {spec.duration:g} s runs (transient '
        f'{spec.transient:g} s), x(0) = 0', label), fontsize=7)
    ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.12), ncol=3)
    fig.tight_layout()
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=120)
    plt.close(fig)
    return paths


def plot_history(record: dict[str, Any], stem: Path, label: str = '') -> list[Path]:
    """The search history: per generation every candidate's level-1 rank (scenarios not
    steady), margin and metric, with the best so far. PNG and SVG ``<stem>.png/.svg``."""
    from ..figures import pyplot, save, titled

    plt = pyplot()
    spec = TuneSpec.from_dict(record['spec'])
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 7.5), sharex=True)
    panels = (('not_steady', 'scenarios not steady'), ('margin', 'min(α_c − α)'),
              ('metric', f'worst {OBJECTIVE_TEXT[spec.objective]}'))
    for ax, (key, text) in zip(axes, panels):
        gx, gy, bx, by = [], [], [], []
        for g in record['generations']:
            for c in g['candidates']:
                if c.get('valid'):
                    gx.append(g['generation'])
                    gy.append(_num(c[key]))
            b = g.get('best_so_far')
            if b is not None:
                bx.append(g['generation'])
                by.append(_num(b[key]))
        ax.plot(gx, gy, '.', color='0.6', ms=4, label='candidates')
        ax.plot(bx, by, 'o-', color='tab:red', ms=4, label='best so far (lexicographic)')
        ax.set_ylabel(text)
        if key == 'margin':
            ax.axhline(spec.min_margin, color='m', lw=0.8, ls='--', label='min_margin')
    axes[-1].set_xlabel('generation')
    axes[-1].xaxis.get_major_locator().set_params(integer=True)
    axes[0].legend(fontsize=7)
    axes[1].legend(fontsize=7)
    opt = record['optimizer']
    axes[0].set_title(titled(
        f'fohssv tune {spec.controller}: differential evolution, population '
        f"{opt['population']}, {len(record['generations'])} generation(s), seed {spec.seed}\n"
        f'{len(spec.scenarios())} scenarios; score: worst outcome, then margin, then metric',
        label), fontsize=7)
    fig.tight_layout()
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=120)
    plt.close(fig)
    return paths
