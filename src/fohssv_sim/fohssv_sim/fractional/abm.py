"""Online Adams-Bashforth-Moulton (ABM) predictor-corrector for Caputo systems.

Solves  D^a x(t) = f(t, x, u),  0 < a <= 1,  x(t0) = x0  on t_n = t0 + n h with the scheme of
Diethelm, Ford & Freed (2002), Nonlinear Dyn. 29:3-22, eqs. (1.4)-(1.9) (docs/model.md §5.4):

    x^P_{n+1} = x0 + h^a/G(a+1) * sum_{j=0..n} b_{j,n+1} f_j
    x_{n+1}   = x0 + h^a/G(a+2) * [ f(t_{n+1}, x^P_{n+1}, u) + sum_{j=0..n} a_{j,n+1} f_j ]

with f_j = f(t_j, x_j, u_j) stored once per step (the history term) and the weights of
:mod:`.weights`. Global error O(h^(1+a)) for smooth D^a x (Diethelm, Ford & Freed 2004,
Numer. Algorithms 36:31-52); for the typical x = x0 + c t^a + ... the observed order is about
1 + a for a near 1 and 2a for small a.

:class:`ABMStepper` is the exact reference (O(n) per step); the history-sum engine is shared
with the bounded-cost :class:`~.soe.SOEStepper` and with the batched steppers through
:class:`PECEStepperBase`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ._stored import gamma
from ._validate import check_alpha, check_positive_int, check_state, check_step, check_t0
from .weights import WeightTable, weight_table

__all__ = ['ABMStepper', 'BatchABM', 'BatchMixin', 'PECEStepperBase', 'ExactHistory']

RhsFn = Callable[[float, np.ndarray, Any], np.ndarray]


class ExactHistory:
    """Exact ABM history sums over stored right-hand sides (time-ordered, grown by doubling).

    ``push(n, f)`` stores f_n (flattened, length m); ``sums(n)`` returns the (2, m) array

        [ cp * sum_{j=0..n} b_{j,n+1} f_j ,  cc * sum_{j=0..n} a_{j,n+1} f_j ]

    of docs/model.md §5.4, with ``scale = (cp, cc) = (h^a/G(a+1), h^a/G(a+2))``. Accuracy: exact up
    to rounding (one BLAS product over the history). Cost: O(n m) per call to ``sums``; memory
    (capacity) x m doubles, doubled when full.

    Raises:
        MemoryError: the doubled buffer cannot be allocated (no other errors; no checks on
            the call order, which the steppers guarantee).
    """

    def __init__(self, table: WeightTable, m: int, capacity: int = 1024,
                 scale: tuple[float, float] = (1.0, 1.0)) -> None:
        self._table = table
        self._m = m
        self._scale = np.array(scale, dtype=float)[:, None]
        self._F = np.zeros((max(int(capacity), 16), m))

    def reset(self) -> None:
        """Forget the stored history (keeps the buffer)."""
        self._F[:] = 0.0

    def push(self, n: int, f: np.ndarray) -> None:
        """Store f_n (must be called for n = 0, 1, 2, ... in order)."""
        F = self._F
        if n >= F.shape[0]:
            G = np.zeros((2 * F.shape[0], self._m))
            G[:F.shape[0]] = F
            self._F = F = G
        F[n] = f

    def sums(self, n: int) -> np.ndarray:
        """Return the scaled (2, m) predictor and corrector history sums of step n -> n+1."""
        tab = self._table
        if n >= tab.capacity:
            tab.ensure(n)
        F = self._F
        bc = tab.bc_rev
        cap = bc.shape[0]
        # lags n-1..0 (j = 1..n) against the contiguous time-ordered slice F[1:n+1]
        out = bc[cap - n:].T @ F[1:n + 1] if n > 0 else np.zeros((2, self._m))
        out[0] += bc[cap - 1 - n, 0] * F[0]        # b(n) f_0
        out[1] += tab.a0[n] * F[0]                 # a_{0,n+1} f_0
        out *= self._scale
        return out

    def fill(self, F: np.ndarray) -> None:
        """Replace the stored history by rows F[0..k-1] (testing / benchmarking helper)."""
        F = np.asarray(F, dtype=float).reshape(F.shape[0], self._m)
        cap = self._F.shape[0]
        while cap < F.shape[0] + 1:
            cap *= 2
        self._F = np.zeros((cap, self._m))
        self._F[:F.shape[0]] = F


class PECEStepperBase:
    """Shared driver of the ABM predictor-corrector (docs/model.md §5.4) for any history engine.

    Per step n -> n+1 (t_n = t0 + n h):

        f_n       = rhs(t_n, x_n, u_n)                       stored in the history
        x^P_{n+1} = x0 + h^a/G(a+1) * S^P_n                  S^P_n = sum_j b_{j,n+1} f_j
        x_{n+1}   = x0 + h^a/G(a+2) * [ rhs(t_{n+1}, x^P_{n+1}, u^P) + S^C_n ]

    where ``u`` passed to :meth:`step` is either an array held over [t_n, t_{n+1}]
    (u_n = u^P = u) or a callable u(t, x) (u_n = u(t_n, x_n), u^P = u(t_{n+1}, x^P_{n+1})).
    ``u=None`` passes an empty array. The state may be (d,) or (P, d) (batched); the history
    engine only sees it flattened.

    Subclasses provide ``_make_history(m)``. Not meant to be used directly.

    Raises:
        ValueError: invalid alpha, step, t0 or x0 (message names parameter, value, range,
            unit), or an rhs result of the wrong shape.
        FloatingPointError: a step produced a non-finite state (status becomes 'failed').
        RuntimeError: step() called on a failed stepper (call reset()).
    """

    _state_ndim = 1

    def __init__(self, rhs: RhsFn, alpha: float, step: float, x0, t0: float = 0.0,
                 capacity: int | None = None) -> None:
        if not callable(rhs):
            raise ValueError(f"rhs={rhs!r} must be callable as rhs(t, x, u) -> dx")
        self._rhs = rhs
        self._alpha = self._check_order(alpha)
        self._h = check_step(step)
        self._t0 = check_t0(t0)
        x0 = check_state(x0, 'x0', ndim=self._state_ndim)
        self._shape = x0.shape
        self._m = x0.size
        self._capacity = (1024 if capacity is None
                          else check_positive_int(capacity, 'capacity', unit='steps'))
        a = self._alpha
        self._cp = self._h ** a / gamma(a + 1.0)      # predictor factor h^a / G(a+1)
        self._cc = self._h ** a / gamma(a + 2.0)      # corrector factor h^a / G(a+2)
        self._hist = self._make_history(self._m)
        self._empty_u = np.zeros(0)
        self.reset(x0)

    # -- subclass hooks ---------------------------------------------------------------------
    def _make_history(self, m: int):  # pragma: no cover - abstract
        raise NotImplementedError

    def _check_order(self, alpha):
        """The validated order: a float (the batched SOE stepper may return a (P, 1) array of
        per-point orders, which the factors h^a/G(a+1), h^a/G(a+2) broadcast over)."""
        return check_alpha(alpha)

    # -- public API ---------------------------------------------------------------------------
    def reset(self, x0) -> None:
        """Restart at t = t0 from state ``x0`` (same shape as before), clearing the history.

        Raises:
            ValueError: x0 of the wrong shape or non-finite.
        """
        x0 = check_state(x0, 'x0', shape=getattr(self, '_shape', None), ndim=self._state_ndim)
        self._x0 = x0.copy()
        self._x0.flags.writeable = False
        self._x = x0.copy()
        self._n = 0
        self._status = 'running'
        self._last_rhs: np.ndarray | None = None
        self._hist.reset()

    @property
    def alpha(self) -> float:
        """Fractional order a in (0, 1]."""
        return self._alpha

    @property
    def step_size(self) -> float:
        """Step h (s)."""
        return self._h

    @property
    def t(self) -> float:
        """Current time t_n = t0 + n h (s)."""
        return self._t0 + self._n * self._h

    @property
    def x(self) -> np.ndarray:
        """Copy of the current state x_n."""
        return self._x.copy()

    @property
    def n(self) -> int:
        """Number of steps taken."""
        return self._n

    @property
    def status(self) -> str:
        """'running' or 'failed' (after a non-finite step)."""
        return self._status

    @property
    def history(self):
        """The history engine (its arrays are what a compiled kernel advances in place)."""
        return self._hist

    def live_state(self) -> np.ndarray:
        """The current state array itself (not a copy), for a compiled kernel that advances
        the stepper in place; report what it did with :meth:`advanced`."""
        return self._x

    def advanced(self, steps: int, last_rhs: np.ndarray, failed: bool = False) -> None:
        """Record ``steps`` steps taken by a compiled kernel on :meth:`live_state` and
        :attr:`history`; ``last_rhs`` is f of the last step (kept by reference: the caller's
        buffer, which the kernel overwrites on its next call; :attr:`last_rhs` copies);
        ``failed``: the next step turned non-finite (the stepper then refuses to step until
        reset)."""
        self._n += steps
        if steps or failed:
            self._last_rhs = last_rhs
        if failed:
            self._status = 'failed'

    @property
    def last_rhs(self) -> np.ndarray | None:
        """History term f_{n-1} = rhs(t_{n-1}, x_{n-1}, u_{n-1}) of the last step (a copy), i.e.
        the Caputo derivative D^a x at the start of that step; None before the first step."""
        return None if self._last_rhs is None else self._last_rhs.reshape(self._shape).copy()

    def _eval(self, t: float, x: np.ndarray, u) -> np.ndarray:
        f = self._rhs(t, x, u)
        if not (isinstance(f, np.ndarray) and f.shape == self._shape and f.dtype == np.float64):
            f = np.asarray(f, dtype=float)
            if f.shape != self._shape:
                raise ValueError(f"rhs returned shape {f.shape}, expected {self._shape} "
                                 f"(state shape)")
        return f

    def step(self, u=None) -> np.ndarray:
        """Advance one step h with input ``u`` (array held constant, or callable u(t, x)).

        Returns the new state x_{n+1} (a copy). Accuracy and cost: see the class docstring.

        Raises:
            FloatingPointError: x_{n+1} is not finite (names t and the state); status 'failed'.
            RuntimeError: the stepper has failed before (call reset()).
            ValueError: rhs returned the wrong shape.
        """
        if self._status != 'running':
            raise RuntimeError(f"stepper failed at t={self.t!r} s; call reset(x0) first")
        n = self._n
        h = self._h
        tn = self._t0 + n * h
        tn1 = self._t0 + (n + 1) * h
        xn = self._x
        if callable(u):
            un = np.asarray(u(tn, xn), dtype=float)
        else:
            un = self._empty_u if u is None else np.asarray(u, dtype=float)
        fn = self._eval(tn, xn, un)
        self._last_rhs = fn.copy()
        hist = self._hist
        hist.push(n, fn.reshape(-1))
        s = hist.sums(n)
        xp = self._x0 + s[0].reshape(self._shape)
        up = np.asarray(u(tn1, xp), dtype=float) if callable(u) else un
        fp = self._eval(tn1, xp, up)
        xn1 = (self._x0 + s[1].reshape(self._shape)) + self._cc * fp
        if not np.isfinite(xn1).all():
            return self._nonfinite(n, tn1, xn1)
        self._x = xn1
        self._n = n + 1
        return xn1.copy()

    def _nonfinite(self, n: int, tn1: float, xn1: np.ndarray) -> np.ndarray:
        self._status = 'failed'
        raise FloatingPointError(
            f"non-finite state at t={tn1!r} s (step {n + 1}, h={self._h!r} s, "
            f"alpha={self._alpha!r}): x={np.array2string(xn1, threshold=20)}; "
            f"last finite state x={np.array2string(self._x, threshold=20)}")

    def run(self, n_steps: int, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Take ``n_steps`` steps with the same ``u`` (array or callable); return (t, x) with
        the n_steps+1 times and states including the current one.

        Raises:
            ValueError: n_steps not a non-negative integer.
            FloatingPointError: see :meth:`step`.
        """
        n_steps = check_positive_int(n_steps, 'n_steps', low=0)
        ts = np.empty(n_steps + 1)
        xs = np.empty((n_steps + 1,) + self._shape)
        ts[0], xs[0] = self.t, self._x
        for i in range(1, n_steps + 1):
            xs[i] = self.step(u)
            ts[i] = self.t
        return ts, xs


