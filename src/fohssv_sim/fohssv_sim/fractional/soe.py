"""Bounded-cost ABM stepping: the history convolution with a sum-of-exponentials tail.

The SOE approximation of the ABM tail weights (modes, quadrature, error report) is in
:mod:`.soe_kernel`; this module keeps the history and the steppers. The last ``n_exact`` to
``n_exact + K`` lags are summed exactly with the ABM weights; older values live in the mode
sums M_l = sum_j z_l^(j_lo-1-j) f_j, which are folded forward K = 32 values at a time,
M <- z^K M + sum_i z^(K-1-i) f_(j_lo+i); the f_0 terms b(n) f_0, a_{0,n+1} f_0 are added
exactly. (Jiang, Zhang, Zhang & Zhang 2017, Commun. Comput. Phys. 21:650-678; Baffet &
Hesthaven 2017, SIAM J. Numer. Anal. 55:496-520.)
"""

from __future__ import annotations

import warnings

import numpy as np

from ._validate import check_alpha
from .abm import BatchMixin, PECEStepperBase, RhsFn
from .soe_kernel import SOEModes, soe_modes
from .weights import _a0 as _a0_lag
from .weights import _b_lag, _c_lag, _start_coeffs

__all__ = ['SOEHistory', 'SOEStepper', 'BatchSOE']


