"""Matignon stability of the closed loop (Fig. 5) and the critical order over speed.

Pure: numpy, scipy and matplotlib (Agg); no ROS.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..equilibria import Equilibrium, find_equilibria
from ..params import ModelParameters
from .figures import pyplot, save, titled

__all__ = ['StabilityPoint', 'critical_order_curve', 'plot_wedge', 'plot_critical_order']


@dataclass(frozen=True)
class StabilityPoint:
    """alpha_c at one speed (NaN when no equilibrium was found)."""

    speed: float
    critical_order: float
    state: tuple[float, ...]


def critical_order_curve(params: ModelParameters, controller: Any,
                         speeds: Sequence[float]) -> list[StabilityPoint]:
    """alpha_c(V) of the equilibrium nearest the cavity centre at each speed (Matignon: the
    FOM equilibrium is stable for alpha < alpha_c)."""
    out = []
    for v in speeds:
        eqs = find_equilibria(params.replace(speed=float(v)), controller)
        if not eqs:
            out.append(StabilityPoint(float(v), math.nan, ()))
            continue
        e = min(eqs, key=lambda e: abs(e.state[1]))
        out.append(StabilityPoint(float(v), e.critical_order, tuple(map(float, e.state))))
    return out


def plot_wedge(eq: Equilibrium, alpha: float, paths: Sequence[Path], title: str = '', *,
               speed: float | None = None, label: str = '') -> Any:
    """Eigenvalues of the Jacobian and the Matignon wedge |arg lambda| = alpha pi/2 (Fig. 5).
    Eigenvalues outside the shaded unstable sector mean stability at this alpha. The title
    names the speed V of the equilibrium (``speed``) and ``label``. Returns the (closed)
    figure."""
    plt = pyplot()
    lam = eq.eigenvalues
    r = 1.15 * max(1.0, float(np.max(np.abs(lam))))
    fig, ax = plt.subplots(figsize=(6, 5))
    phi = alpha * math.pi / 2
    arc = np.linspace(-phi, phi, 200)
    big = 3.0 * r   # beyond the axes: the sector reaches the frame
    ax.fill(np.r_[0.0, big * np.cos(arc)], np.r_[0.0, big * np.sin(arc)], color='tab:red',
            alpha=0.12, label=f'unstable sector |arg λ| ≤ απ/2 (α = {alpha:g})')
    for s in (1, -1):
        ax.plot([0, big * math.cos(phi)], [0, s * big * math.sin(phi)], color='tab:red', lw=1)
    stable = eq.stable(alpha)
    ax.plot(lam.real, lam.imag, 'o', color='tab:blue', label='eigenvalues of J(x*)')
    ax.axhline(0, color='k', lw=0.5)
    ax.axvline(0, color='k', lw=0.5)
    ax.set_xlim(-r, r)
    ax.set_ylim(-r, r)
    ax.set_xlabel('Re λ (1/s)')
    ax.set_ylabel('Im λ (1/s)')
    verdict = 'stable' if stable else 'unstable'
    at = f'V = {speed:g} m/s, ' if speed is not None else ''
    ax.set_title(titled(title or f'Matignon test at {at}α = {alpha:g}: {verdict} (α_c = '
                        f'{eq.critical_order:.4f})', label), fontsize=10)
    ax.legend(loc='lower left', fontsize=8)
    fig.tight_layout()
    save(fig, paths)
    plt.close(fig)
    return fig


def plot_critical_order(points: Sequence[StabilityPoint], paths: Sequence[Path],
                        alpha: float | None = None, *, caption: str = '', label: str = ''
                        ) -> Any:
    """alpha_c against V; the equilibrium is Matignon-stable below the curve. ``caption``
    (e.g. the model and controller) is the title's second line. Returns the (closed)
    figure."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    v = [p.speed for p in points]
    a = [p.critical_order for p in points]
    ax.plot(v, a, '.-', label='α_c(V): stable below')
    if alpha is not None:
        ax.axhline(alpha, color='tab:red', lw=1, ls='--', label=f'α = {alpha:g}')
    ax.set_xlabel('V (m/s)')
    ax.set_ylabel('critical order α_c')
    title = 'Critical order α_c(V) of the closed-loop equilibrium (Matignon, eq. 30)'
    ax.set_title(titled(title + (f'\n{caption}' if caption else ''), label), fontsize=9)
    ax.legend()
    fig.tight_layout()
    save(fig, paths)
    plt.close(fig)
    return fig