class ABMStepper(PECEStepperBase):
    """Exact online ABM predictor-corrector (Diethelm-Ford-Freed 2002; docs/model.md §5.4).

    Integrates D^a x = rhs(t, x, u), 0 < a <= 1, x(t0) = x0 in R^d with uniform step h:

        x^P_{n+1} = x0 + h^a/G(a+1) sum_{j=0..n} b_{j,n+1} f_j,  b_{j,n+1} = (n+1-j)^a - (n-j)^a
        x_{n+1}   = x0 + h^a/G(a+2) [ f(t_{n+1}, x^P_{n+1}) + sum_{j=0..n} a_{j,n+1} f_j ]

    with f_j = rhs(t_j, x_j, u_j) and the weights computed cancellation-free
    (:mod:`.weights`). At a = 1 the weights are b = 1, a_{0,n+1} = 1, a_{j,n+1} = 2 and the
    scheme is the trapezoidal PECE in integral (Volterra) form: predictor x0 + h sum f_j,
    corrector x0 + h/2 (f_0 + 2 f_1 + ... + 2 f_n + f^P_{n+1}). It is second order, but not
    step-for-step identical to Heun's x_n + h/2 (f_n + f(x_n + h f_n)): the two differ by
    O(h^2) globally.

    Accuracy: global error O(h^(1+a)) (order ~2a for small a when x ~ t^a near t0).
    Cost per step: 2 rhs calls + O(n d) for the history sums (one BLAS product over the stored
    f's); memory O(n d), preallocated and doubled when full (``capacity`` = initial size).
    :meth:`~PECEStepperBase.step` semantics: see :class:`PECEStepperBase`.

    Raises:
        ValueError: alpha outside (0, 1], step not finite > 0, x0 not a finite 1-D array,
            capacity < 1 (message names parameter, value, range and unit).
        FloatingPointError: a step produced a non-finite state (status becomes 'failed').
    """

    def _make_history(self, m: int) -> ExactHistory:
        return ExactHistory(weight_table(self._alpha), m, self._capacity,
                            scale=(self._cp, self._cc))


