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

from .figures import STATE_UNITS, pyplot, save, titled
from .sweep import SweepResult, alpha_star

__all__ = ['plot_orbit_diagram', 'alpha_star', 'plot_alpha_v']

COLORS = {'steady': 'tab:green', 'drifting': 'tab:cyan', 'periodic': 'tab:blue',
          'aperiodic': 'tab:red', 'diverged': 'k'}


def _caption(side: dict[str, Any]) -> str:
    s = side['spec']
    cp = s['control_period']
    ctl = 'continuous feedback' if cp is None else f'ZOH {cp:g} s'
    return (f"{side['model']} model, solver {side['solver']}, step {side['step']:g} s, "
            f"transient {s['transient']:g} s, window {s['window']:g} s, {ctl}")


def _fixed(side: dict[str, Any], axis: str) -> str:
    """The parameter held fixed along an orbit diagram's axis, e.g. 'V = 84.5 m/s'."""
    s = side['spec']
    if axis == 'alpha':
        speeds = s['speeds']
        return ('V = ' + ', '.join(f'{v:g}' for v in speeds) + ' m/s') if speeds else ''
    if side['model'] != 'fractional':
        return ''           # no order to hold fixed: the caption names the model
    return 'α = ' + ', '.join(f'{a:g}' for a in s['alphas'])


def plot_orbit_diagram(result: SweepResult, axis: str, paths: Sequence[Path],
                       label: str = '') -> Any:
    """Maxima of the swept state against ``axis`` ('alpha' or 'speed'), coloured by class;
    the title names the fixed parameter (V or alpha) and ``label`` (e.g. quick). Returns the
    (closed) figure."""
    plt = pyplot()
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
    ax.set_ylabel(f'local maxima of {state} ({STATE_UNITS[state]})')
    fixed = _fixed(result.sidecar, axis)
    ax.set_title(titled(f"Orbit diagram{' at ' + fixed if fixed else ''}\n"
                        + _caption(result.sidecar), label), fontsize=9)
    ax.legend(fontsize=8, markerscale=4)
    fig.tight_layout()
    save(fig, paths, dpi=130)
    plt.close(fig)
    return fig


def plot_alpha_v(result: SweepResult, paths: Sequence[Path],
                 critical: Sequence[tuple[float, float]] | None = None, label: str = '') -> Any:
    """Class of every (alpha, V) point, alpha*(V) where the grid shows it, and Matignon's
    alpha_c(V) if given. alpha*(V) is drawn with markers (a speed alone is visible too) and is
    in the legend only when drawn; otherwise the legend says it was not found. Returns the
    (closed) figure."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 6))
    for kind, color in COLORS.items():
        pts = [(r['speed'], r['alpha']) for r in result.rows if r['kind'] == kind]
        if pts:
            v, a = zip(*pts)
            ax.scatter(v, a, s=12, color=color, label=kind)
    star = [(v, a) for v, a in alpha_star(result) if not math.isnan(a)]
    if star:
        ax.plot(*zip(*star), 'k-', marker='D', ms=5, lw=1.5,
                label='α*(V): steady → oscillating')
    else:
        ax.plot([], [], ' ', label='α*(V): no steady-oscillating change on the grid')
    if critical:
        ax.plot(*zip(*critical), 'm--', lw=1, label='Matignon α_c(V) (linear)')
    ax.set_xlabel('V (m/s)')
    ax.set_ylabel('fractional order α')
    ax.set_title(titled('α–V map\n' + _caption(result.sidecar), label), fontsize=9)
    # below the axes: inside, it would hide points of the grid
    ax.legend(fontsize=8, loc='upper center', bbox_to_anchor=(0.5, -0.12), ncol=3)
    fig.tight_layout()
    save(fig, paths, dpi=130)
    plt.close(fig)
    return fig