class SOEHistory:
    """ABM history sums with an SOE tail for G groups of d columns, each group with its own
    order alpha_g (one order for every column is the one-group case, G = 1).

    H (G, d, R) holds for group g, along its last axis: f_0, the L mode sums M_l and a
    time-ordered buffer of the w most recent values f_{j_lo..n} (n_exact < w <= n_exact + K once
    n is large). Those w lags are summed exactly with the ABM weights; older values live in the
    modes, whose contribution at lag offset w is sum_l pred_l z_l^(w - n_exact) M_l (corrector
    alike). Every group's mode set is padded to the largest count L with zero-weight modes
    (decay that of its fastest mode, so their sums stay bounded), which puts all groups on one
    row layout; the weights (G, R, 2) of each buffer fill w are precomputed (zero beyond the
    filled rows), so ``sums(n)`` is one stacked product (G, d, R) @ (G, R, 2), and the fold
    (when the buffer is full, its K oldest values go into the modes) one stacked
    (G, d, K) @ (G, K, L). The f_0 weights b_g(n), a0_g(n) are computed for blocks of 4096
    steps at once, vectorised over the groups.

    ``push(n, f)`` stores f_n (length G d); ``sums(n)`` returns the (2, G, d) scaled predictor
    and corrector sums of step n -> n+1. Padded modes and unfilled rows add exact zeros, so
    every group equals its own one-group history up to rounding. Accuracy: tail weights to the
    SOE tolerance (relative). Cost per step: O((L + n_exact + K) G d), independent of n;
    memory O((n_exact + K) (L + n_exact + K) G) for the weight table plus 2 x 4096 G for the
    f_0 weights. The arrays are the state the compiled FOM kernel
    (:func:`fohssv_sim.kernels.fom_soe_run`) advances in place.

    Raises:
        RuntimeWarning (a warning, once): the step count passed horizon_steps.
    """

    K = 32        # values folded into the modes at once
    _BLOCK = 4096

    def __init__(self, alphas: np.ndarray, modes: list[SOEModes], d: int,
                 cp: np.ndarray, cc: np.ndarray) -> None:
        G = alphas.size
        n0 = modes[0].n_exact
        K = self.K
        L = max(md.n_modes for md in modes)
        wmax = n0 + K
        R = 1 + L + wmax
        self.alphas = alphas
        self.G, self.d, self.n0, self.L, self.R = G, d, n0, L, R
        self.cp, self.cc = cp, cc
        self.horizon = modes[0].horizon_steps
        lags = np.arange(wmax - 1, -1, -1, dtype=float)      # buffer rows: lags wmax-1..0
        W = np.zeros((wmax + 1, G, R, 2))
        logz = np.empty((G, L))
        for g, (a, md) in enumerate(zip(alphas.tolist(), modes)):
            lz = np.log1p(-np.array(md.decay))
            logz[g, :md.n_modes] = lz
            logz[g, md.n_modes:] = lz[-1]                   # padding: fastest mode, weight 0
            b_rev, c_rev = _b_lag(a, lags), _c_lag(a, lags)
            for w in range(wmax + 1):
                zw = np.exp((w - n0) * lz)                   # z^(w - n0): M anchored at lag w
                W[w, g, 1:1 + md.n_modes, 0] = cp[g] * md.pred * zw
                W[w, g, 1:1 + md.n_modes, 1] = cc[g] * md.corr * zw
                if w:
                    W[w, g, 1 + L:1 + L + w, 0] = cp[g] * b_rev[wmax - w:]
                    W[w, g, 1 + L:1 + L + w, 1] = cc[g] * c_rev[wmax - w:]
        self.W = W
        # fold: z^K via 1 - z^K (exact for z near 1); E^T (G, K, L), E_{l,i} = z_l^(K-1-i)
        self.eps_k = (-np.expm1(K * logz))[:, None, :]                  # (G, 1, L)
        self.ET = np.exp(np.arange(K - 1, -1, -1, dtype=float)[None, :, None]
                         * logz[:, None, :])
        self.H = np.zeros((G, d, R))
        self._M = self.H[:, :, 1:1 + L]
        self._buf = self.H[:, :, 1 + L:]
        self._tmp = np.zeros((G, d, L))
        self._out = np.zeros((G, d, 2))
        # f_0 weights: the series coefficients of a0 (n >= 64), exact a0 below 64, per group
        self.a0_coef = np.array([_start_coeffs(a, 12) for a in alphas.tolist()])
        self.a0_small = np.array([_a0_lag(a, np.arange(64, dtype=float))
                                  for a in alphas.tolist()])
        self._f0w = np.zeros((0, G, 2))         # f_0 weights of steps base..base+BLOCK-1
        self._f0_base = 0
        self.fill = np.zeros(1, dtype=np.int64)   # w, the buffer fill (an array: the kernel
        self._warned = False                      # updates it in place)

    def reset(self) -> None:
        self.H[:] = 0.0
        self.fill[0] = 0
        self._warned = False

    def _f0_block(self, n: int) -> None:
        """cp b_g(n'), cc a0_g(n') for n' in [n, n + BLOCK), vectorised over groups and steps
        (the exact values below n' = 64)."""
        ns = np.arange(n, n + self._BLOCK, dtype=float)[:, None]      # (B, 1)
        a = self.alphas[None, :]                                      # (1, G)
        with np.errstate(divide='ignore', invalid='ignore'):
            b = np.power(ns, a) * np.expm1(a * np.log1p(1.0 / ns))
            y = 1.0 / ns
            coef = self.a0_coef
            acc = np.broadcast_to(coef[:, -1], (ns.size, self.G)).copy()
            for i in range(coef.shape[1] - 2, -1, -1):
                acc *= y
                acc += coef[:, i]
            a0 = np.power(ns, a - 1.0) * acc
        small = int(max(0, min(64 - n, ns.size)))
        if small:                                   # n' < 64: exact start weights
            k = ns[:small, 0]
            for g, al in enumerate(self.alphas.tolist()):
                b[:small, g] = _b_lag(al, k)
            a0[:small] = self.a0_small[:, n:n + small].T
        out = np.empty((ns.size, self.G, 2))
        out[:, :, 0] = self.cp * b
        out[:, :, 1] = self.cc * a0
        self._f0w, self._f0_base = out, n

    def _fold(self) -> None:
        K, n0 = self.K, self.n0
        M, buf, tmp = self._M, self._buf, self._tmp
        np.multiply(M, self.eps_k, out=tmp)
        M -= tmp                                   # z^K M
        M += np.matmul(buf[:, :, :K], self.ET)
        buf[:, :, :n0] = buf[:, :, K:K + n0]
        self.fill[0] = n0

    def check_horizon(self, n: int) -> None:
        """Warn once when step ``n`` is past the horizon the SOE tolerance holds for."""
        if n > self.horizon and not self._warned:
            self._warned = True
            warnings.warn(f"SOE history beyond horizon_steps={self.horizon}: kernel accuracy "
                          f"no longer guaranteed", RuntimeWarning, stacklevel=4)

    def push(self, n: int, f: np.ndarray) -> None:
        """Store f_n (called for n = 0, 1, 2, ... in order)."""
        f = f.reshape(self.G, self.d)
        if n == 0:
            self.H[:, :, 0] = f
            return
        if self.fill[0] == self.n0 + self.K:
            self._fold()
            self.check_horizon(n)
        w = int(self.fill[0])
        self._buf[:, :, w] = f
        self.fill[0] = w + 1

    def sums(self, n: int) -> np.ndarray:
        """(2, G d): scaled predictor and corrector sums of step n -> n+1."""
        i = n - self._f0_base
        if not 0 <= i < self._f0w.shape[0]:
            self._f0_block(n)
            i = 0
        wt = self.W[int(self.fill[0])]
        wt[:, 0] = self._f0w[i]
        np.matmul(self.H, wt, out=self._out)      # rows past the fill have weight 0
        return self._out.transpose(2, 0, 1).reshape(2, -1)


