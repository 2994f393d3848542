"""The compiled loops that step the model: RK4, delayed RK4 and the FOM's ABM with SOE history.

The physics they step (eq. 17, the planing forces, the Hermite history) is :mod:`.physics`,
plain ``@jitable`` arithmetic compiled inline here and run interpreted by :mod:`.models`.

**Kernels.** Each ``*_run`` function takes many integration steps of one model in one compiled
call, advancing the model's own arrays in place (the plant calls one per control period):

* :func:`delay_free_run` -- classical RK4 of eq. 17;
* :func:`delayed_run` -- RK4 by the method of steps, delayed states from the Hermite history;
* :func:`fom_soe_run` -- the ABM predictor-corrector of the FOM with the sum-of-exponentials
  history of :class:`fohssv_sim.fractional.soe.SOEHistory` (the same arrays).

The input is an affine law evaluated at every stage, packed as ``law`` = [K (2x4, row-major),
u0 (2), limit (2)]: u = clamp(K x + u0, limit) when ``continuous``, else u = u0 held over the
call (zero-order hold). The time-stepping loops are the compiled twins of the interpreted
steppers (RK4 in :mod:`.models`, the PECE driver of :mod:`.fractional.abm`), tested against them
step for step (``test/test_kernels.py``). Each kernel returns the number of steps taken: fewer
than asked when a state turned non-finite; that state is left in ``bad`` and the arrays hold
the last finite step.

**Drivers.** The compiled loops that run many control periods with a sampled law, or keep
every k-th step of a run, are in :mod:`.drivers`, over these kernels.

**Held-input entry point.** A plant stepping the FOM one control period at a time with the
input held (lockstep, real time with an external controller) calls :func:`fom_soe_run` once
per sample with 20 arguments; numba's dispatcher checks the type of each, 1.7 us a call warm
and about 7 us inside the lockstep round trip, as much as the period's arithmetic.
:class:`FomHeldCall` binds the arrays' addresses once (a table of int64) and calls the same
kernel through a C entry point (``numba.cfunc``, called with ctypes: 0.5 us warm) with only
the step index and the step count: the same arithmetic, bit for bit.

**A period prepared ahead.** Of an ABM step's sums, all but those over the period's own
values (at step i of a period its last i + 1 rows of the about 110: f_0, 80 modes and a
window of 16-48 values) and a fold of the window into the modes (every K = 32 steps, the
costliest part) depend only on what came before the period. :func:`_prepare_period`
does them ahead for a held-input period and :func:`fom_soe_prepared_run` finishes it once the
input is known, with the same sums in the same order as :func:`fom_soe_run` (bit for bit,
``test_kernels.py``): the plant's compiled sample prepares the next period while the state it
just published travels, and the command's round trip waits for the rest only (about 0.8 us
of the period's 2.7 in one process; periods of up to n0 = 16 steps, so that a fold never
takes a value of the period itself).

Compiled on first use and cached on disk (``cache=True``, next to this file or in numba's
user cache); :func:`fohssv_sim.models.warm_up` compiles them all, through the plants (a few
seconds the first time, well under a second from the cache). Without numba everything still
runs, interpreted.
"""

from __future__ import annotations

import ctypes
import functools
import math
import warnings
from typing import Any

import numpy as np

from .coefficients import KernelCoefficients
from .physics import eq17, hermite_delayed, jitable, planing_delayed, planing_exact, planing_smooth

try:
    import numba
except ImportError:  # pragma: no cover - numba is pinned in requirements.txt
    numba = None

__all__ = ['AVAILABLE', 'KernelCoefficients', 'delay_free_run', 'delayed_run', 'fom_soe_run',
           'FomHeldCall', 'pack_law', 'unpack_coefficients']

#: True when the kernels run compiled (numba importable).
AVAILABLE = numba is not None


# -- helpers of the loops ---------------------------------------------------------------------

def pack_law(K=None, u0=(0.0, 0.0), limit=(math.inf, math.inf)) -> np.ndarray:
    """The ``law`` array of the kernels: [K (2x4, row-major), u0 (2), limit (2)]."""
    out = np.zeros(12)
    if K is not None:
        out[:8] = np.asarray(K, dtype=float).reshape(8)
    out[8:10] = u0
    out[10:12] = limit
    return out


@jitable
def unpack_coefficients(cv):
    return KernelCoefficients(cv[0], cv[1], cv[2], cv[3], cv[4], cv[5], cv[6], cv[7], cv[8],
                              cv[9], cv[10], cv[11], cv[12], cv[13], cv[14], cv[15], cv[16],
                              cv[17])


