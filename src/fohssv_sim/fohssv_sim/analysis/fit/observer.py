"""An open-loop replay fitted through an extended Kalman filter of the FOM, one control period
at a time (the prediction-error method).

The vehicle is open-loop unstable, so a replay of the recorded commands leaves the data
within tens of milliseconds of any error. Instead the model runs over the whole record
corrected at every control instant towards the sample by this filter, and the fit's residual
is its *prediction errors*: each sample against the model's one-period prediction, over the
standard deviation the filter predicts for it (:func:`run_filter`): white noise of unit
variance when the model is right, so the test of "reproduces" (:mod:`.noise`) applies as to
any residual. Taking each sample whole instead (the model restarted from it) puts the
measurement noise into the fractional memory, where f, nonlinear through the planing force,
turns it into a bias of alpha growing as the noise squared; and an unmeasured state (w and q
of a vehicle that measures depth and pitch) cannot be taken from a sample at all. The filter
answers both: it weighs each sample against the prediction and corrects all four states from
the measured ones.

**The filter.** Over one period the FOM moves a correction d of its state by about
(I + c J) d, J the Jacobian of f (eq. 17's A, with the planing force's slope dFp/dw at the
model's w in the w column) and c = h^alpha / Gamma(alpha + 1) (the weight of the last period
in the Caputo integral, h the control period): the one-period map the covariance P is
propagated through, P <- F P F^T + Q. The measured states (rows H) of noise R = sigma^2
(:mod:`.noise`, the estimate the test of "reproduces" uses) give S = H P H^T + R, the gain
K = P H^T S^-1, the correction K e of the innovation e = sample - prediction, and
P <- (I - K H) P. The correction shifts the state and its Volterra constant x0 (x = x0 +
I^alpha f), so it stays outside the fractional dynamics, and the history of f is kept: the
memory is that of the filtered trajectory from t = 0. The initial state is known (P starts
at Q). Each innovation is whitened by its own sqrt(S_ii) (S is diagonal to within P's small
share).

**Q**, the model's error per period the filter allows: :data:`PROCESS_NOISE` of each state's
standard deviation over the window (1 in the state's unit for a state not measured, whose
samples the fit never reads). Small against the noise of a measured run, so the filter follows
the model between samples and averages the noise over many of them; with noise-free data
(the noise at its floor, 1e-3 of the spread) it takes most of each sample. At the truth the
prediction errors are the noise; at a wrong alpha the prediction errs by more.

Pure: numpy, numba.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ... import kernels
from ...coefficients import coefficients
from ...params import ModelParameters
from ...physics import jitable, planing_exact, planing_smooth

if kernels.numba is not None:
    _njit = kernels.numba.njit(cache=True, nogil=True, error_model='numpy')
else:  # pragma: no cover - numba is pinned
    def _njit(fn):
        return fn

#: The model's error per control period the filter allows, as a fraction of each measured
#: state's standard deviation over the window.
PROCESS_NOISE = 1e-3


def settings(params: Sequence[ModelParameters], period: float, scale: np.ndarray,
             sigma: np.ndarray, measured: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(c per point, Q (4,), R (4,), measured (4,)) of the filter (module docstring) for the
    points ``params``, the control ``period`` (s), the states' ``scale`` (their standard
    deviations) and noise ``sigma`` (:class:`.noise.Noise`)."""
    c = np.array([period ** p.fractional_order / math.gamma(p.fractional_order + 1.0)
                  for p in params])
    m = np.asarray(measured, dtype=np.bool_)
    Q = (PROCESS_NOISE * np.where(m, np.asarray(scale, dtype=float), 1.0)) ** 2
    R = np.where(m, np.asarray(sigma, dtype=float) ** 2, 1.0)
    return c, Q, R, m


@jitable
def update(P, y, y0, e, c, co, smooth, Q, R, m, white):
    """One period of the filter, in place: P (4, 4) propagated through I + c J(y) (``co``
    the model's coefficients, ``smooth`` its planing form) and corrected by the innovations
    ``e`` of the states ``m`` (this sample's measured ones); the state ``y`` and its Volterra
    constant ``y0`` moved by K e; ``white``: each innovation over its predicted standard
    deviation sqrt(S_ii) (0 where not measured)."""
    w = y[1]
    dw = 1e-7 * max(abs(w), 1.0)
    if smooth:
        dfp = (planing_smooth(w + dw, co) - planing_smooth(w - dw, co)) / (2.0 * dw)
    else:
        dfp = (planing_exact(w + dw, co) - planing_exact(w - dw, co)) / (2.0 * dw)
    F = np.eye(4)
    F[0, 1] += c
    F[0, 2] -= c * co.V
    F[1, 1] += c * (co.a22 + co.d2 * dfp)
    F[1, 3] += c * co.a24
    F[2, 3] += c
    F[3, 1] += c * (co.a42 + co.d4 * dfp)
    F[3, 3] += c * co.a44
    P[:, :] = F @ P @ F.T
    S = np.eye(4)                       # H P H^T + R, the unmeasured rows as the identity
    PH = np.zeros((4, 4))               # P H^T, the unmeasured columns 0
    for i in range(4):
        P[i, i] += Q[i]
    for i in range(4):
        for j in range(4):
            if m[j]:
                PH[i, j] = P[i, j]
                if m[i]:
                    S[i, j] = P[i, j] + (R[i] if i == j else 0.0)
    for i in range(4):
        white[i] = e[i] / math.sqrt(S[i, i]) if m[i] else 0.0
    K = PH @ np.linalg.inv(S)
    d = K @ e
    for i in range(4):
        y[i] += d[i]
        y0[i] += d[i]
    P[:, :] = P - K @ P


