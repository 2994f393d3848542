"""What a fit writes: the one-line verdict, fit.json, the params YAML, the figures, and
the paper's alpha*(tau) table and figure.

Pure: numpy, matplotlib (Agg); never imports rclpy or the CLI.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...params import ModelParameters
from .data import STATE_NAMES, FitData
from .problem import FitSpec
from .result import FitResult, acceptance


# -- outputs ------------------------------------------------------------------------------------
def params_yaml(params: ModelParameters, control_period: float,
                initial_state: Sequence[float], header: str) -> str:
    """A ``--params-file`` for the plant node with the fitted model: every model parameter,
    the control period and the initial state."""
    from ...docs import yaml_value

    lines = [f'# {line}' for line in header.splitlines()]
    lines += ['/**:', '  ros__parameters:']
    for name, value in params.to_dict().items():
        lines.append(f'    {name}: {yaml_value(value)}')
    lines.append(f'    control_period: {yaml_value(float(control_period))}')
    lines.append(f'    initial_state: {yaml_value([float(v) for v in initial_state])}')
    return '\n'.join(lines) + '\n'


def write_outputs(result: FitResult, out: Path, extra: dict[str, Any] | None = None,
                  stem: str = 'fit') -> list[Path]:
    """``fit.json``, ``fit_params.yaml`` and the figures (overlay, alpha profile), PNG and
    SVG; returns the paths."""
    d = result.to_dict()
    d.update(extra or {})
    d['versions'] = _versions()
    paths = [out / f'{stem}.json', out / f'{stem}_params.yaml']
    paths[0].write_text(json.dumps(d, indent=2, default=float) + '\n')
    head = (f"fohssv fit: {result.message}\nplant --ros-args --params-file {paths[1].name}")
    paths[1].write_text(params_yaml(result.params, result.settings['control_period'],
                                    result.settings['initial_state'], head))
    paths += plot_overlay(result, out / f'{stem}_overlay')
    paths += plot_profile(result, out / f'{stem}_profile')
    return paths


def _versions() -> dict[str, str]:
    import scipy

    from ... import __version__
    return {'fohssv': __version__, 'python': sys.version.split()[0], 'numpy': np.__version__,
            'scipy': scipy.__version__}


def _caption(result: FitResult) -> str:
    st = result.settings
    return (f"FOM, solver {st['solver']}, step {st['step']:g} s, control period "
            f"{st['control_period']:g} s, {result.spec.objective} objective;\n"
            f"loop {st['loop']}")


def plot_overlay(result: FitResult, stem: Path, label: str = '') -> list[Path]:
    """The run's states and the fitted model's over the window (the fitted horizon marked)."""
    from ..figures import STATE_UNITS, pyplot, save, titled

    plt = pyplot()
    fig, axes = plt.subplots(4, 1, figsize=(8, 8), sharex=True)
    t = result.t
    keep = np.isfinite(result.data_states).all(axis=1)
    w0, w1 = result.window
    sel = keep & (t >= w0 - 1e-12) & (t <= w1 + 1e-12)
    for i, (ax, n) in enumerate(zip(axes, STATE_NAMES)):
        ax.plot(t[sel], result.data_states[sel, i], 'k-', lw=1.2, label='run')
        ok = np.isfinite(result.fitted_states[:, i]) & (t >= w0 - 1e-12) & (t <= w1 + 1e-12)
        ax.plot(t[ok], result.fitted_states[ok, i], 'r--', lw=1.0, label='fitted FOM')
        ax.set_ylabel(f'{n} ({STATE_UNITS[n]})')
        if result.horizon_end < w1 - 1e-12:
            ax.axvline(result.horizon_end, color='0.5', ls=':', lw=1)
    axes[0].legend(fontsize=7, loc='best')
    axes[-1].set_xlabel('t (s)')
    vals = ', '.join(f'{n}={v:.6g}' for n, v in result.values.items())
    axes[0].set_title(titled(f'run vs fitted FOM ({vals}), residual {result.residual:.3g} '
                             f"({'reproduced' if result.reproduces else 'NOT reproduced'}, "
                             f'{acceptance(result)[1]} {acceptance(result)[0]:.3g}; fitted up to '
                             f't = {result.horizon_end:g} s)\n{_caption(result)}', label),
                      fontsize=7)
    fig.tight_layout()
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=110)
    plt.close(fig)
    return paths


def plot_profile(result: FitResult, stem: Path, label: str = '') -> list[Path]:
    """The residual over alpha (coarse: others at the estimate; fine: re-optimised), the
    threshold and the profile interval."""
    from ..figures import pyplot, save, titled

    plt = pyplot()
    pr = result.profile
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.semilogy(pr['coarse'], np.maximum(pr['coarse_residual'], 1e-16), 'o-', ms=3,
                label='residual, other names at the estimate')
    ax.semilogy(pr['fine'], np.maximum(pr['fine_residual'], 1e-16), 's-', ms=3,
                label='residual near the estimate (others re-optimised)')
    level, what = acceptance(result)
    ax.axhline(level, color='r', ls='--', lw=1, label=f'reproduced below: {what}')
    if pr.get('interval'):
        ax.axvspan(*pr['interval'], color='g', alpha=0.2, label='profile interval (95 %)')
    ax.set_xlabel(pr['name'])
    ax.set_ylabel('residual (RMS)')
    ax.legend(fontsize=7)
    ax.set_title(titled(f"profile over {pr['name']} (horizon up to t = {result.horizon_end:g} "
                        f's)\n{_caption(result)}', label), fontsize=7)
    fig.tight_layout()
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=110)
    plt.close(fig)
    return paths


def write_reference(results: Sequence[tuple[float, FitResult, FitData]], out: Path
                    ) -> list[Path]:
    """Per speed the fit's outputs in ``out/V<speed>/``; the table ``reference.md`` and
    ``reference.json``; the figure alpha*(tau) with the residual floor."""
    from ...docs import markdown_table

    paths: list[Path] = []
    rows = []
    for v, res, data in results:
        sub = out / f'V{v:g}'
        sub.mkdir(parents=True, exist_ok=True)
        paths += write_outputs(res, sub, {'reference': data.source})
        n = res.spec.names[0]
        rows.append({'speed': v, 'tau': data.source['tau'], 'name': n,
                     'value': res.values[n], 'interval': res.intervals[n],
                     'residual': res.residual, 'reproduces': res.reproduces,
                     'horizon_end': res.horizon_end, 'message': res.message,
                     'acceptance': acceptance(res)[0],
                     'local_minima': res.profile.get('local_minima'),
                     'pieces': res.profile.get('pieces')})
    spec = results[0][1].spec
    first = results[0][1]
    table = markdown_table(
        ('V (m/s)', 'tau = L/V (s)', f'{rows[0]["name"]}*', '95 % interval',
         'local minima', 'residual', f'reproduced below ({acceptance(first)[1]})',
         'reproduced'),
        [(f"{r['speed']:g}", f"{r['tau']:.5g}", f"{r['value']:.4f}",
          f"[{r['interval'][0]:.4f}, {r['interval'][1]:.4f}]"
          + (f" ({r['pieces']} pieces)" if (r['pieces'] or 0) > 1 else ''),
          f"{r['local_minima']}", f"{r['residual']:.3g}", f"{r['acceptance']:.3g}",
          'yes' if r['reproduces'] else 'no') for r in rows])
    head = (f"FOM closed loop vs delayed closed loop, {spec.objective} objective over "
            f"[{first.window[0]:g}, {first.window[1]:g}] s;\n{_caption(first)}")
    (out / 'reference.md').write_text(f'{head}\n\n{table}\n')
    (out / 'reference.json').write_text(json.dumps(
        {'rows': rows, 'spec': spec.to_dict(), 'settings': first.settings,
         'versions': _versions()}, indent=2, default=float) + '\n')
    paths += [out / 'reference.md', out / 'reference.json']
    paths += plot_alpha_tau(rows, spec, out / 'alpha_tau', head)
    return paths


def plot_alpha_tau(rows: list[dict[str, Any]], spec: FitSpec, stem: Path, caption: str,
                   label: str = '') -> list[Path]:
    """alpha*(tau) with the intervals, and the residual floor on a second axis (the figure
    of :func:`alpha_tau_figure`), saved as ``stem``.png and .svg."""
    from ..figures import pyplot, save

    fig = alpha_tau_figure(rows, spec, caption, label)
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=110)
    pyplot().close(fig)
    return paths


def alpha_tau_figure(rows: list[dict[str, Any]], spec: FitSpec, caption: str,
                     label: str = '') -> Any:
    """The figure alpha*(tau): filled markers where the run is reproduced, open ones where
    the best value is not; a legend entry only for a kind of point the figure has."""
    from ..figures import pyplot, titled

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    tau = np.array([r['tau'] for r in rows])
    val = np.array([r['value'] for r in rows])
    lo = val - np.array([r['interval'][0] for r in rows])
    hi = np.array([r['interval'][1] for r in rows]) - val
    ok = np.array([bool(r['reproduces']) for r in rows], dtype=bool)
    name = rows[0]['name']
    ax.errorbar(tau, val, yerr=[lo, hi], fmt='none', ecolor='tab:blue', capsize=3)
    if ok.any():
        ax.plot(tau[ok], val[ok], 'o', color='tab:blue', label=f'{name}* (reproduced)')
    if not ok.all():
        ax.plot(tau[~ok], val[~ok], 'o', mfc='none', color='tab:blue',
                label=f'{name}* (best, not reproduced)')
    ax.set_xlabel('τ = L/V (s)')
    ax.set_ylabel(f'{name}*')
    ax2 = ax.twinx()
    ax2.semilogy(tau, [max(r['residual'], 1e-16) for r in rows], 's--', color='tab:red',
                 ms=4, label='residual floor at the best α')
    if all('acceptance' in r for r in rows):
        ax2.semilogy(tau, [r['acceptance'] for r in rows], ':', color='tab:red', lw=1,
                     label='reproduced below this residual')
    else:
        ax2.axhline(spec.threshold, color='tab:red', ls=':', lw=1,
                    label=f'threshold {spec.threshold:g}')
    ax2.set_ylabel('residual (RMS)', color='tab:red')
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc='best')
    ax.set_title(titled(f'the FOM order that best reproduces the delayed model\n{caption}',
                        label), fontsize=7)
    fig.tight_layout()
    return fig