@jitable
def _clamp(value, limit):
    return max(-limit, min(limit, value))


@jitable
def _input(law, continuous, z, w, th, q):
    """(delta_f, delta_c) at a stage: the held u0, or clamp(K x + u0) (same summation order
    as the eq. 31 controller's ``update``)."""
    if not continuous:
        return law[8], law[9]
    uf = (law[0] * z + law[1] * w + law[2] * th + law[3] * q) + law[8]
    uc = (law[4] * z + law[5] * w + law[6] * th + law[7] * q) + law[9]
    return _clamp(uf, law[10]), _clamp(uc, law[11])


@jitable
def _finite4(a, b, c, d):
    return math.isfinite(a) and math.isfinite(b) and math.isfinite(c) and math.isfinite(d)


@jitable
def _fail(bad, a, b, c, d):
    bad[0], bad[1], bad[2], bad[3] = a, b, c, d


@jitable
def _shift(x, k, a):
    """x + a k for 4-tuples (an RK4 stage point)."""
    return x[0] + a * k[0], x[1] + a * k[1], x[2] + a * k[2], x[3] + a * k[3]


@jitable
def _rk4_sum(x, k1, k2, k3, k4, h):
    """The RK4 update x + h/6 (k1 + 2 k2 + 2 k3 + k4), in the interpreted models' order."""
    g = h / 6.0
    return (x[0] + g * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
            x[1] + g * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
            x[2] + g * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]),
            x[3] + g * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]))


def _njit(fn):
    if numba is None:  # pragma: no cover
        return fn
    return numba.njit(cache=True, nogil=True, error_model='numpy')(fn)


# -- delay-free model: RK4 ----------------------------------------------------------------------

@jitable
def _planing(c, smooth, w):
    """Fp of the integer and fractional models at ``w``: the smooth form or the exact one."""
    return planing_smooth(w, c) if smooth else planing_exact(w, c)


@jitable
def _rhs_free(c, smooth, w, th, q, uf, uc):
    return eq17(c, w, th, q, uf, uc, _planing(c, smooth, w))


@jitable
def _free_step(c, smooth, law, continuous, xs, h, hh):
    """One RK4 step of eq. 17 from the 4-tuple ``xs``: the new state (a 4-tuple) and Fp at
    ``xs`` (its first stage's, for a caller that keeps it)."""
    uf, uc = _input(law, continuous, xs[0], xs[1], xs[2], xs[3])
    fp = _planing(c, smooth, xs[1])
    k1 = eq17(c, xs[1], xs[2], xs[3], uf, uc, fp)
    x2 = _shift(xs, k1, hh)
    uf, uc = _input(law, continuous, x2[0], x2[1], x2[2], x2[3])
    k2 = _rhs_free(c, smooth, x2[1], x2[2], x2[3], uf, uc)
    x3 = _shift(xs, k2, hh)
    uf, uc = _input(law, continuous, x3[0], x3[1], x3[2], x3[3])
    k3 = _rhs_free(c, smooth, x3[1], x3[2], x3[3], uf, uc)
    x4 = _shift(xs, k3, h)
    uf, uc = _input(law, continuous, x4[0], x4[1], x4[2], x4[3])
    k4 = _rhs_free(c, smooth, x4[1], x4[2], x4[3], uf, uc)
    return _rk4_sum(xs, k1, k2, k3, k4, h), fp


@_njit
def delay_free_run(x, nsteps, h, cv, smooth, law, continuous, bad):
    """``nsteps`` RK4 steps of eq. 17 from ``x`` (4,), in place; returns the steps taken."""
    c = unpack_coefficients(cv)
    xs = (x[0], x[1], x[2], x[3])
    hh = 0.5 * h
    taken = nsteps
    for i in range(nsteps):
        xn, _ = _free_step(c, smooth, law, continuous, xs, h, hh)
        if not _finite4(xn[0], xn[1], xn[2], xn[3]):
            _fail(bad, xn[0], xn[1], xn[2], xn[3])
            taken = i
            break
        xs = xn
    x[0], x[1], x[2], x[3] = xs
    return taken


# -- delayed model: RK4 by the method of steps -------------------------------------------------