@_njit
def _filter_kernel(X0, CV, smooth, inputs, hold, n_periods, data, kf, H, W, fill, eps_k, ET,
                   a0_coef, a0_small, alphas, cp, cc, speeds, out, white, failed):
    """The filtered run of every point p over ``n_periods`` periods on the held ``inputs``:
    its prediction of each sample (``out[p, k]``, before the correction) and the whitened
    innovation (``white[p, k]``); a point whose prediction leaves the domain stops
    (``failed[p]``, NaN from there on)."""
    y = np.empty(4)
    y0 = np.empty(4)
    e = np.empty(4)
    m = np.empty(4, dtype=np.bool_)
    Pk = np.empty((4, 4))
    last_f = np.empty(4)
    bad = np.empty(4)
    held = np.zeros(12)
    held[10] = math.inf
    held[11] = math.inf
    kf_c, Q, R, measured = kf
    for p in range(X0.shape[0]):
        co = kernels.unpack_coefficients(CV[p])
        for i in range(4):
            y[i] = X0[p, i]
            y0[i] = X0[p, i]
            out[p, 0, i] = X0[p, i]
            white[p, 0, i] = 0.0
        Pk[:, :] = np.diag(Q)
        n = 0
        v = speeds[p]
        for k in range(n_periods):
            held[8] = inputs[k, 0]
            held[9] = inputs[k, 1]
            taken = kernels.fom_soe_run(
                y, y0, n, hold, CV[p], smooth, held, False, H[p:p + 1], W[:, p:p + 1],
                fill[p:p + 1], eps_k[p:p + 1], ET[p:p + 1], a0_coef[p:p + 1],
                a0_small[p:p + 1], alphas[p], cp[p], cc[p], last_f, bad)
            if taken < hold or not (-v <= y[1] <= v and -1.5707963267948966 <= y[2]
                                    <= 1.5707963267948966):
                failed[p] = True
                out[p, k + 1:] = np.nan
                white[p, k + 1:] = np.nan
                break
            n += hold
            for i in range(4):
                out[p, k + 1, i] = y[i]
                m[i] = measured[i] and math.isfinite(data[k + 1, i])
                e[i] = data[k + 1, i] - y[i] if m[i] else 0.0
            update(Pk, y, y0, e, kf_c[p], co, smooth, Q, R, m, white[p, k + 1])


@dataclass
class Filtered:
    """The filtered runs of some points: ``states`` (P, n + 1, 4) their predictions of the
    samples, ``white`` their whitened innovations (same shape), ``failed`` (P,)."""

    states: np.ndarray
    white: np.ndarray
    failed: np.ndarray


def run_filter(params: Sequence[ModelParameters], n_periods: int, hold: int,
               inputs: np.ndarray, data: np.ndarray, kf: tuple, *,
               initial_state: Sequence[float], duration: float | None, threads: int = 1
               ) -> Filtered:
    """The filtered runs (:class:`Filtered`) of the points ``params`` on ``inputs``,
    filtering ``data`` (NaN: not measured) with ``kf`` (:func:`settings`); ``threads`` > 1
    splits the points over threads."""
    from ..population import _soe_arrays, check_population, over_threads

    params = list(params)
    if threads > 1 and len(params) > 1:
        parts = over_threads(lambda a, b: run_filter(
            params[a:b], n_periods, hold, inputs, data, (kf[0][a:b], *kf[1:]),
            initial_state=initial_state, duration=duration), len(params), threads)
        return Filtered(*(np.concatenate([getattr(q, f) for q in parts])
                          for f in ('states', 'white', 'failed')))
    check_population(params)
    P = len(params)
    hist, alphas, cp, cc = _soe_arrays(params, duration)
    out = np.empty((P, n_periods + 1, 4))
    white = np.empty((P, n_periods + 1, 4))
    failed = np.zeros(P, dtype=np.bool_)
    _filter_kernel(np.tile(np.asarray(initial_state, dtype=float), (P, 1)),
                   np.array([coefficients(p).kernel for p in params], dtype=float),
                   params[0].planing_form == 'smooth',
                   np.ascontiguousarray(inputs[:n_periods], dtype=float), int(hold),
                   int(n_periods), np.ascontiguousarray(data[:n_periods + 1], dtype=float),
                   tuple(np.ascontiguousarray(a, dtype=t)
                         for a, t in zip(kf, (float, float, float, np.bool_))),
                   np.zeros_like(hist.H), hist.W, np.zeros(P, dtype=np.int64), hist.eps_k,
                   hist.ET, hist.a0_coef, hist.a0_small, alphas, cp, cc,
                   np.array([p.speed for p in params], dtype=float), out, white, failed)
    return Filtered(out, white, failed)


def warm_up() -> None:
    """Compile (or load from numba's cache) :func:`_filter_kernel` with the argument types a
    fit passes (``make test`` calls it once, before the test workers start)."""
    n, hold = 4, 5
    run_filter([ModelParameters(model='fractional')], n, hold, np.zeros((n, 2)),
               np.zeros((n + 1, 4)), (np.ones(1), np.ones(4), np.ones(4), np.ones(4, dtype=bool)),
               initial_state=(0.0, 0.0, 0.0, 0.0), duration=None)