class BatchMixin:
    """Batch behaviour shared by :class:`BatchABM` and :class:`~.soe.BatchSOE`: state (P, d),
    per-point failure handling (``on_nonfinite`` = 'raise' or 'mask'). Cost: O(P d) per step
    on top of the stepper.

    Raises:
        ValueError: on_nonfinite not 'raise' or 'mask'.
        FloatingPointError: a point became non-finite in mode 'raise' (names t and the points).
    """

    _state_ndim = 2

    def _init_batch(self, on_nonfinite: str) -> None:
        if on_nonfinite not in ('raise', 'mask'):
            raise ValueError(f"on_nonfinite={on_nonfinite!r} is not one of 'raise', 'mask'")
        self._on_nonfinite = on_nonfinite
        self._failed = np.zeros(0, dtype=bool)

    def reset(self, x0) -> None:
        """Restart all points at t0 from X0 (P, d); clears history and failure marks.

        Raises:
            ValueError: X0 of the wrong shape or non-finite.
        """
        super().reset(x0)  # type: ignore[misc]
        self._failed = np.zeros(self._shape[0], dtype=bool)  # type: ignore[attr-defined]

    @property
    def failed_points(self) -> np.ndarray:
        """Boolean (P,) mask of the points that became non-finite (mode 'mask')."""
        return self._failed.copy()

    def _alpha_text(self, rows: np.ndarray) -> str:
        a = self._alpha  # type: ignore[attr-defined]
        if np.ndim(a) == 0:
            return repr(a)
        return repr(np.asarray(a).reshape(-1)[rows[:10]].tolist())   # per-point orders

    def _nonfinite(self, n: int, tn1: float, xn1: np.ndarray) -> np.ndarray:
        bad = ~np.isfinite(xn1).all(axis=1)
        if self._on_nonfinite == 'raise':
            rows = np.flatnonzero(bad & ~self._failed)
            self._status = 'failed'
            raise FloatingPointError(
                f"non-finite state at t={tn1!r} s (step {n + 1}, h={self._h!r} s, "  # type: ignore
                f"alpha={self._alpha_text(rows)}) for points {rows[:10].tolist()}"
                f"{' ...' if rows.size > 10 else ''}: "
                f"x={np.array2string(xn1[rows[:3]], threshold=20)}")
        self._failed |= bad
        xn1 = xn1.copy()
        xn1[self._failed] = math.nan
        self._x = xn1
        self._n = n + 1
        return xn1.copy()