@jitable
def _planing_at_delay(c, paper, hx, hf, n, c_stage, lag, tau, h, x_init, xs):
    """Fp of the delayed model at the stage ``c_stage`` of step ``n``, state ``xs``: the
    delayed states from the history rings (Hermite), or ``xs``'s own when tau = 0."""
    if tau == 0.0:
        zd, wd, thd = xs[0], xs[1], xs[2]
    else:
        zd, wd, thd, _ = hermite_delayed(hx, hf, n, c_stage, lag, h, x_init)
    return planing_delayed(xs[0], xs[2], zd, wd, thd, c, 'paper' if paper else 'geometric')


@jitable
def _rhs_delayed(c, paper, hx, hf, n, c_stage, lag, tau, h, x_init, xs, uf, uc):
    fp = _planing_at_delay(c, paper, hx, hf, n, c_stage, lag, tau, h, x_init, xs)
    return eq17(c, xs[1], xs[2], xs[3], uf, uc, fp)


@jitable
def _delayed_step(c, paper, hx, hf, m, lag, tau, h, hh, x_init, law, continuous, xs):
    """One RK4 step of eqs. 22-25, step ``m`` from the 4-tuple ``xs``: writes x_m and f_m into
    the history rings; the new state (a 4-tuple) and Fp at ``xs`` (its first stage's)."""
    r = m % hx.shape[0]
    hx[r, 0], hx[r, 1], hx[r, 2], hx[r, 3] = xs
    uf, uc = _input(law, continuous, xs[0], xs[1], xs[2], xs[3])
    fp = _planing_at_delay(c, paper, hx, hf, m, 0.0, lag, tau, h, x_init, xs)
    k1 = eq17(c, xs[1], xs[2], xs[3], uf, uc, fp)
    hf[r, 0], hf[r, 1], hf[r, 2], hf[r, 3] = k1     # f_m: the Hermite slope at t_m
    x2 = _shift(xs, k1, hh)
    uf, uc = _input(law, continuous, x2[0], x2[1], x2[2], x2[3])
    k2 = _rhs_delayed(c, paper, hx, hf, m, 0.5, lag, tau, h, x_init, x2, uf, uc)
    x3 = _shift(xs, k2, hh)
    uf, uc = _input(law, continuous, x3[0], x3[1], x3[2], x3[3])
    k3 = _rhs_delayed(c, paper, hx, hf, m, 0.5, lag, tau, h, x_init, x3, uf, uc)
    x4 = _shift(xs, k3, h)
    uf, uc = _input(law, continuous, x4[0], x4[1], x4[2], x4[3])
    k4 = _rhs_delayed(c, paper, hx, hf, m, 1.0, lag, tau, h, x_init, x4, uf, uc)
    return _rk4_sum(xs, k1, k2, k3, k4, h), fp


@_njit
def delayed_run(x, n, nsteps, h, cv, hx, hf, lag, tau, x_init, paper, law, continuous, bad):
    """``nsteps`` RK4 steps of eqs. 22-25 from step ``n`` at ``x``, in place (state and history
    rings ``hx``, ``hf``); returns the steps taken."""
    c = unpack_coefficients(cv)
    xs = (x[0], x[1], x[2], x[3])
    hh = 0.5 * h
    taken = nsteps
    for i in range(nsteps):
        xn, _ = _delayed_step(c, paper, hx, hf, n + i, lag, tau, h, hh, x_init, law,
                              continuous, xs)
        if not _finite4(xn[0], xn[1], xn[2], xn[3]):
            _fail(bad, xn[0], xn[1], xn[2], xn[3])
            taken = i
            break
        xs = xn
    x[0], x[1], x[2], x[3] = xs
    return taken


# -- fractional model: ABM predictor-corrector with the SOE history -----------------------------

@jitable
def _fold_into(H, K, L, eps_k, ET, M):
    """The L modes after folding the K oldest values of the one-group SOE window of ``H``
    into them, written into ``M`` (4 x L: ``H``'s own modes, a view, or a copy of them made
    ahead): each mode's sum over the K values runs in the order r = 0..K-1 from 0.0, the
    modes side by side in the inner loop (contiguous rows of ``ET``, one pass over the K
    values per component instead of one per mode)."""
    base = 1 + L
    acc = np.empty(L)
    for k in range(4):
        for j in range(L):
            acc[j] = 0.0
        for r in range(K):
            v = H[0, k, base + r]
            for j in range(L):
                acc[j] += v * ET[0, r, j]
        for j in range(L):
            mj = H[0, k, 1 + j]
            mj -= mj * eps_k[0, 0, j]
            M[k, j] = mj + acc[j]


