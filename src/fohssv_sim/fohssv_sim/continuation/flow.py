"""The delay-free closed loop's flow and its variational equations, compiled (numba): fixed-step
RK4 with each step split at a contact of the tail with the cavity wall.

Shooting needs x(T; x0) and the monodromy X(T) = dx(T)/dx0 some ten times per branch point.
This integrates the closed loop of eq. 17 with the exact switching planing force
(:func:`fohssv_sim.physics.planing_exact`) and the clamped affine law u = clip(K x + u0), and
with it X' = df/dx X, X(0) = I, in one compiled loop: ``steps`` equal RK4 steps of T/steps
(a fixed count, so x(T) is a smooth function of T as well as of x0).

**Contact.** The field is continuous across the contact surfaces w = +-w_c (w_c = R'RV/L) but
its slope jumps there, so a step straddling one would lose RK4's order. A step whose end lies
in another region than its start is cut at the crossing (the time where the RK4 step of that
length lands on the surface, by the Illinois method to round-off) and restarted there; the
saltation matrix is the identity (continuous field), so X needs no correction. A grazing
contact inside one step (in and out again) is not split.

Within a step the planing force is the formula of the region the step started in (eqs. 12-14:
lower wall, clear, upper wall), so each step is a smooth map and its RK4 variational step is
that map's exact derivative. df/dx is A + B K' + D Fp'(w) e_w (K' the rows of K whose output
is not clamped), evaluated as eq. 17 of unit vectors; Fp' by central differences of the
region's formula. The law's clamp is not split (a kink of u, not of the contact).
"""

from __future__ import annotations

import numpy as np

from ..kernels import unpack_coefficients
from ..physics import eq17, jitable, planing_delayed, planing_force_law

try:
    import numba
except ImportError:  # pragma: no cover - numba is pinned in requirements.txt
    numba = None

__all__ = ['flow', 'pack_coefficients', 'planing_delayed_many', 'warm_up']


def _njit(fn):
    if numba is None:  # pragma: no cover
        return fn
    return numba.njit(cache=True, nogil=True, error_model='numpy')(fn)


def pack_coefficients(c) -> np.ndarray:
    """The kernel scalars of :class:`fohssv_sim.coefficients.Coefficients` as a float array
    (:class:`~fohssv_sim.coefficients.KernelCoefficients` order)."""
    return np.asarray(tuple(c.kernel), dtype=float)


@jitable
def _planing(w, c, region):
    """The planing force of the branch of eqs. 12-14 that holds in ``region`` (-1, 0, 1: lower
    wall, clear, upper wall), continued a little past its surface: within one step the field
    is one smooth formula, as :func:`fohssv_sim.physics.planing_exact` is between contacts."""
    if region == 0:
        return 0.0
    hs = c.L * w / (c.R * c.V)
    if region > 0:
        return planing_force_law(hs - c.R_prime, (w - c.Rc_dot) / c.V, c)
    return planing_force_law(-hs - c.R_prime, (w + c.Rc_dot) / c.V, c)


@jitable
def _rhs(cv, law, x, region, out):
    """f(x) into ``out`` on the branch ``region``; returns the two 'not clamped' flags of the
    law's outputs."""
    uf = law[0] * x[0] + law[1] * x[1] + law[2] * x[2] + law[3] * x[3] + law[8]
    uc = law[4] * x[0] + law[5] * x[1] + law[6] * x[2] + law[7] * x[3] + law[9]
    free_f = abs(uf) < law[10]
    free_c = abs(uc) < law[11]
    uf = max(-law[10], min(law[10], uf))
    uc = max(-law[11], min(law[11], uc))
    c = unpack_coefficients(cv)
    f = eq17(c, x[1], x[2], x[3], uf, uc, _planing(x[1], c, region))
    out[0], out[1], out[2], out[3] = f[0], f[1], f[2], f[3]
    return free_f, free_c


