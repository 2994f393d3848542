"""The model's physics, written once: eq. 17, the planing forces and the delayed history.

Eq. 17's right-hand side, the three planing forces (eq. 10 with the switching immersion of
eqs. 12-14, the delayed one of eqs. 22-25, the smooth one of eqs. 28-29) and the delayed
model's Hermite history are plain float arithmetic marked ``@jitable`` (numba's
``register_jitable``): called from Python they run interpreted, as the models in
:mod:`.models` call them; called from a compiled loop of :mod:`.kernels` they are compiled
inline. So the interpreted models and the compiled kernels evaluate the same source. Without
numba, ``jitable`` is the identity and everything runs interpreted.
"""

from __future__ import annotations

import math

try:
    from numba.extending import register_jitable as jitable
except ImportError:  # pragma: no cover - numba is pinned in requirements.txt
    def jitable(fn):
        return fn

__all__ = ['jitable', 'eq17', 'planing_force_law', 'planing_exact', 'planing_delayed',
           'planing_smooth', 'hermite_delayed']


@jitable
def eq17(c, w, th, q, uf, uc, fp):
    """dx/dt = A x + B u + G + D Fp of eq. 17 in float arithmetic (z does not enter)."""
    return (w - c.V * th,
            c.a22 * w + c.a24 * q + c.b21 * uf + c.b22 * uc + c.g + c.d2 * fp,
            q,
            c.a42 * w + c.a44 * q + c.b41 * uf + c.b42 * uc + c.d4 * fp)


@jitable
def planing_force_law(h, alpha_p, c):
    """Eq. 10 for immersion depth ``h`` (in body radii) and planing angle ``alpha_p``."""
    rp = c.R_prime
    ratio = rp / (h + rp)
    return -c.V * c.V * (1.0 - ratio * ratio) * (1.0 + h) / (1.0 + 2.0 * h) * alpha_p


@jitable
def planing_exact(w, c):
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


@jitable
def planing_delayed(z, theta, z_tau, w_tau, theta_tau, c, form='paper'):
    """Planing force of the delayed model (eqs. 22-25), from the states now and at t - tau.

    ``form='paper'``: h* = [z - z_tau + L (theta - theta_tau) + L w_tau / V] / R (eq. 25 as
    printed); ``form='geometric'``: h* = [z - z_tau + L theta] / R (docs/model.md §9.9). In
    both, alpha_p = theta - theta_tau + (w_tau -+ Rc_dot)/V on the lower/upper wall.
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


@jitable
def planing_smooth(w, c):
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


@jitable
def hermite_delayed(hx, hf, n, c_stage, lag, h, x_init):
    """x(t_n + c h - tau) from the history rings (states ``hx``, derivatives ``hf``, row k % size
    for step k) by cubic Hermite interpolation, or x(0) = ``x_init`` before t = 0."""
    s = n + c_stage - lag   # in steps
    if s <= 0.0:
        return x_init[0], x_init[1], x_init[2], x_init[3]
    size = hx.shape[0]
    k = int(s)
    theta = s - k
    i = k % size
    if theta == 0.0:
        return hx[i, 0], hx[i, 1], hx[i, 2], hx[i, 3]
    j = (k + 1) % size
    t2, t3 = theta * theta, theta * theta * theta
    h00 = 2.0 * t3 - 3.0 * t2 + 1.0
    h10 = (t3 - 2.0 * t2 + theta) * h
    h01 = -2.0 * t3 + 3.0 * t2
    h11 = (t3 - t2) * h
    return (h00 * hx[i, 0] + h10 * hf[i, 0] + h01 * hx[j, 0] + h11 * hf[j, 0],
            h00 * hx[i, 1] + h10 * hf[i, 1] + h01 * hx[j, 1] + h11 * hf[j, 1],
            h00 * hx[i, 2] + h10 * hf[i, 2] + h01 * hx[j, 2] + h11 * hf[j, 2],
            h00 * hx[i, 3] + h10 * hf[i, 3] + h01 * hx[j, 3] + h11 * hf[j, 3])