def _batch_orders(alpha) -> float | np.ndarray:
    """A scalar order as a float; per-point orders as a 1-D float array (each checked)."""
    if np.ndim(alpha) == 0:
        return check_alpha(alpha)
    arr = np.array(alpha, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"fractional_order alpha must be a number or a 1-D array of per-point "
                         f"orders in (0, 1] (dimensionless), got shape {arr.shape}")
    for a in np.unique(arr):
        check_alpha(a)
    if np.all(arr == arr[0]):
        return float(arr[0])            # one order for all: the (faster) scalar path
    return arr


class SOEStepper(PECEStepperBase):
    """ABM predictor-corrector with bounded cost per step (sum-of-exponentials history).

    Same scheme and :meth:`step` semantics as :class:`~.abm.ABMStepper` (docs/model.md §5.4, §5.6;
    Diethelm-Ford-Freed 2002):

        x^P_{n+1} = x0 + h^a/G(a+1) sum_j b_{j,n+1} f_j,
        x_{n+1}   = x0 + h^a/G(a+2) [ f(t_{n+1}, x^P_{n+1}) + sum_j a_{j,n+1} f_j ],

    except that the weights of lags >= ``n_exact`` are replaced by their sum-of-exponentials
    approximation (module docstring; Jiang et al. 2017; Baffet & Hesthaven 2017), relative error
    below ``tolerance`` for every lag up to ``horizon_steps`` (:func:`soe_kernel_error`). The
    last n_exact lags and the f_0 terms are exact.

    Accuracy: deviation from ABMStepper of order tolerance x (sum |weights f|)/|x| (measured,
    tolerance 1e-10, damped 4-state linear system, 1e5 steps: ~1e-11 of max|x|, <= 2e-9
    pointwise-relative); the ABM discretisation error O(h^(1+a)) is unchanged. Beyond
    ``horizon_steps`` a RuntimeWarning is issued once and the error grows slowly. Cost per
    step: 2 rhs calls + O((n_exact + 32 + L) d), L ~ 60-90 modes, independent of n; memory
    O((n_exact + 32 + L) d). ``capacity`` is accepted for
    signature compatibility and ignored. Modes are cached per (alpha, tolerance, horizon,
    n_exact); h does not enter.

    Raises:
        ValueError: invalid alpha, step, x0, tolerance, horizon_steps or n_exact.
        FloatingPointError: a step produced a non-finite state (status becomes 'failed').
    """

    def __init__(self, rhs: RhsFn, alpha: float, step: float, x0, t0: float = 0.0,
                 capacity: int | None = None, *, tolerance: float = 1e-10,
                 horizon_steps: int = 10**8, n_exact: int = 16) -> None:
        self._soe_args = (tolerance, horizon_steps, n_exact)
        super().__init__(rhs, alpha, step, x0, t0, capacity)   # checks alpha (_check_order)

    @property
    def modes(self) -> SOEModes:
        """The SOE modes in use."""
        return self._modes

    def _make_history(self, m: int) -> SOEHistory:
        """One group of m columns with this stepper's (checked) order."""
        self._modes = soe_modes(self._alpha, *self._soe_args)
        return SOEHistory(np.array([self._alpha]), [self._modes], m,
                          np.array([self._cp]), np.array([self._cc]))


