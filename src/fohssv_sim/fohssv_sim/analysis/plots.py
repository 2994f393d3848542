"""Time responses (Figs. 3-4) and the w-q phase portrait (Fig. 7) of recorded runs."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .figures import save

__all__ = ['plot_time_responses', 'plot_phase_portrait', 'describe_run', 'controller_of',
           'zoom_window']


def _plt():
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def controller_of(run) -> str:
    """The law that answered the run (``fohssv.controller`` in the run metadata, recorded from
    the command publisher's ``controller`` parameter), else the publishing node, else '?'."""
    meta = getattr(run, 'metadata', None) or {}
    return str(meta.get('fohssv.controller') or meta.get('fohssv.controller_node') or '?')


def _resolved_step(p: dict) -> object:
    """The run's integration step: the recorded value, or the model's default that 'auto'
    stands for (resolved by the parameter table, as the plant resolved it)."""
    step = p.get('step')
    if isinstance(step, float):
        return step
    try:
        from ..params import PARAMETERS, ModelParameters

        names = {q.name for q in PARAMETERS}
        return ModelParameters.from_dict({k: v for k, v in p.items() if k in names}).step
    except (ValueError, TypeError):
        return step


def _step_text(p: dict) -> str:
    step, cp = _resolved_step(p), p.get('control_period')
    out = f'h={step:g} s' if isinstance(step, float) else ''
    if isinstance(cp, float):
        out += (', ' if out else '') + f'ZOH {cp:g} s'
    return out


def describe_run(run) -> str:
    """One line naming the controller, model, order, speed, step and control period of a
    run."""
    p = run.parameters
    if not p:
        return f'{run.path.name}: controller {controller_of(run)}'
    model = p.get('model', '?')
    alpha = f", α={p['fractional_order']:g}" if model == 'fractional' and isinstance(
        p.get('fractional_order'), float) else ''
    speed = p.get('speed')
    v = f', V={speed:g}' if isinstance(speed, float) else ''
    extra = _step_text(p)
    return (f'{run.path.name}: controller {controller_of(run)}, {model}{alpha}{v}'
            + (f', {extra}' if extra else ''))


def _title(what: str, runs: Sequence) -> str:
    """``what`` with the controller and the step of the runs (each distinct pair once)."""
    pairs = []
    for run in runs:
        pair = f'controller {controller_of(run)}' + (
            f', {_step_text(run.parameters)}' if _step_text(run.parameters or {}) else '')
        if pair not in pairs:
            pairs.append(pair)
    return f"{what}: {'; '.join(pairs)}"


def zoom_window(run, cycles: int = 4) -> tuple[float, float]:
    """The last ``cycles`` periods of w's dominant frequency (last half of the run), or the
    last tenth of the run when w does not oscillate."""
    t = run.t
    if t.size < 16:
        return (float(t[0]), float(t[-1])) if t.size else (0.0, 1.0)
    s = summary(run)
    f = s.get('w_dominant_frequency_hz', 0.0)
    length = t[-1] - t[0]
    span = cycles / f if f > 2 * s.get('frequency_resolution_hz', np.inf) else 0.1 * length
    return float(t[-1] - min(span, 0.5 * length)), float(t[-1])


def plot_time_responses(runs: Sequence, paths: Sequence[Path]) -> None:
    """z, w, theta, q, delta_c and Fp against time (left) and over the last cycles (right,
    zoomed: a ~130 Hz cycle over seconds is a solid band otherwise); several runs overlay.
    The legend is below the plots, the title names the controller and the step."""
    plt = _plt()
    fig, axes = plt.subplots(6, 2, figsize=(13, 11), sharex='col',
                             gridspec_kw={'width_ratios': [2, 1]})
    labels = ('z (m)', 'w (m/s)', 'θ (rad)', 'q (rad/s)', 'δc (rad)', 'Fp (m²/s²)')
    z0, z1 = zoom_window(runs[0]) if runs else (0.0, 1.0)
    for run in runs:
        name = describe_run(run)
        for col in (0, 1):
            ax = axes[:, col]
            for i in range(4):
                ax[i].plot(run.t, run.state[:, i], lw=0.8, label=name)
            if run.command_t.size:
                ax[4].step(run.command_t, run.delta_c, where='post', lw=0.8, label=name)
            ax[5].plot(run.planing_force_t, run.planing_force, lw=0.8, label=name)
    for row, label in zip(axes, labels):
        row[0].set_ylabel(label)
        for ax in row:
            ax.grid(alpha=0.3)
    for run in runs[:1]:
        # the zoom's y range is that of the zoomed samples, not of the whole run
        keep = (run.t >= z0) & (run.t <= z1)
        series = [run.state[keep, i] for i in range(4)]
        ck = (run.command_t >= z0) & (run.command_t <= z1)
        fk = (run.planing_force_t >= z0) & (run.planing_force_t <= z1)
        series += [run.delta_c[ck] if run.command_t.size else np.zeros(0),
                   run.planing_force[fk]]
        for ax, y in zip(axes[:, 1], series):
            if y.size:
                lo, hi = float(np.min(y)), float(np.max(y))
                pad = 0.05 * (hi - lo) or 0.05 * max(abs(hi), 1e-12)
                ax.set_ylim(lo - pad, hi + pad)
    axes[0, 1].set_xlim(z0, z1)
    axes[0, 1].set_title(f'zoom: last {z1 - z0:.3g} s', fontsize=9)
    axes[0, 0].set_title('whole run', fontsize=9)
    axes[-1, 0].set_xlabel('t (s)')
    axes[-1, 1].set_xlabel('t (s)')
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.suptitle(_title('Time responses', runs), fontsize=10)
    fig.legend(handles, names, loc='lower center', fontsize=8, ncol=1, frameon=False)
    fig.tight_layout(rect=(0, 0.025 * (len(names) + 1), 1, 1))
    save(fig, paths, dpi=120)
    plt.close(fig)


def plot_phase_portrait(runs: Sequence, paths: Sequence[Path], skip: float = 0.0) -> None:
    """w against q after ``skip`` seconds; the legend below the plot."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 6))
    for run in runs:
        keep = run.t >= skip
        ax.plot(run.state[keep, 1], run.state[keep, 3], lw=0.6, label=describe_run(run))
    ax.set_xlabel('w (m/s)')
    ax.set_ylabel('q (rad/s)')
    what = f'Phase portrait (t ≥ {skip:g} s)' if skip else 'Phase portrait'
    ax.set_title(_title(what, runs), fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.12), frameon=False)
    fig.tight_layout()
    save(fig, paths, dpi=120)
    plt.close(fig)


def summary(run) -> dict:
    """Dominant frequency and amplitude of w (last half of the run), peak |Fp|, samples."""
    t, w = run.t, run.state[:, 1]
    half = t >= t[0] + 0.5 * (t[-1] - t[0]) if t.size else np.zeros(0, bool)
    out = {'samples': int(t.size), 'duration_s': float(t[-1] - t[0]) if t.size else 0.0,
           'peak_abs_planing_force': float(np.max(np.abs(run.planing_force)))
           if run.planing_force.size else 0.0}
    if half.sum() > 8:
        y = w[half] - w[half].mean()
        dt = float(np.median(np.diff(t[half])))
        spec = np.abs(np.fft.rfft(y * np.hanning(y.size)))
        freqs = np.fft.rfftfreq(y.size, dt)
        k = int(np.argmax(spec[1:]) + 1)
        out.update({'w_dominant_frequency_hz': float(freqs[k]),
                    'w_peak_to_peak': float(np.ptp(w[half])), 'w_mean': float(w[half].mean()),
                    'frequency_resolution_hz': float(freqs[1])})
    return out
