"""Normalised planing force Fp (physical force / rho pi R^2, m^2/s^2, positive down).

Three forms, all sharing eq. 10 (with the leading minus of docs/model.md §9.3)::

    Fp = -V^2 [1 - (R'/(h + R'))^2] (1 + h)/(1 + 2h) alpha_p

* :func:`planing_exact`: delay-free switching immersion, eqs. 12-14 / docs/model.md §3.3;
* :func:`planing_delayed`: immersion from delayed states, eqs. 22-25 / docs/model.md §4;
* :func:`planing_smooth`: the tanh-smoothed form of the FOM, eqs. 28-29 / docs/model.md §5.2.

The scalar functions work in float arithmetic and are defined once in :mod:`.kernels` (the
interpreted models and the compiled kernels run the same source; re-exported here);
:func:`planing_smooth_array` and :func:`planing_exact_array` are their numpy counterparts for
batched runs.
"""

from __future__ import annotations

import numpy as np

from .coefficients import Coefficients
from .physics import planing_delayed, planing_exact, planing_force_law, planing_smooth

__all__ = [
    'planing_force_law',
    'planing_exact',
    'planing_delayed',
    'planing_smooth',
    'planing_exact_array',
    'planing_smooth_array',
]


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
