"""The sum-of-exponentials (SOE) approximation of the ABM tail weights: modes, quadrature, error.

The ABM weights of docs/model.md §5.4 are integrals of the Caputo kernel tau^(a-1) (tau = lag in
steps) against piecewise-constant and piecewise-linear hats:

    b(k) = a      * int_k^{k+1}  tau^(a-1) dtau                        (predictor)
    c(k) = a(a+1) * int_k^{k+2}  tau^(a-1) (1 - |tau - k - 1|) dtau    (corrector, j >= 1)

If tau^(a-1) ~= sum_l W_l exp(-s_l tau) with relative error eps on [n0, horizon + 2], both
integrals can be done exactly per mode,

    b(k) ~= sum_l [a W_l (1 - e^{-s_l})/s_l] z_l^k,
    c(k) ~= sum_l [a(a+1) W_l ((1 - e^{-s_l})/s_l)^2] z_l^k,

z_l = e^{-s_l}, with relative error <= eps for every k >= n0 (positive weights, positive hats).
Both sequences share the modes z_l, so the tail of the history is carried by one (L, d) array
of mode sums M_l = sum_j z_l^(j_lo-1-j) f_j over the values already folded in (j < j_lo),
updated recursively M <- z^K M + sum_i z^(K-1-i) f_(j_lo+i) when K = 32 more values are folded
in at once; the n0 to n0+K most recent lags are summed exactly with the ABM weights, and the
f_0 terms b(n) f_0, a_{0,n+1} f_0 are added exactly. This is the kernel
compression of Jiang, Zhang, Zhang & Zhang (2017, Commun. Comput. Phys. 21:650-678) and Baffet
& Hesthaven (2017, SIAM J. Numer. Anal. 55:496-520), applied to the ABM weights.

The SOE comes from the Laplace representation

    Gamma(1-a) tau^(a-1) = int_0^inf s^(-a) e^{-s tau} ds,

discretised (in the scaled variable t = tau/n0 in [1, R]) by Gauss-Jacobi quadrature with weight
s^(-a) on [0, s_a] (s_a = c/R) and composite Gauss-Legendre quadrature in log s on [s_a, s_b],
s_b from the incomplete-gamma tail; panel sizes are chosen (cheapest first) until the relative
kernel error on a dense log grid is below tolerance/4. The decay is applied as M - (1 - z) M
with 1 - z = -expm1(-s) stored, so z^k is not spoiled by the rounding of z near 1 (which
would cost ~1e-8 relative at k = 1e8 for the slowest modes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numpy.polynomial.legendre import leggauss

from ._stored import stored
from ._validate import check_positive_int, check_tolerance
from .weights import corrector_weights, predictor_weights

__all__ = ['SOEModes', 'soe_modes', 'soe_kernel_error', 'SOEErrorReport']


@dataclass(frozen=True)
class SOEModes:
    """Sum-of-exponentials representation of the ABM tail weights (lag units, step-free).

    For lags k >= n_exact:  b(k) ~= sum_l pred[l] z_l^(k - n_exact),
    c(k) ~= sum_l corr[l] z_l^(k - n_exact), with z_l = 1 - decay[l] = exp(-s[l]), and the
    kernel tau^(a-1) ~= sum_l weight[l] exp(-s[l] tau). Arrays are read-only, sorted by s.
    Built by :func:`soe_modes`; accuracy: see :func:`soe_kernel_error`.

    Raises:
        nothing (plain data); :meth:`tail_weights` raises ValueError for non-numeric lags.
    """

    alpha: float
    n_exact: int
    tolerance: float
    horizon_steps: int
    s: np.ndarray
    decay: np.ndarray
    weight: np.ndarray
    pred: np.ndarray
    corr: np.ndarray

    @property
    def n_modes(self) -> int:
        return int(self.s.size)

    def tail_weights(self, k) -> tuple[np.ndarray, np.ndarray]:
        """SOE values of (b(k), c(k)) for lags k >= n_exact, evaluated exactly as the stepper
        applies them (z^m = exp(m log1p(-decay)))."""
        k = np.asarray(k, dtype=float)
        logz = np.log1p(-self.decay)
        powers = np.exp(np.multiply.outer(k - self.n_exact, logz))
        return powers @ self.pred, powers @ self.corr


@lru_cache(maxsize=256)
def _roots_jacobi(nj: int, beta: float) -> tuple[np.ndarray, np.ndarray]:
    from scipy.special import roots_jacobi

    return roots_jacobi(nj, 0.0, beta - 1.0)


def _gauss_jacobi_lower(beta: float, sa: float, nj: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes/weights for int_0^sa s^(beta-1) g(s) ds."""
    y, w = _roots_jacobi(nj, beta)
    return sa * (1.0 + y) / 2.0, (sa / 2.0) ** beta * w