@jitable
def _jac(cv, law, x, region, J):
    """df/dx at x on the branch ``region`` into the 4 x 4 ``J``."""
    tmp = np.empty(4)
    free_f, free_c = _rhs(cv, law, x, region, tmp)
    c = unpack_coefficients(cv)
    w = x[1]
    d = 1e-7 * max(1.0, abs(w))
    slope = (_planing(w + d, c, region) - _planing(w - d, c, region)) / (2.0 * d)
    base = eq17(c, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for j in range(4):
        e = np.zeros(4)
        e[j] = 1.0
        gf = law[j] if free_f else 0.0
        gc = law[4 + j] if free_c else 0.0
        col = eq17(c, e[1], e[2], e[3], gf, gc, slope * e[1])
        for i in range(4):
            J[i, j] = col[i] - base[i]


@jitable
def _region(w, wc):
    if w > wc:
        return 1
    if w < -wc:
        return -1
    return 0


@jitable
def _step(cv, law, x, X, h, region, variational, xo, Xo):
    """One RK4 step of length h of x (and X if ``variational``) into xo, Xo, on the branch
    ``region``."""
    k = np.empty((4, 4))
    xs = x.copy()
    J = np.empty((4, 4))
    K = np.zeros((4, 4, 4))
    Xs = X.copy()
    weights = (0.0, 0.5, 0.5, 1.0)
    for s in range(4):
        if s > 0:
            a = weights[s] * h
            for i in range(4):
                xs[i] = x[i] + a * k[s - 1, i]
            if variational:
                Xs[:, :] = X + a * K[s - 1]
        ks = np.empty(4)
        _rhs(cv, law, xs, region, ks)
        k[s] = ks
        if variational:
            _jac(cv, law, xs, region, J)
            for i in range(4):
                for j in range(4):
                    K[s, i, j] = J[i, 0] * Xs[0, j] + J[i, 1] * Xs[1, j] + \
                        J[i, 2] * Xs[2, j] + J[i, 3] * Xs[3, j]
    g = h / 6.0
    for i in range(4):
        xo[i] = x[i] + g * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])
    if variational:
        Xo[:, :] = X + g * (K[0] + 2.0 * K[1] + 2.0 * K[2] + K[3])


@jitable
def _crossing(cv, law, x, h, region, surface):
    """The length in (0, h) of the RK4 step from x (on the branch ``region``) that lands on
    w = ``surface`` (Illinois method, to round-off)."""
    xo = np.empty(4)
    dummy = np.empty((4, 4))
    a, b = 0.0, h
    ga = x[1] - surface
    _step(cv, law, x, dummy, b, region, False, xo, dummy)
    gb = xo[1] - surface
    side = 0
    m = 0.5 * h
    for _ in range(60):
        m_new = (a * gb - b * ga) / (gb - ga)
        if abs(m_new - m) <= 1e-15 * h:
            return m_new
        m = m_new
        _step(cv, law, x, dummy, m, region, False, xo, dummy)
        gm = xo[1] - surface
        if gm == 0.0:
            break
        if (gm > 0.0) == (gb > 0.0):
            b, gb = m, gm
            if side == -1:
                ga *= 0.5
            side = -1
        else:
            a, ga = m, gm
            if side == 1:
                gb *= 0.5
            side = 1
    return m


@_njit
def flow(x0, T, steps, cv, law, variational, every, record):
    """x(T) and X(T) from x0 by ``steps`` RK4 steps (split at contact); with ``every`` > 0 the
    state at every ``every``-th step boundary is written to ``record`` (rows 0, 1, ...)."""
    wc = cv[14] * cv[2] * cv[0] / cv[1]
    h = T / steps
    x = x0.copy()
    X = np.eye(4)
    xo = np.empty(4)
    Xo = np.empty((4, 4))
    region = _region(x[1], wc)
    for n in range(steps):
        if every > 0 and n % every == 0:
            record[n // every] = x
        left = h
        for _ in range(8):                 # at most a few contacts within one step
            _step(cv, law, x, X, left, region, variational, xo, Xo)
            new = _region(xo[1], wc)
            if new == region:
                break
            # crossed out of `region` towards `new`: the first surface on the way
            if new > region:
                surface = -wc if region == -1 else wc
            else:
                surface = wc if region == 1 else -wc
            m = _crossing(cv, law, x, left, region, surface)
            _step(cv, law, x, X, m, region, variational, xo, Xo)
            x[:] = xo
            x[1] = surface
            if variational:
                X[:, :] = Xo
            left -= m
            region = region + (1 if new > region else -1)
        x[:] = xo
        if variational:
            X[:, :] = Xo
    if every > 0 and steps % every == 0:
        record[steps // every] = x
    return x, X


@_njit
def planing_delayed_many(X, Xd, cv, form):
    """The delayed model's planing force (:func:`fohssv_sim.physics.planing_delayed`) at N
    states X and delayed states Xd (each (4, N)), compiled: harmonic balance of the delayed
    model and its monodromy operator evaluate it at thousands of points per branch point."""
    c = unpack_coefficients(cv)
    out = np.empty(X.shape[1])
    for i in range(X.shape[1]):
        out[i] = planing_delayed(X[0, i], X[2, i], Xd[0, i], Xd[1, i], Xd[2, i], c, form)
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) :func:`flow` and :func:`planing_delayed_many` with
    the argument types the continuation passes (``make test`` calls it once, before the test
    workers start: each worker whose first branch came before another had written the cache
    compiled them again)."""
    from ..coefficients import coefficients
    from ..kernels import pack_law
    from ..params import ModelParameters

    cv = pack_coefficients(coefficients(ModelParameters(model='delay-free')))
    flow(np.zeros(4), 1e-3, 4, cv, pack_law(), True, 2, np.empty((3, 4)))
    X = np.zeros((4, 2))
    planing_delayed_many(X, X.copy(), cv, 'paper')