class BatchSOE(BatchMixin, SOEStepper):
    """P independent :class:`SOEStepper` systems (same h) advanced together, X (P, d).

    ``alpha`` is one order for all points, or a (P,) array of per-point orders (an alpha
    sweep in one batch); an array whose entries are all equal takes the scalar path.
    ``rhs(t, X (P, d), U) -> (P, d)`` acting row by row. With one order the history sums are
    one BLAS product over all P d columns; with per-point orders each point keeps its own SOE
    modes and ABM weights (mode sets padded to a common count with zero-weight modes) and the
    sums are one stacked matrix product (:class:`SOEHistory` with one group per point).
    Either way each point equals a per-point SOEStepper run with its order up to rounding
    (tested to 1e-12).

    Accuracy: as :class:`SOEStepper`. Cost per step: 2 rhs calls + O((n_exact + 32 + L) P d)
    (a few 1e6 point-steps/s per core at P = 512, d = 4 for a cheap rhs and one order; the
    per-point-order product is about 2x the one-order gemm, small against the rhs); setup
    ~10 ms per distinct order (the SOE modes, cached per process).
    ``on_nonfinite``: 'raise' (default) or 'mask' (see :class:`~.abm.BatchABM`).

    Raises:
        ValueError: invalid alpha (or an alpha array not of shape (P,)), step, X0 (finite 2-D
            array), tolerance, horizon_steps, n_exact or on_nonfinite.
        FloatingPointError: see ``on_nonfinite``.
    """

    def __init__(self, rhs: RhsFn, alpha, step: float, x0, t0: float = 0.0,
                 capacity: int | None = None, *, tolerance: float = 1e-10,
                 horizon_steps: int = 10**8, n_exact: int = 16,
                 on_nonfinite: str = 'raise') -> None:
        self._init_batch(on_nonfinite)
        orders = _batch_orders(alpha)
        if isinstance(orders, float):
            self._alphas = None
            super().__init__(rhs, orders, step, x0, t0, capacity, tolerance=tolerance,
                             horizon_steps=horizon_steps, n_exact=n_exact)
            return
        rows = np.shape(x0)[0] if np.ndim(x0) == 2 else None
        if rows is not None and rows != orders.size:
            raise ValueError(f"fractional_order alpha has {orders.size} entries but X0 has "
                             f"{rows} rows (one order per point)")
        self._alphas = orders
        cache = {a: soe_modes(a, tolerance, horizon_steps, n_exact)
                 for a in np.unique(orders).tolist()}
        self._point_modes = tuple(cache[a] for a in orders.tolist())
        PECEStepperBase.__init__(self, rhs, orders, step, x0, t0, capacity)

    def _check_order(self, alpha):
        if self._alphas is None:
            return alpha                    # checked once, by _batch_orders
        return self._alphas[:, None]        # (P, 1): cp, cc broadcast over the state columns

    def _make_history(self, m: int):
        if self._alphas is None:
            return super()._make_history(m)
        P = self._alphas.size
        return SOEHistory(self._alphas, list(self._point_modes), m // P,
                          self._cp[:, 0], self._cc[:, 0])

    @property
    def alpha(self):
        """The order: a float, or a (P,) array of per-point orders (a copy)."""
        return self._alpha if self._alphas is None else self._alphas.copy()

    @property
    def alphas(self) -> np.ndarray:
        """Per-point orders (P,) (all equal in the one-order case)."""
        if self._alphas is None:
            return np.full(self._shape[0], self._alpha)
        return self._alphas.copy()

    @property
    def modes(self):
        """The SOE modes: one :class:`SOEModes`, or a tuple of them per point."""
        return self._modes if self._alphas is None else self._point_modes
