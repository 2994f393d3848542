"""Time responses (Figs. 3-4) and the w-q phase portrait (Fig. 7) of recorded runs."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ['plot_time_responses', 'plot_phase_portrait', 'describe_run']


def _plt():
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def describe_run(run) -> str:
    """One line naming the model, order, speed, step and control period of a run."""
    p = run.parameters
    if not p:
        return run.path.name
    model = p.get('model', '?')
    alpha = f", α={p['fractional_order']:g}" if model == 'fractional' and isinstance(
        p.get('fractional_order'), float) else ''
    step = p.get('step')
    cp = p.get('control_period')
    extra = ''
    if isinstance(step, float):
        extra += f', h={step:g} s'
    if isinstance(cp, float):
        extra += f', ZOH {cp:g} s'
    speed = p.get('speed')
    v = f', V={speed:g}' if isinstance(speed, float) else ''
    return f'{run.path.name}: {model}{alpha}{v}{extra}'


def plot_time_responses(runs: Sequence, paths: Sequence[Path]) -> None:
    """z, w, theta, q, delta_c and Fp against time; several runs overlay."""
    plt = _plt()
    fig, axes = plt.subplots(6, 1, figsize=(9, 11), sharex=True)
    labels = ('z (m)', 'w (m/s)', 'θ (rad)', 'q (rad/s)', 'δc (rad)', 'Fp (m²/s²)')
    for run in runs:
        name = describe_run(run)
        for i in range(4):
            axes[i].plot(run.t, run.state[:, i], lw=0.8, label=name)
        if run.command_t.size:
            axes[4].step(run.command_t, run.delta_c, where='post', lw=0.8, label=name)
        axes[5].plot(run.planing_force_t, run.planing_force, lw=0.8, label=name)
    for ax, label in zip(axes, labels):
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel('t (s)')
    axes[0].legend(fontsize=7, loc='upper right')
    fig.suptitle('Time responses', fontsize=10)
    fig.tight_layout()
    for p in paths:
        fig.savefig(p, dpi=120)
    plt.close(fig)


def plot_phase_portrait(runs: Sequence, paths: Sequence[Path], skip: float = 0.0) -> None:
    """w against q after ``skip`` seconds."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 5))
    for run in runs:
        keep = run.t >= skip
        ax.plot(run.state[keep, 1], run.state[keep, 3], lw=0.6, label=describe_run(run))
    ax.set_xlabel('w (m/s)')
    ax.set_ylabel('q (rad/s)')
    ax.set_title(f'Phase portrait (t ≥ {skip:g} s)' if skip else 'Phase portrait', fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    for p in paths:
        fig.savefig(p, dpi=120)
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
