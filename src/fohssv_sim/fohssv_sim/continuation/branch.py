"""A branch of periodic orbits as a result: its JSON file and its bifurcation diagram.

``branch.json`` holds ``parameter`` (the varied name), ``model``, ``method``, ``settings``,
``points`` (each with ``value``, ``frequency_hz``, ``period_s``, ``w_amplitude``, ``w_mean``,
``w_min``, ``w_max``, ``immersion_min``, ``immersion_max`` and ``stable``: true, false or null
where the method gives no stability), ``bifurcations`` (each ``kind`` and ``value``), and
``complete`` (false while a branch runs; the point unknowns kept under ``resume`` let a rerun
carry on from the last point).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ['Branch', 'load_branch', 'plot_branch']


@dataclass
class Branch:
    """A followed branch; ``points`` and ``bifurcations`` as in the module docstring."""

    parameter: str
    model: str
    method: str
    settings: dict[str, Any]
    points: list[dict[str, Any]] = field(default_factory=list)
    bifurcations: list[dict[str, Any]] = field(default_factory=list)
    complete: bool = False
    resume: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {'parameter': self.parameter, 'model': self.model, 'method': self.method,
                'settings': self.settings, 'points': self.points,
                'bifurcations': self.bifurcations, 'complete': self.complete,
                'resume': self.resume}

    def write(self, path: Path) -> None:
        """Write atomically (a reader never sees half a file)."""
        tmp = path.with_name(path.name + '.tmp')
        tmp.write_text(json.dumps(self.to_dict(), indent=1, allow_nan=False,
                                  default=_plain) + '\n')
        os.replace(tmp, path)


def _plain(x: Any) -> Any:
    if hasattr(x, 'tolist'):
        return x.tolist()
    raise TypeError(f'{type(x).__name__} is not JSON serialisable')


def load_branch(path: Path) -> Branch:
    """The branch in ``path`` (a ``branch.json``)."""
    d = json.loads(Path(path).read_text())
    return Branch(d['parameter'], d['model'], d['method'], d['settings'], d['points'],
                  d['bifurcations'], bool(d.get('complete')), d.get('resume') or {})


MARKERS = {'hopf': ('o', 'tab:red'), 'fold': ('s', 'tab:purple'),
           'period_doubling': ('D', 'tab:orange'), 'torus': ('^', 'tab:green'),
           'grazing': ('v', 'tab:brown')}


def _runs(points: Sequence[dict[str, Any]]) -> list[tuple[Any, list[dict[str, Any]]]]:
    """Consecutive points of equal stability, each run sharing its end point with the next."""
    runs: list[tuple[Any, list[dict[str, Any]]]] = []
    for p in points:
        if runs and runs[-1][0] == p['stable']:
            runs[-1][1].append(p)
        else:
            if runs:
                runs[-1][1].append(p)
            runs.append((p['stable'], [p]))
    return runs


def plot_branch(branch: Branch, paths: Sequence[Path], sweep: Any = None,
                axis_label: str = '') -> Any:
    """Extremes of w along the branch against the parameter: stable solid, unstable dashed,
    stability unknown dotted; bifurcations marked; the maxima of a brute-force sweep
    (:class:`fohssv_sim.analysis.sweep.SweepResult` over the same parameter) as grey dots
    beneath. Returns the (closed) figure."""
    from ..analysis.figures import pyplot, save

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    if sweep is not None:
        key = 'alpha' if branch.parameter == 'fractional_order' else 'speed'
        xs, ys = [], []
        for r in sweep.rows:
            for m in r['maxima'] or []:
                xs.append(r[key])
                ys.append(m)
        ax.plot(xs, ys, '.', color='0.6', ms=2, label='sweep: local maxima of w (simulation)')
    style = {True: ('-', 'stable'), False: ('--', 'unstable'), None: (':', 'stability unknown')}
    seen: set[Any] = set()
    for stable, run in _runs(branch.points):
        ls, text = style[stable]
        x = [p['value'] for p in run]
        for k in ('w_max', 'w_min'):
            ax.plot(x, [p[k] for p in run], ls, color='tab:blue', lw=1.5,
                    label=None if stable in seen else f'orbit max/min of w, {text}')
            seen.add(stable)
    for b in branch.bifurcations:
        marker, color = MARKERS.get(b['kind'], ('x', 'k'))
        y = b.get('w')
        if y is None or not math.isfinite(y):
            continue
        ax.plot([b['value']], [y], marker, color=color, ms=7, ls='none',
                label=None if b['kind'] in seen else b['kind'].replace('_', ' '))
        seen.add(b['kind'])
    ax.set_xlabel(axis_label or branch.parameter)
    ax.set_ylabel('w (m/s)')
    s = branch.settings
    ax.set_title(f"Periodic orbits of the {branch.model} model by {branch.method}\n"
                 f"{s.get('summary', '')}", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save(fig, paths, dpi=130)
    plt.close(fig)
    return fig