@jitable
def _window_append(H, fill, f, n0, K, L):
    """Append f to the window of ``H`` (``fill`` values in it); when it is full, its K oldest
    values, already folded into the modes (:func:`_fold_into`), are dropped first."""
    base = 1 + L
    fw = fill[0]
    if fw == n0 + K:
        for k in range(4):
            for r in range(n0):
                H[0, k, base + r] = H[0, k, base + K + r]
        fw = n0
    for k in range(4):
        H[0, k, base + fw] = f[k]
    fill[0] = fw + 1


@_njit
def _soe_push(H, fill, f, m, n0, K, L, eps_k, ET):
    """Push f_m into the one-group SOE history ``H`` (``fill`` values in its exact window):
    at m = 0 into the f_0 slot; when the window is full its K oldest values are folded into
    the L modes first (:func:`_fold_into`, in place)."""
    if m == 0:
        for k in range(4):
            H[0, k, 0] = f[k]
        return
    if fill[0] == n0 + K:
        _fold_into(H, K, L, eps_k, ET, H[0, :, 1:1 + L])
    _window_append(H, fill, f, n0, K, L)


@_njit
def _f0_weights(m, alpha, a0_coef, a0_small):
    """The weights b(m) and a0(m) of f_0 in the predictor and the corrector at step m."""
    if m == 0:
        return 1.0, a0_small[0, 0]
    bm = m ** alpha * math.expm1(alpha * math.log1p(1.0 / m))
    if m < 64:
        return bm, a0_small[0, m]
    ncoef = a0_coef.shape[1]
    y = 1.0 / m
    acc = a0_coef[0, ncoef - 1]
    for r in range(ncoef - 2, -1, -1):
        acc = acc * y + a0_coef[0, r]
    return bm, m ** (alpha - 1.0) * acc


@jitable
def _soe_shape(eps_k, ET, W):
    """L modes, K values per fold, n0 values a fold keeps, and the first window row (1 + L)
    of a one-group SOE history."""
    L = eps_k.shape[2]
    K = ET.shape[1]
    return L, K, W.shape[0] - 1 - K, 1 + L


@jitable
def _abm_f(x, c, smooth, law, continuous):
    """f at a step's start ``x`` (the held input, or the law's) and Fp there."""
    z, w, th, q = x[0], x[1], x[2], x[3]
    uf, uc = _input(law, continuous, z, w, th, q)
    fp = _planing(c, smooth, w)
    return eq17(c, w, th, q, uf, uc, fp), fp


@jitable
def _abm_rhs(x, c, smooth, law, continuous, last_f):
    """f at the step's start ``x`` (:func:`_abm_f`), also into ``last_f``."""
    f, _ = _abm_f(x, c, smooth, law, continuous)
    last_f[0], last_f[1], last_f[2], last_f[3] = f[0], f[1], f[2], f[3]
    return f


@jitable
def _abm_start(H, m, alpha, a0_coef, a0_small, cp, cc):
    """The predictor's and the corrector's sums of the four components at step m, f_0's terms
    only (the row r = 0 of ``H``)."""
    bm, a0m = _f0_weights(m, alpha, a0_coef, a0_small)
    return (cp * bm * H[0, 0, 0], cp * bm * H[0, 1, 0], cp * bm * H[0, 2, 0],
            cp * bm * H[0, 3, 0], cc * a0m * H[0, 0, 0], cc * a0m * H[0, 1, 0],
            cc * a0m * H[0, 2, 0], cc * a0m * H[0, 3, 0])


@jitable
def _abm_sums(V, W, fw, r0, rows, off, s):
    """The sums ``s`` (predictor's four, corrector's four) continued over the rows r = r0..
    rows-1 of step ``fw``'s weights, the values of row r at ``V[k, r - off]``: eight
    independent chains side by side, each summed in the order r as one at a time would."""
    p0, p1, p2, p3, c0, c1, c2, c3 = s
    for r in range(r0, rows):
        bp = W[fw, 0, r, 0]
        bc = W[fw, 0, r, 1]
        v0 = V[0, r - off]
        v1 = V[1, r - off]
        v2 = V[2, r - off]
        v3 = V[3, r - off]
        p0 += v0 * bp
        p1 += v1 * bp
        p2 += v2 * bp
        p3 += v3 * bp
        c0 += v0 * bc
        c1 += v1 * bc
        c2 += v2 * bc
        c3 += v3 * bc
    return p0, p1, p2, p3, c0, c1, c2, c3


