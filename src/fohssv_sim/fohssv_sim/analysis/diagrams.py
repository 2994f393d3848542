"""Orbit diagrams (Figs. 6, 8, 9) and the alpha-V map with alpha*(V) (Fig. 10).

Called orbit diagrams, not bifurcation diagrams: they show the local maxima of one state after
a transient, per parameter value (as DynamicalSystems.jl names them). Every figure states its
step, solver, transient and window so that it can be checked by halving the step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .sweep import SweepResult

__all__ = ['plot_orbit_diagram', 'alpha_star', 'plot_alpha_v']

COLORS = {'equilibrium': 'tab:green', 'converging': 'tab:olive', 'periodic': 'tab:blue',
          'aperiodic': 'tab:red', 'diverged': 'k'}


def _plt():
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def _caption(side: dict[str, Any]) -> str:
    s = side['spec']
    cp = s['control_period']
    ctl = 'continuous feedback' if cp is None else f'ZOH {cp:g} s'
    return (f"{side['model']} model, solver {side['solver']}, step {side['step']:g} s, "
            f"transient {s['transient']:g} s, window {s['window']:g} s, {ctl}")


def plot_orbit_diagram(result: SweepResult, axis: str, paths: Sequence[Path]) -> None:
    """Maxima of the swept state against ``axis`` ('alpha' or 'speed'), coloured by class."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 5))
    state = result.sidecar['spec']['state']
    seen = set()
    for r in result.rows:
        x = r[axis]
        m = r['maxima'] or []
        if not m:
            continue
        kind = r['kind']
        ax.plot([x] * len(m), m, '.', color=COLORS.get(kind, 'k'), ms=2,
                ls='none', label=None if kind in seen else kind)
        seen.add(kind)
        if r['step_check'].startswith('changed'):
            ax.plot([x], [max(m)], 'x', color='tab:orange', ms=6,
                    label=None if 'step' in seen else 'classification changes at half step')
            seen.add('step')
    ax.set_xlabel('fractional order α' if axis == 'alpha' else 'V (m/s)')
    ax.set_ylabel(f'local maxima of {state}')
    ax.set_title('Orbit diagram\n' + _caption(result.sidecar), fontsize=9)
    ax.legend(fontsize=8, markerscale=4)
    fig.tight_layout()
    for p in paths:
        fig.savefig(p, dpi=130)
    plt.close(fig)


def alpha_star(result: SweepResult) -> list[tuple[float, float]]:
    """alpha*(V): per speed, the first alpha (scanning upward) where the orbit leaves the
    equilibrium class ('equilibrium' or 'converging'), as the midpoint between the two grid
    values; NaN when the class never changes on the grid."""
    out = []
    speeds = sorted({r['speed'] for r in result.rows})
    for v in speeds:
        rows = sorted((r for r in result.rows if r['speed'] == v), key=lambda r: r['alpha'])
        steady = [r['kind'] in ('equilibrium', 'converging') for r in rows]
        a = math.nan
        for i in range(1, len(rows)):
            if steady[i] != steady[i - 1]:
                a = 0.5 * (rows[i]['alpha'] + rows[i - 1]['alpha'])
                break
        out.append((v, a))
    return out


def plot_alpha_v(result: SweepResult, paths: Sequence[Path],
                 critical: Sequence[tuple[float, float]] | None = None) -> None:
    """Class of every (alpha, V) point, alpha*(V), and Matignon's alpha_c(V) if given."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 5))
    for kind, color in COLORS.items():
        pts = [(r['speed'], r['alpha']) for r in result.rows if r['kind'] == kind]
        if pts:
            v, a = zip(*pts)
            ax.scatter(v, a, s=12, color=color, label=kind)
    star = [(v, a) for v, a in alpha_star(result) if not math.isnan(a)]
    if star:
        ax.plot(*zip(*star), 'k-', lw=1.5, label='α*(V): first change of class')
    if critical:
        ax.plot(*zip(*critical), 'm--', lw=1, label='Matignon α_c(V) (linear)')
    ax.set_xlabel('V (m/s)')
    ax.set_ylabel('fractional order α')
    ax.set_title('α–V map\n' + _caption(result.sidecar), fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    for p in paths:
        fig.savefig(p, dpi=130)
    plt.close(fig)
