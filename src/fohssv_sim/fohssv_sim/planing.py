"""Normalised planing force Fp (physical force / rho pi R^2, m^2/s^2, positive down).

Three forms, all sharing eq. 10 (with the leading minus of docs/model.md §9.3)::

    Fp = -V^2 [1 - (R'/(h + R'))^2] (1 + h)/(1 + 2h) alpha_p

* :func:`planing_exact`: delay-free switching immersion, eqs. 12-14 / docs/model.md §3.3;
* :func:`planing_delayed`: immersion from delayed states, eqs. 22-25 / docs/model.md §4;
* :func:`planing_smooth`: the tanh-smoothed form of the FOM, eqs. 28-29 / docs/model.md §5.2.

The scalar functions work in float arithmetic (the plant calls them at every stage);
:func:`planing_smooth_array` and :func:`planing_exact_array` are their numpy counterparts for
batched runs.
"""

from __future__ import annotations

import math

import numpy as np

from .coefficients import Coefficients

__all__ = [
    'planing_force_law',
    'planing_exact',
    'planing_delayed',
    'planing_smooth',
    'planing_exact_array',
    'planing_smooth_array',
]


def planing_force_law(h: float, alpha_p: float, c: Coefficients) -> float:
    """Eq. 10 for immersion depth ``h`` (in body radii) and planing angle ``alpha_p``."""
    rp = c.R_prime
    ratio = rp / (h + rp)
    return -c.V * c.V * (1.0 - ratio * ratio) * (1.0 + h) / (1.0 + 2.0 * h) * alpha_p


def planing_exact(w: float, c: Coefficients) -> float:
    """Delay-free planing force with the exact switching immersion (eqs. 10, 12-14).

    h* = L w / (R V); the tail touches the wall when |h*| > R', i.e. |w| > R'RV/L.
    """
    hs = c.L * w / (c.R * c.V)
    rp = c.R_prime
    if hs > rp:
        return planing_force_law(hs - rp, (w - c.Rc_dot) / c.V, c)
    if hs < -rp:
        return planing_force_law(-hs - rp, (w + c.Rc_dot) / c.V, c)
    return 0.0


def planing_delayed(z: float, theta: float, z_tau: float, w_tau: float, theta_tau: float,
                    c: Coefficients, form: str = 'paper') -> float:
    """Planing force of the delayed model (eqs. 22-25), from the states now and at t - tau.

    ``form='paper'``: h* = [z - z_tau + L (theta - theta_tau) + L w_tau / V] / R (eq. 25 as
    printed); ``form='geometric'``: h* = [z - z_tau + L theta] / R (docs/model.md §9.9). In both,
    alpha_p = theta - theta_tau + (w_tau -+ Rc_dot)/V on the lower/upper wall.
    """
    if form == 'paper':
        hs = (z - z_tau + c.L * (theta - theta_tau) + c.L * w_tau / c.V) / c.R
    else:
        hs = (z - z_tau + c.L * theta) / c.R
    rp = c.R_prime
    if hs > rp:
        return planing_force_law(hs - rp, theta - theta_tau + (w_tau - c.Rc_dot) / c.V, c)
    if hs < -rp:
        return planing_force_law(-hs - rp, theta - theta_tau + (w_tau + c.Rc_dot) / c.V, c)
    return 0.0


def planing_smooth(w: float, c: Coefficients) -> float:
    """Smooth planing force of the FOM (eqs. 28-29, the one-typo reading of docs/model.md §9.6).

    h = tanh(k w) L/(2RV) [2w - (w + w0) tanh(k(w + w0)) + (w - w0) tanh(k(w - w0))],
    clipped at h >= 0; alpha_p = w/V - tanh(k w) Rc_dot / V. As k -> inf this tends to
    :func:`planing_exact` when w0 = R'RV/L.
    """
    k, w0 = c.k, c.w0
    s = math.tanh(k * w)
    h = s * c.L / (2.0 * c.R * c.V) * (
        2.0 * w - (w + w0) * math.tanh(k * (w + w0)) + (w - w0) * math.tanh(k * (w - w0)))
    if h < 0.0:
        h = 0.0
    return planing_force_law(h, w / c.V - s * c.Rc_dot / c.V, c)


def _law_array(h: np.ndarray, alpha_p: np.ndarray, c: Coefficients) -> np.ndarray:
    rp = c.R_prime
    ratio = rp / (h + rp)
    return -c.V * c.V * (1.0 - ratio * ratio) * (1.0 + h) / (1.0 + 2.0 * h) * alpha_p


def planing_exact_array(w: np.ndarray, c: Coefficients) -> np.ndarray:
    """:func:`planing_exact` over an array of ``w``."""
    w = np.asarray(w, dtype=float)
    hs = c.L * w / (c.R * c.V)
    rp = c.R_prime
    upper = hs > rp
    lower = hs < -rp
    h = np.where(upper, hs - rp, np.where(lower, -hs - rp, 0.0))
    ap = np.where(upper, (w - c.Rc_dot) / c.V, np.where(lower, (w + c.Rc_dot) / c.V, 0.0))
    return _law_array(h, ap, c)


def planing_smooth_array(w: np.ndarray, c: Coefficients) -> np.ndarray:
    """:func:`planing_smooth` over an array of ``w``."""
    w = np.asarray(w, dtype=float)
    k, w0 = c.k, c.w0
    s = np.tanh(k * w)
    h = s * c.L / (2.0 * c.R * c.V) * (
        2.0 * w - (w + w0) * np.tanh(k * (w + w0)) + (w - w0) * np.tanh(k * (w - w0)))
    h = np.maximum(h, 0.0)
    return _law_array(h, w / c.V - s * c.Rc_dot / c.V, c)