@jitable
def _abm_correct(x, x0, c, smooth, law, continuous, cc, s, bad):
    """The step's predictor and corrector from its sums ``s``: ``x`` advanced in place, or
    False (``bad`` holding the non-finite state, ``x`` unchanged)."""
    p0, p1, p2, p3, c0, c1, c2, c3 = s
    zp = x0[0] + p0
    wp = x0[1] + p1
    tp = x0[2] + p2
    qp = x0[3] + p3
    uf, uc = _input(law, continuous, zp, wp, tp, qp)
    fq = _rhs_free(c, smooth, wp, tp, qp, uf, uc)
    zn = (x0[0] + c0) + cc * fq[0]
    wn = (x0[1] + c1) + cc * fq[1]
    tn = (x0[2] + c2) + cc * fq[2]
    qn = (x0[3] + c3) + cc * fq[3]
    if not _finite4(zn, wn, tn, qn):
        _fail(bad, zn, wn, tn, qn)
        return False
    x[0], x[1], x[2], x[3] = zn, wn, tn, qn
    return True


@jitable
def _abm_step_from(f, x, x0, m, c, smooth, law, continuous, H, W, fill, eps_k, ET, a0_coef,
                  a0_small, alpha, cp, cc, last_f, bad):
    """ABM step ``m`` of :func:`fom_soe_run` from f at its start (:func:`_abm_f`; into
    ``last_f``): ``x`` advanced in place; False when the state turned non-finite (``bad``
    holds it, ``x`` unchanged)."""
    L, K, n0, base = _soe_shape(eps_k, ET, W)
    last_f[0], last_f[1], last_f[2], last_f[3] = f[0], f[1], f[2], f[3]
    _soe_push(H, fill, f, m, n0, K, L, eps_k, ET)
    fw = fill[0]
    s = _abm_start(H, m, alpha, a0_coef, a0_small, cp, cc)
    s = _abm_sums(H[0], W, fw, 1, base + fw, 0, s)
    return _abm_correct(x, x0, c, smooth, law, continuous, cc, s, bad)


@jitable
def _abm_step(x, x0, m, c, smooth, law, continuous, H, W, fill, eps_k, ET, a0_coef, a0_small,
              alpha, cp, cc, last_f, bad):
    """ABM step ``m`` of :func:`fom_soe_run` (:func:`_abm_step_from` at f of ``x``)."""
    f, _ = _abm_f(x, c, smooth, law, continuous)
    return _abm_step_from(f, x, x0, m, c, smooth, law, continuous, H, W, fill, eps_k, ET,
                         a0_coef, a0_small, alpha, cp, cc, last_f, bad)


@_njit
def fom_soe_run(x, x0, n, nsteps, cv, smooth, law, continuous, H, W, fill, eps_k, ET,
                a0_coef, a0_small, alpha, cp, cc, last_f, bad):
    """``nsteps`` ABM steps of eq. 26 from step ``n`` at ``x`` with the SOE history arrays of a
    one-group :class:`~fohssv_sim.fractional.soe.SOEHistory` (``H``, ``W``, ``fill``, ``eps_k``,
    ``ET``, ``a0_coef``, ``a0_small``), in place; ``last_f`` receives f_n of the last step.
    Returns the steps taken. Same arithmetic as ``SOEStepper.step`` (sums in another order)."""
    c = unpack_coefficients(cv)
    for i in range(nsteps):
        if not _abm_step(x, x0, n + i, c, smooth, law, continuous, H, W, fill, eps_k, ET,
                         a0_coef, a0_small, alpha, cp, cc, last_f, bad):
            return i
    return nsteps


@jitable
def _prepare_period(H, fill, m0, steps, W, eps_k, ET, a0_coef, a0_small, alpha, cp, cc, P, M):
    """Ahead of a held-input period of ``steps`` steps from step ``m0`` (> 0), what in its
    steps does not depend on the input: each step's sums over f_0, the L modes and the
    window's values from before the period into the rows of ``P`` (:func:`_abm_start`,
    then :func:`_abm_sums` over r = 1.. up to the period's own values, which are always the
    step's last rows: exactly as :func:`fom_soe_run` begins them), and, when the window
    fills during the period, the modes folded from its K oldest values into ``M``. False
    (nothing prepared) when the period has more steps than the n0 values a fold keeps in the
    window (a fold would then take values of the period itself) or ``P`` too few rows."""
    L, K, n0, base = _soe_shape(eps_k, ET, W)
    if m0 <= 0 or steps > n0 or steps > P.shape[0]:
        return False
    fw = fill[0]
    V = H[0]
    shift = 0              # where a row's value is now: K further on once the period folded
    for i in range(steps):
        if fw == n0 + K:
            _fold_into(H, K, L, eps_k, ET, M)
            fw = n0
            shift = K
        fw += 1
        old = base + fw - (i + 1)       # the rows before the period's i + 1 values
        s = _abm_start(H, m0 + i, alpha, a0_coef, a0_small, cp, cc)
        if shift:
            s = _abm_sums(M, W, fw, 1, base, 1, s)
            s = _abm_sums(V, W, fw, base, old, -shift, s)
        else:
            s = _abm_sums(V, W, fw, 1, old, 0, s)
        for j in range(8):
            P[i, j] = s[j]
    return True