class BatchABM(BatchMixin, ABMStepper):
    """P independent copies of :class:`ABMStepper` (same alpha and h) advanced together.

    The state X has shape (P, d); ``rhs(t, X (P, d), U) -> (P, d)`` must act row by row; U is
    what :meth:`step` gets (e.g. (P, du)) or, if that is callable, U(t, X). The history sums
    are one BLAS product over all P d columns, so each point's result equals a per-point
    :class:`ABMStepper` run up to rounding (<= 1e-12 relative, tested).

    Accuracy: as :class:`ABMStepper`. Cost per step: 2 rhs calls + O(n P d).

    ``on_nonfinite='raise'`` (default) raises FloatingPointError if any point becomes
    non-finite; ``'mask'`` sets that point's state to NaN, records it in
    :attr:`failed_points` and keeps advancing the others.

    Raises:
        ValueError: invalid alpha, step, X0 (must be a finite 2-D array) or on_nonfinite.
        FloatingPointError: see ``on_nonfinite``.
    """

    def __init__(self, rhs: RhsFn, alpha: float, step: float, x0, t0: float = 0.0,
                 capacity: int | None = None, *, on_nonfinite: str = 'raise') -> None:
        self._init_batch(on_nonfinite)
        super().__init__(rhs, alpha, step, x0, t0, capacity)