@lru_cache(maxsize=64)
def _leggauss(npan: int) -> tuple[np.ndarray, np.ndarray]:
    return leggauss(npan)


def _log_panels(beta: float, sa: float, sb: float, width: float, npan: int):
    xa, xb = math.log(sa), math.log(sb)
    count = max(1, math.ceil((xb - xa) / width))
    edges = np.linspace(xa, xb, count + 1)
    gx, gw = _leggauss(npan)
    mid = (edges[:-1] + edges[1:]) / 2.0
    half = (edges[1:] - edges[:-1]) / 2.0
    x = (mid[:, None] + half[:, None] * gx[None, :]).ravel()
    w = (half[:, None] * gw[None, :]).ravel() * np.exp(beta * x)
    return np.exp(x), w


def _kernel_rel_error(beta: float, s: np.ndarray, W: np.ndarray, t: np.ndarray) -> float:
    approx = np.exp(-np.multiply.outer(t, s)) @ W
    return float(np.max(np.abs(approx * t ** beta - 1.0)))


_JACOBI = ((1.0, 6), (2.0, 8), (4.0, 10), (8.0, 12), (8.0, 16), (16.0, 20))
_PANEL_WIDTH = 4.0


@lru_cache(maxsize=64)
def _scaled_soe(beta: float, R: float, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """SOE of t^-beta on [1, R] with relative error < eps (cheapest of a candidate family)."""
    from scipy.special import gamma, gammainccinv

    sb = float(gammainccinv(beta, eps / 20.0))
    sb = max(sb, 1.0)
    t_grid = np.geomspace(1.0, R, 1500)
    cands = []
    for npan in range(4, 40):
        for ca, nj in _JACOBI:
            sa = ca / R
            if sa >= sb:
                continue
            count = max(1, math.ceil((math.log(sb) - math.log(sa)) / _PANEL_WIDTH))
            cands.append((count * npan + nj, npan, ca, nj))
    cands.sort()
    gb = gamma(beta)
    t_coarse = t_grid[::10]       # a subset: its error never exceeds the full grid's
    for _, npan, ca, nj in cands:
        sa = ca / R
        s1, w1 = _gauss_jacobi_lower(beta, sa, nj)
        s2, w2 = _log_panels(beta, sa, sb, _PANEL_WIDTH, npan)
        s = np.concatenate([s1, s2])
        W = np.concatenate([w1, w2]) / gb
        if _kernel_rel_error(beta, s, W, t_coarse) >= eps:
            continue              # rejected cheaply; the choice is that of the full check
        if _kernel_rel_error(beta, s, W, t_grid) < eps:
            order = np.argsort(s)
            return s[order], W[order]
    raise RuntimeError(f"no SOE found for beta={beta}, R={R}, eps={eps}")  # pragma: no cover


@lru_cache(maxsize=128)
def _soe_modes_cached(alpha: float, n_exact: int, tolerance: float,
                      horizon_steps: int) -> SOEModes:
    rows = stored('soe', (alpha, n_exact, tolerance, horizon_steps),
                  lambda: np.stack(_mode_arrays(alpha, n_exact, tolerance, horizon_steps)))
    s, W, decay, pred, corr = (row.copy() for row in rows)
    for arr in (s, W, decay, pred, corr):
        arr.flags.writeable = False
    return SOEModes(alpha, n_exact, tolerance, horizon_steps, s, decay, W, pred, corr)


def _mode_arrays(alpha: float, n_exact: int, tolerance: float,
                 horizon_steps: int) -> tuple[np.ndarray, ...]:
    """The arrays of :class:`SOEModes`: s, weight, decay, pred, corr (computed)."""
    if alpha == 1.0:
        s = np.zeros(1)
        W = np.ones(1)
        decay = np.zeros(1)
        pred = np.ones(1)
        corr = np.full(1, 2.0)
    else:
        beta = 1.0 - alpha
        R = (horizon_steps + 2.0) / n_exact
        ss, Ws = _scaled_soe(beta, max(R, 2.0), tolerance / 4.0)
        # back to lag units tau = n_exact * t
        s0 = ss / n_exact
        decay = -np.expm1(-s0)
        s = -np.log1p(-decay)             # the decay rates actually applied
        W = Ws * n_exact ** (-beta)
        ratio = decay / s                 # (1 - e^{-s}) / s
        zeta = np.exp(-s * n_exact)       # z^n_exact
        pred = alpha * W * ratio * zeta
        corr = alpha * (alpha + 1.0) * W * ratio * ratio * zeta
    return s, W, decay, pred, corr


def soe_modes(alpha: float, tolerance: float = 1e-10, horizon_steps: int = 10**8,
              n_exact: int = 16) -> SOEModes:
    """The SOE modes of the ABM tail weights for (alpha, tolerance, horizon, n_exact), cached.

    Construction: see the module docstring (Gauss-Jacobi + log-Gauss-Legendre discretisation of
    the Laplace representation of tau^(a-1); Jiang et al. 2017, Baffet & Hesthaven 2017). The
    weights are in lag units, so the step h does not enter and one set serves every h.
    Accuracy: relative error of the tail weights b(k), c(k) below ``tolerance`` for
    n_exact <= k <= horizon_steps (see :func:`soe_kernel_error`). Cost: ~5-20 ms once per
    key; about 60-90 modes for tolerance 1e-10 and horizon 1e8.

    ``alpha`` is trusted (a float in (0, 1], checked where it entered: the steppers'
    constructors or :class:`~fohssv_sim.params.ModelParameters`).

    Raises:
        ValueError: tolerance outside [1e-13, 1e-2], horizon_steps or n_exact not integers
            >= 1 (n_exact >= 2).
    """
    a = float(alpha)        # trusted: checked where it entered (steppers, ModelParameters)
    tol = check_tolerance(tolerance)
    hor = check_positive_int(horizon_steps, 'horizon_steps', low=1)
    n0 = check_positive_int(n_exact, 'n_exact', low=2)
    return _soe_modes_cached(a, n0, tol, hor)


class SOEErrorReport(NamedTuple):
    """Max relative errors of the SOE over lags [n_exact, horizon_steps]: of the kernel
    tau^(a-1) itself, of the predictor weights b(k) and of the corrector weights c(k);
    ``max`` is the largest of the latter two (the numbers the stepper uses).

    Raises:
        nothing (plain data).
    """

    kernel: float
    predictor: float
    corrector: float
    max: float
    n_modes: int
    n_lags_checked: int


def soe_kernel_error(alpha: float, tolerance: float = 1e-10, horizon_steps: int = 10**8,
                     n_exact: int = 16, samples_per_decade: int = 1000) -> SOEErrorReport:
    """Report the SOE approximation's max relative error over the whole horizon.

    Checks every lag in [n_exact, n_exact + 2000] and ``samples_per_decade`` log-spaced lags
    per decade up to horizon_steps, comparing the SOE tail weights (as applied by the stepper)
    with the exact cancellation-free weights of :mod:`.weights`, and the SOE kernel with
    tau^(a-1). Accuracy target: ``max <= tolerance``. Cost: O(samples x modes).

    Raises:
        ValueError: as :func:`soe_modes`.
    """
    modes = soe_modes(alpha, tolerance, horizon_steps, n_exact)
    n0, hor = modes.n_exact, modes.horizon_steps
    dense = np.arange(n0, min(hor, n0 + 2000) + 1, dtype=float)
    decades = max(math.log10(max(hor, n0 + 1) / n0), 1e-3)
    logk = np.geomspace(n0, hor, max(int(samples_per_decade * decades), 2))
    k = np.unique(np.concatenate([dense, np.floor(logk), [float(hor)]]))
    k = k[(k >= n0) & (k <= hor)]
    if k.size == 0:                     # horizon shorter than the exact window: no tail used
        return SOEErrorReport(0.0, 0.0, 0.0, 0.0, modes.n_modes, 0)
    b_soe, c_soe = modes.tail_weights(k)
    b_ex = predictor_weights(modes.alpha, k.astype(np.int64))
    c_ex = corrector_weights(modes.alpha, k.astype(np.int64))
    e_b = float(np.max(np.abs(b_soe / b_ex - 1.0)))
    e_c = float(np.max(np.abs(c_soe / c_ex - 1.0)))
    tau = np.concatenate([k, k + 0.5, k + 1.0])
    ker = np.exp(-np.multiply.outer(tau, modes.s)) @ modes.weight
    e_k = float(np.max(np.abs(ker * tau ** (1.0 - modes.alpha) - 1.0)))
    return SOEErrorReport(e_k, e_b, e_c, max(e_b, e_c), modes.n_modes, int(k.size))