@jitable
def fom_soe_prepared_run(x, x0, n, nsteps, cv, smooth, law, H, W, fill, eps_k, ET, cc,
                         last_f, bad, P, M):
    """:func:`fom_soe_run` with a held input over the period :func:`_prepare_period` prepared
    ``P`` and ``M`` for (from step ``n`` > 0, nothing changed since): each step's sums begin
    at its row of ``P`` and add the period's own values only (the step's last rows), a fold
    takes ``M``'s modes. The same arithmetic in the same order, bit for bit; only what
    depends on the input is left to compute."""
    c = unpack_coefficients(cv)
    L, K, n0, base = _soe_shape(eps_k, ET, W)
    V = H[0]
    for i in range(nsteps):
        f = _abm_rhs(x, c, smooth, law, False, last_f)
        if fill[0] == n0 + K:               # the fold prepared ahead
            for k in range(4):
                for j in range(L):
                    H[0, k, 1 + j] = M[k, j]
        _window_append(H, fill, f, n0, K, L)
        fw = fill[0]
        s = (P[i, 0], P[i, 1], P[i, 2], P[i, 3], P[i, 4], P[i, 5], P[i, 6], P[i, 7])
        s = _abm_sums(V, W, fw, base + fw - (i + 1), base + fw, 0, s)
        if not _abm_correct(x, x0, c, smooth, law, False, cc, s, bad):
            return i
    return nsteps

# -- held-input entry point: fom_soe_run through a C function, the arrays bound once -----------

#: The int64 table :class:`FomHeldCall` gives the C entry point: slots of the arrays' addresses
#: (x, x0, cv, law, H, W, fill, eps_k, ET, a0_coef, a0_small, last_f, bad), the flag
#: ``smooth``, then the arrays' shapes (cv, law, H, W, eps_k, ET, a0_coef, a0_small).
_T_X, _T_X0, _T_CV, _T_LAW, _T_H, _T_W, _T_FILL, _T_EPS, _T_ET, _T_A0C, _T_A0S = range(11)
_T_LAST_F, _T_BAD, _T_SMOOTH, _T_SHAPES = 11, 12, 13, 14
_TABLE = _T_SHAPES + 1 + 1 + 3 + 4 + 3 + 3 + 2 + 2
#: The array slots with their ndim and dtype, in the table's order (shapes follow for ndim
#: > 0 arrays whose size is not fixed: x, x0, last_f, bad are 4, fill is 1).
_T_ARRAYS = (('x', 1, np.float64), ('x0', 1, np.float64), ('cv', 1, np.float64),
             ('law', 1, np.float64), ('H', 3, np.float64), ('W', 4, np.float64),
             ('fill', 1, np.int64), ('eps_k', 3, np.float64), ('ET', 3, np.float64),
             ('a0_coef', 2, np.float64), ('a0_small', 2, np.float64),
             ('last_f', 1, np.float64), ('bad', 1, np.float64))
_T_SHAPED = ('cv', 'law', 'H', 'W', 'eps_k', 'ET', 'a0_coef', 'a0_small')


if numba is not None:
    from numba.core import cgutils
    from numba.extending import intrinsic

    @intrinsic
    def _as_pointer(typingctx, address):
        """An int64 address as a void pointer, for ``numba.carray`` (compiled code only)."""
        def codegen(context, builder, signature, args):
            return builder.inttoptr(args[0], cgutils.voidptr_t)
        return numba.types.voidptr(numba.types.int64), codegen


