"""The gain map figures: outcome and metric over the gain grid, with the Matignon boundary."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .result import GainMapResult
from .spec import (
    METRICS,
    OUTCOME_COLORS,
    OUTCOME_RANK,
    OUTCOMES,
    GainMapError,
    GainMapSpec,
    controller_parameters,
)


# -- figures -----------------------------------------------------------------------------
def _edges(values: Sequence[float]) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    if v.size == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.r_[v[0] - (mid[0] - v[0]), mid, v[-1] + (v[-1] - mid[-1])]


def _caption(result: GainMapResult) -> str:
    side, s = result.sidecar, result.spec
    cp = s.control_period
    hold = 'continuous feedback' if cp is None else f'ZOH {cp:g} s'
    fixed = ', '.join(f'{k}={v:g}' if isinstance(v, float) else f'{k}={v}'
                      for k, v in s.gains.items())
    return (f"{side['model']} model, solver {side['solver']}, step {side['step']:g} s, {hold}, "
            f'{s.duration:g} s runs (transient {s.transient:g} s), x(0) = 0; '
            f"{s.controller}{' (' + fixed + ')' if fixed else ''}")


def gain_label(controller: str, name: str) -> str:
    """An axis label for a gain: its name and unit, e.g. 'pitch_rate_gain (rad s/rad)'."""
    spec = controller_parameters(controller).get(name)
    unit = getattr(spec, 'unit', '-')
    return name if unit in ('', '-') else f'{name} ({unit})'


def reference_gains(s: GainMapSpec) -> tuple[tuple[float, float], str] | None:
    """The controller's default (x, y) gains and a legend text, when they lie inside the map:
    for eq. 31 (defaults referenced to the paper) the paper's gains, named so when every other
    gain is at its default too."""
    specs = controller_parameters(s.controller)
    x0, y0 = specs[s.gain_x].default, specs[s.gain_y].default
    if not all(isinstance(v, (int, float)) for v in (x0, y0)):
        return None
    inside = (min(s.x_values) <= x0 <= max(s.x_values)
              and min(s.y_values) <= y0 <= max(s.y_values))
    if not inside:
        return None
    eq31 = {k for k, p in specs.items() if getattr(p, 'reference', '') == 'eq. 31'}
    paper = {s.gain_x, s.gain_y} <= eq31 and all(
        specs[k].default == v for k, v in s.gains.items() if k in eq31)
    text = "the paper's gains (eq. 31" if paper else 'default gains ('
    return (float(x0), float(y0)), f'{text}: {x0:g}, {y0:g})'


def _boundary(ax: Any, result: GainMapResult, margin: np.ndarray, what: str,
              unstable_text: str) -> str:
    """Draw the contour margin = 0 (alpha_c - alpha) and mark the Matignon-unstable cells
    (``unstable_text``: when a cell is, e.g. 'α_c < α'); returns a note for the title when
    nothing can be drawn."""
    s = result.spec
    if np.all(np.isnan(margin)):
        return ('Matignon boundary not drawn: no linearisation (controller with internal '
                'fractional states, or no equilibrium)')
    X, Y = np.meshgrid(s.x_values, s.y_values)
    unstable = margin < 0
    ax.plot(X[unstable], Y[unstable], 'x', color='m', ms=4, lw=0.8,
            label=f'linearisation unstable ({unstable_text})')
    finite = np.where(np.isnan(margin), np.nan, margin)
    note = ''
    if margin.shape[0] >= 2 and margin.shape[1] >= 2 and np.nanmin(finite) < 0 < np.nanmax(
            finite):
        ax.contour(X, Y, finite, levels=[0.0], colors='m', linewidths=1.5)
        ax.plot([], [], 'm-', label=f'Matignon boundary: {what} = 0')
    else:
        side = 'below' if np.nanmax(finite) < 0 else 'above'
        note = f'no Matignon boundary in the map ({what} {side} 0 everywhere)'
    if np.any(np.isnan(margin)):
        note += ('; ' if note else '') + 'α_c unknown at some pairs (no equilibrium)'
    return note


def plot_gain_map(result: GainMapResult, stem: Path, *, worst: bool = False,
                  alpha: float | None = None, speed: float | None = None,
                  label: str = '') -> list[Path]:
    """The classification map and one map per metric (:data:`METRICS`), PNG and SVG, with
    the Matignon boundary on each: for one scenario (``alpha``, ``speed``, default the
    spec's) or, with ``worst``, the worst case over the envelope. Files are
    ``<stem>_classes``, ``<stem>_<metric>``; returns the paths written."""
    from matplotlib.colors import BoundaryNorm, ListedColormap

    from ..figures import pyplot, save, titled

    plt = pyplot()
    s = result.spec
    if worst:
        rows = result.worst()
        margin = result.grid(rows, 'alpha_margin')
        what = 'min over envelope of α_c(V) − α'
        unstable_text = 'α_c(V) < α somewhere in the envelope'
        speeds = sorted({r['speed'] for r in result.rows})
        alphas = sorted({r['alpha'] for r in result.rows})
        head = (f'worst case over V ∈ [{speeds[0]:g}, {speeds[-1]:g}] m/s ({len(speeds)}), '
                f'α ∈ [{alphas[0]:g}, {alphas[-1]:g}] ({len(alphas)})')
    else:
        alpha = s.alpha if alpha is None else alpha
        speed = s.speed if speed is None else speed
        rows = result.scenario_rows(alpha, speed)
        for r in rows:
            r['alpha_margin'] = r['alpha_c'] - r['alpha']
        margin = result.grid(rows, 'alpha_margin')
        what = 'α_c − α'
        unstable_text = 'α_c < α'
        head = f'α = {alpha:g}, V = {speed:g} m/s'
    if not rows:
        raise GainMapError(f'no points of scenario alpha={alpha}, V={speed} in the map')
    xe, ye = _edges(s.x_values), _edges(s.y_values)
    written: list[Path] = []

    shown = {r['pair'] for r in rows}
    changed = {r['pair'] for r in result.rows if r['pair'] in shown and r.get(
        'step_check', 'same') not in ('same', '')}
    pairs = s.pairs()

    reference = reference_gains(s)

    def finish(fig: Any, ax: Any, name: str, title: str) -> None:
        note = _boundary(ax, result, margin, what, unstable_text)
        if changed:
            ax.plot([s.x_values[pairs[k][0]] for k in sorted(changed)],
                    [s.y_values[pairs[k][1]] for k in sorted(changed)], 'o', mfc='none',
                    mec='orange', ms=9, label='outcome changes at half step')
        if reference is not None:
            (x0, y0), text = reference
            ax.plot([x0], [y0], '*', color='gold', mec='k', mew=0.8, ms=15, ls='none',
                    label=text)
        ax.set_xlabel(gain_label(s.controller, s.gain_x))
        ax.set_ylabel(gain_label(s.controller, s.gain_y))
        ax.set_title(titled(f'{title}, {head}\n{_caption(result)}' + (
            f'\n{note}' if note else ''), label), fontsize=7)
        handles, names = ax.get_legend_handles_labels()
        # below the plot, on the figure: centred under the axes it was cut at the edges when a
        # colour bar narrows them
        fig.tight_layout(rect=(0, 0.03 * ((len(names) + 1) // 2) + 0.02 if names else 0, 1, 1))
        if names:
            fig.legend(handles, names, fontsize=7, loc='lower center', ncol=2, frameon=False)
        paths = [stem.parent / f'{stem.name}_{name}.png', stem.parent / f'{stem.name}_{name}.svg']
        save(fig, paths, dpi=120)
        plt.close(fig)
        written.extend(paths)

    classes = result.grid(rows, 'outcome')
    codes = np.vectorize(lambda o: OUTCOME_RANK.get(o, np.nan) if isinstance(o, str)
                         else np.nan, otypes=[float])(classes)
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    cmap = ListedColormap([OUTCOME_COLORS[o] for o in OUTCOMES])
    ax.pcolormesh(xe, ye, np.ma.masked_invalid(codes), cmap=cmap,
                  norm=BoundaryNorm(np.arange(len(OUTCOMES) + 1) - 0.5, len(OUTCOMES)))
    present = set(classes.ravel().tolist())
    for o in OUTCOMES:
        if o in present:
            ax.fill_between([], [], color=OUTCOME_COLORS[o], label=o)
    finish(fig, ax, 'classes', ('worst outcome' if worst else 'outcome') + ' of each gain pair')

    for m, axis_label in METRICS.items():
        g = result.grid(rows, m)
        fig, ax = plt.subplots(figsize=(7.5, 6.5))
        finite = np.isfinite(g)
        if finite.any():
            mesh = ax.pcolormesh(xe, ye, np.ma.masked_where(~finite, g), cmap='viridis')
            fig.colorbar(mesh, ax=ax, label=axis_label)
        inf = np.isinf(g)
        if inf.any():
            ax.pcolormesh(xe, ye, np.ma.masked_where(~inf, np.ones_like(g)), cmap=ListedColormap(
                ['0.6']), vmin=0, vmax=1)
            ax.fill_between([], [], color='0.6', label='inf (never settles / diverged)')
        finish(fig, ax, m, ('worst ' if worst else '') + axis_label)
    return written