def _held_arrays(t):   # pragma: no cover - compiled into the entry points below
    """The arrays of the table ``t`` (:class:`FomHeldCall`), as :func:`fom_soe_run` takes them
    (but ``law``, which follows): x, x0, cv, H, W, fill, eps_k, ET, a0_coef, a0_small, last_f,
    bad, law."""
    s = _T_SHAPES
    x = numba.carray(_as_pointer(t[_T_X]), (4,), np.float64)
    x0 = numba.carray(_as_pointer(t[_T_X0]), (4,), np.float64)
    cv = numba.carray(_as_pointer(t[_T_CV]), (t[s],), np.float64)
    law = numba.carray(_as_pointer(t[_T_LAW]), (t[s + 1],), np.float64)
    H = numba.carray(_as_pointer(t[_T_H]), (t[s + 2], t[s + 3], t[s + 4]), np.float64)
    W = numba.carray(_as_pointer(t[_T_W]), (t[s + 5], t[s + 6], t[s + 7], t[s + 8]),
                     np.float64)
    fill = numba.carray(_as_pointer(t[_T_FILL]), (1,), np.int64)
    eps_k = numba.carray(_as_pointer(t[_T_EPS]), (t[s + 9], t[s + 10], t[s + 11]), np.float64)
    ET = numba.carray(_as_pointer(t[_T_ET]), (t[s + 12], t[s + 13], t[s + 14]), np.float64)
    a0_coef = numba.carray(_as_pointer(t[_T_A0C]), (t[s + 15], t[s + 16]), np.float64)
    a0_small = numba.carray(_as_pointer(t[_T_A0S]), (t[s + 17], t[s + 18]), np.float64)
    last_f = numba.carray(_as_pointer(t[_T_LAST_F]), (4,), np.float64)
    bad = numba.carray(_as_pointer(t[_T_BAD]), (4,), np.float64)
    return x, x0, cv, H, W, fill, eps_k, ET, a0_coef, a0_small, last_f, bad, law


def _fom_held_entry(t, f, n, nsteps):   # pragma: no cover - compiled by _fom_held_c
    """The C entry point's body: :func:`fom_soe_run` with a held input on the arrays whose
    addresses and shapes the table ``t`` holds, ``f`` = [alpha, cp, cc, Fp]; Fp receives the
    planing force at the state the steps leave (the last finite one if a step failed)."""
    x, x0, cv, H, W, fill, eps_k, ET, a0_coef, a0_small, last_f, bad, law = _held_arrays(t)
    smooth = t[_T_SMOOTH] != 0
    taken = fom_soe_run(x, x0, n, nsteps, cv, smooth, law, False, H, W, fill, eps_k, ET,
                        a0_coef, a0_small, f[0], f[1], f[2], last_f, bad)
    c = unpack_coefficients(cv)
    f[3] = _planing(c, smooth, x[1])
    return taken


def _fom_prepared_entry(t, f, n, nsteps, P, M):   # pragma: no cover - compiled by its user
    """:func:`_fom_held_entry` over a period :func:`_fom_prepare_entry` prepared ``P`` and
    ``M`` for (:func:`fom_soe_prepared_run`: the same results, bit for bit)."""
    x, x0, cv, H, W, fill, eps_k, ET, a0_coef, a0_small, last_f, bad, law = _held_arrays(t)
    smooth = t[_T_SMOOTH] != 0
    taken = fom_soe_prepared_run(x, x0, n, nsteps, cv, smooth, law, H, W, fill, eps_k, ET,
                                 f[2], last_f, bad, P, M)
    c = unpack_coefficients(cv)
    f[3] = _planing(c, smooth, x[1])
    return taken


def _fom_prepare_entry(t, f, m0, steps, P, M):   # pragma: no cover - compiled by its user
    """:func:`_prepare_period` on the table's arrays for the held-input period of ``steps``
    steps from step ``m0``; False when it cannot be prepared."""
    x, x0, cv, H, W, fill, eps_k, ET, a0_coef, a0_small, last_f, bad, law = _held_arrays(t)
    return _prepare_period(H, fill, m0, steps, W, eps_k, ET, a0_coef, a0_small, f[0], f[1],
                          f[2], P, M)


if numba is not None:
    _held_arrays = numba.njit(error_model='numpy', cache=True)(_held_arrays)
    _fom_held_jit = numba.njit(error_model='numpy', cache=True)(_fom_held_entry)
    _fom_prepared_jit = numba.njit(error_model='numpy', cache=True)(_fom_prepared_entry)
    _fom_prepare_jit = numba.njit(error_model='numpy', cache=True)(_fom_prepare_entry)


@functools.cache
def _fom_held_c() -> Any:
    """The C entry point of :func:`_fom_held_entry` as a ctypes function, compiled on first use
    (cached on disk); None without numba or where it cannot be built (a warning says why;
    :class:`FomHeldCall` users then call the dispatcher)."""
    if numba is None:  # pragma: no cover
        return None
    try:
        from numba import types

        sig = types.int64(types.CPointer(types.int64), types.CPointer(types.float64),
                          types.int64, types.int64)
        entry = numba.cfunc(sig, nopython=True, error_model='numpy', cache=True)(
            _fom_held_entry)
        proto = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p,
                                 ctypes.c_int64, ctypes.c_int64)
        return proto(entry.address), entry
    except Exception as exc:  # noqa: BLE001 - a slower call, not a failure
        warnings.warn(f'fohssv_sim.kernels: the FOM kernel\'s C entry point could not be '
                      f'built ({type(exc).__name__}: {exc}); calling it through numba\'s '
                      'dispatcher', RuntimeWarning, stacklevel=2)
        return None


class FomHeldCall:
    """:func:`fom_soe_run` with a held input (``continuous`` False) on fixed arrays, called
    through a C entry point with only the step index and the step count: ``.call(n,
    nsteps)`` (a ctypes call with the table bound, no Python frame in between) returns the
    steps taken, exactly as ``fom_soe_run(x, x0, n, nsteps, cv, smooth, law, False, H, W,
    ...)`` on the same arrays would (the same compiled code, bit for bit), and leaves the
    planing force at the state it reached in ``.values[FomHeldCall.FP]`` (as the sampled
    drivers compute it: what the plant publishes next, without an interpreted evaluation).

    The arrays' addresses are bound at construction; the instance keeps the arrays alive, and
    its owner builds a new one whenever it replaces any of them (the two its callers pass per
    call are kept as :attr:`x` and :attr:`law` for the caller to compare). :meth:`build`
    returns None without the C entry point.
    """

    #: The slot of :attr:`values` the planing force is left in.
    FP = 3

    def __init__(self, entry: Any, arrays: dict[str, np.ndarray], smooth: bool,
                 alpha: float, cp: float, cc: float) -> None:
        table = np.zeros(_TABLE, dtype=np.int64)
        shapes: list[int] = []
        for slot, (name, ndim, dtype) in enumerate(_T_ARRAYS):
            a = arrays[name]
            if (not isinstance(a, np.ndarray) or a.ndim != ndim or a.dtype != dtype
                    or not a.flags.c_contiguous or not a.flags.writeable):
                raise ValueError(f'{name}: a writeable C-contiguous {np.dtype(dtype).name} '
                                 f'array of {ndim} dimension(s) is needed, got '
                                 f'{getattr(a, "dtype", type(a))!s} {getattr(a, "shape", "")}')
            if name in ('x', 'x0', 'last_f', 'bad') and a.shape != (4,) or (
                    name == 'fill' and a.shape != (1,)):
                raise ValueError(f'{name}: shape {a.shape}, not {(1,) if name == "fill" else (4,)}')
            table[slot] = a.ctypes.data
            if name in _T_SHAPED:
                shapes += a.shape
        table[_T_SMOOTH] = 1 if smooth else 0
        table[_T_SHAPES:] = shapes
        self._arrays = arrays                # alive as long as the table points at them
        self._table = table
        self._floats = np.array([alpha, cp, cc, math.nan], dtype=np.float64)
        self.values = memoryview(self._floats)      # [alpha, cp, cc, Fp] as Python floats
        self.x, self.law = arrays['x'], arrays['law']
        self.call = functools.partial(entry, ctypes.c_void_p(table.ctypes.data),
                                      ctypes.c_void_p(self._floats.ctypes.data))

    @classmethod
    def build(cls, x: np.ndarray, x0: np.ndarray, cv: np.ndarray, smooth: bool,
              law: np.ndarray, H: np.ndarray, W: np.ndarray, fill: np.ndarray,
              eps_k: np.ndarray, ET: np.ndarray, a0_coef: np.ndarray, a0_small: np.ndarray,
              alpha: float, cp: float, cc: float, last_f: np.ndarray,
              bad: np.ndarray) -> FomHeldCall | None:
        """Bound to :func:`fom_soe_run`'s arguments (but ``n``, ``nsteps`` and
        ``continuous``), or None without the C entry point."""
        built = _fom_held_c()
        if built is None:
            return None
        arrays = {'x': x, 'x0': x0, 'cv': cv, 'law': law, 'H': H, 'W': W, 'fill': fill,
                  'eps_k': eps_k, 'ET': ET, 'a0_coef': a0_coef, 'a0_small': a0_small,
                  'last_f': last_f, 'bad': bad}
        return cls(built[0], arrays, smooth, alpha, cp, cc)
