"""Weights of the Adams-Bashforth-Moulton predictor-corrector for Caputo equations.

Spec section 5 (Diethelm, Ford & Freed 2002, Nonlinear Dyn. 29, eqs. (1.4)-(1.9)):

    x^P_{n+1} = x0 + h^a/G(a+1) * sum_{j=0..n} b_{j,n+1} f_j,
    x_{n+1}   = x0 + h^a/G(a+2) * [ f(t_{n+1}, x^P_{n+1}) + sum_{j=0..n} a_{j,n+1} f_j ],

    b_{j,n+1} = (n+1-j)^a - (n-j)^a
    a_{0,n+1} = n^(a+1) - (n-a) (n+1)^a
    a_{j,n+1} = (n-j+2)^(a+1) + (n-j)^(a+1) - 2 (n-j+1)^(a+1),   1 <= j <= n.

Apart from a_{0,n+1} the weights depend only on the lag k = n - j, so this module works with
lag-indexed sequences:

    b(k)  = (k+1)^a - k^a                                  (predictor, k >= 0)
    c(k)  = (k+2)^(a+1) - 2 (k+1)^(a+1) + k^(a+1)          (corrector, k >= 0, j >= 1)
    a0(n) = n^(a+1) - (n-a) (n+1)^a                        (corrector, j = 0)

Evaluated as written, these differences of nearly equal powers lose digits: the relative error
grows like eps*k (first differences) and eps*k^2 (second differences), about 1e-4 at k = 1e6.
Here they are evaluated without cancellation:

* b(k) = k^a * expm1(a * log1p(1/k)), a product of accurately computed factors;
* c(k) = m^(a-1) * 2 * sum_{i>=1} C(a+1, 2i) m^(2-2i), m = k+1 >= 2 (binomial series of
  (1+x)^(a+1) + (1-x)^(a+1) - 2 at x = 1/m; every term is positive for 0 < a < 1), and
  c(0) = 2 expm1(a ln 2);
* a0(n) = n^(a-1) * sum_{k>=2} d_k n^(2-k), d_k = C(a, k-1) (k-1)(a+1)/k for n >= 2 (series of
  1 - (1 - a x)(1 + x)^a at x = 1/n; alternating with a dominant first term), a0(1) =
  a 2^a - expm1(a ln 2), a0(0) = a.

Accuracy: a few ulp (relative error below 1e-14) for every index up to 2^53; checked against
50-digit mpmath in ``test/test_fractional_weights.py``. Cost: O(1) per weight (at most 32
series terms for indices below 64, 8-12 terms above), vectorised over index arrays.
"""

from __future__ import annotations

import math
import threading
from functools import lru_cache

import numpy as np

from ._validate import check_alpha, check_positive_int

__all__ = [
    'predictor_weights',
    'corrector_weights',
    'corrector_start_weights',
    'abm_weights',
    'WeightTable',
    'weight_table',
]

# Below this index the series in 1/m need more terms; above it 8 (12) terms reach 1e-18.
_SPLIT = 64


def _as_index(k: object, name: str) -> np.ndarray:
    arr = np.asarray(k)
    if arr.dtype.kind not in 'iu':
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.floor(arr)):
            raise ValueError(f"{name}={k!r} must be integers in [0, inf) (steps)")
    if np.any(arr < 0):
        raise ValueError(f"{name}={k!r} must be integers in [0, inf) (steps)")
    return arr.astype(np.float64)


def _binom_series(c0: float, factor, n_terms: int) -> np.ndarray:
    out = np.empty(n_terms)
    out[0] = c0
    for i in range(1, n_terms):
        out[i] = out[i - 1] * factor(i)
    return out


@lru_cache(maxsize=64)
def _second_difference_coeffs(alpha: float, n_terms: int) -> np.ndarray:
    """C(a+1, 2i) for i = 1..n_terms (all positive for 0 < a <= 1)."""
    beta = alpha + 1.0
    coeffs = np.empty(n_terms)
    # C(b, 2) = b (b-1) / 2 with b - 1 = alpha exactly.
    c = beta * alpha / 2.0
    coeffs[0] = c
    for i in range(2, n_terms + 1):
        # C(b, 2i) = C(b, 2i-2) * (b - 2i + 2)(b - 2i + 1) / ((2i - 1) 2i);
        # b - j = alpha - (j - 1) is computed from alpha to avoid rounding of b.
        c = c * (alpha - (2 * i - 3)) * (alpha - (2 * i - 2)) / ((2 * i - 1) * (2 * i))
        coeffs[i - 1] = c
    return coeffs


@lru_cache(maxsize=64)
def _start_coeffs(alpha: float, n_terms: int) -> np.ndarray:
    """d_k = C(a, k-1) (k-1) (a+1) / k for k = 2..n_terms+1."""
    out = np.empty(n_terms)
    binom = alpha  # C(a, 1)
    for idx, k in enumerate(range(2, n_terms + 2)):
        out[idx] = binom * (k - 1) * (alpha + 1.0) / k
        binom = binom * (alpha - (k - 1)) / k  # C(a, k) from C(a, k-1)
    return out


def _horner(coeffs: np.ndarray, y: np.ndarray) -> np.ndarray:
    acc = np.full_like(y, coeffs[-1])
    for c in coeffs[-2::-1]:
        acc *= y
        acc += c
    return acc


def _b_lag(alpha: float, k: np.ndarray) -> np.ndarray:
    out = np.ones_like(k)
    pos = k > 0
    kp = k[pos]
    out[pos] = np.power(kp, alpha) * np.expm1(alpha * np.log1p(1.0 / kp))
    return out


def _c_lag(alpha: float, k: np.ndarray) -> np.ndarray:
    m = k + 1.0
    out = np.empty_like(m)
    first = m == 1.0
    out[first] = 2.0 * math.expm1(alpha * math.log(2.0))
    for lo, hi, n_terms in ((2.0, _SPLIT, 32), (_SPLIT, np.inf, 8)):
        sel = (m >= lo) & (m < hi)
        if not np.any(sel):
            continue
        ms = m[sel]
        y = 1.0 / (ms * ms)
        series = _horner(_second_difference_coeffs(alpha, n_terms), y)
        out[sel] = 2.0 * np.power(ms, alpha - 1.0) * series
    return out


def _a0(alpha: float, n: np.ndarray) -> np.ndarray:
    out = np.empty_like(n)
    out[n == 0.0] = alpha
    out[n == 1.0] = alpha * 2.0 ** alpha - math.expm1(alpha * math.log(2.0))
    for lo, hi, n_terms in ((2.0, _SPLIT, 64), (_SPLIT, np.inf, 12)):
        sel = (n >= lo) & (n < hi)
        if not np.any(sel):
            continue
        ns = n[sel]
        series = _horner(_start_coeffs(alpha, n_terms), 1.0 / ns)
        out[sel] = np.power(ns, alpha - 1.0) * series
    return out


def predictor_weights(alpha: float, k) -> np.ndarray:
    """Predictor (product-rectangle) weights b(k) = (k+1)^a - k^a by lag k = n - j >= 0.

    Equals b_{j,n+1} of docs/model.md §5.4 / Diethelm-Ford-Freed (2002) eq. (1.7). Accuracy:
    relative error below 1e-14 for all k (no power differences are formed). Cost: O(1) per entry.

    Raises:
        ValueError: alpha outside (0, 1] or k not non-negative integers.
    """
    a = check_alpha(alpha)
    kk = _as_index(k, 'k')
    return _b_lag(a, np.atleast_1d(kk)).reshape(kk.shape)


def corrector_weights(alpha: float, k) -> np.ndarray:
    """Corrector (product-trapezoid) weights c(k) = (k+2)^(a+1) - 2(k+1)^(a+1) + k^(a+1).

    Equals a_{j,n+1} of docs/model.md §5.4 / Diethelm-Ford-Freed (2002) eq. (1.5) for j >= 1 with
    lag k = n - j. Accuracy: relative error below 1e-14 for all k (binomial series in 1/(k+1),
    all terms positive). Cost: O(1) per entry (<= 32 terms).

    Raises:
        ValueError: alpha outside (0, 1] or k not non-negative integers.
    """
    a = check_alpha(alpha)
    kk = _as_index(k, 'k')
    return _c_lag(a, np.atleast_1d(kk)).reshape(kk.shape)


def corrector_start_weights(alpha: float, n) -> np.ndarray:
    """Corrector weight of f_0: a0(n) = a_{0,n+1} = n^(a+1) - (n-a)(n+1)^a, n >= 0.

    Spec section 5 / Diethelm-Ford-Freed (2002) eq. (1.5), j = 0. Accuracy: relative error below
    1e-14 (alternating series in 1/n with dominant first term a(a+1)/2 n^(a-1)). Cost: O(1).

    Raises:
        ValueError: alpha outside (0, 1] or n not non-negative integers.
    """
    a = check_alpha(alpha)
    nn = _as_index(n, 'n')
    return _a0(a, np.atleast_1d(nn)).reshape(nn.shape)


def abm_weights(alpha: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The ABM weights of step n -> n+1 in the j indexing of docs/model.md §5.4.

    Returns ``(b, a)`` with ``b[j] = b_{j,n+1}`` for j = 0..n and ``a[j] = a_{j,n+1}`` for
    j = 0..n+1 (``a[n+1] = 1`` multiplies f(t_{n+1}, x^P_{n+1})), docs/model.md §5.4,
    Diethelm-Ford-Freed (2002) eqs. (1.5), (1.7). Accuracy: relative error below 1e-14 per
    weight. Cost: O(n).

    Raises:
        ValueError: alpha outside (0, 1] or n not a non-negative integer.
    """
    a = check_alpha(alpha)
    nn = check_positive_int(n, 'n', low=0)
    lags = np.arange(nn, -1, -1, dtype=np.float64)        # k = n - j, j = 0..n
    b = _b_lag(a, lags)
    corr = np.empty(nn + 2)
    corr[1:nn + 1] = _c_lag(a, lags[1:])
    corr[0] = _a0(a, np.array([float(nn)]))[0]
    corr[nn + 1] = 1.0
    return b, corr


class WeightTable:
    """Lag-indexed ABM weights of one order alpha, grown by doubling, computed once.

    ``bc_rev`` is a read-only (capacity, 2) array holding [b(k), c(k)] in *reversed* lag order,
    ``bc_rev[capacity-1-k] = (b(k), c(k))``, so the weights of lags L-1..0 are the contiguous
    slice ``bc_rev[capacity-L:]`` matching a time-ordered history slice f_{n-L+1..n}.
    ``b``, ``c`` (lag order, strided views) and ``a0`` (by n) are read-only too. Valid indices
    are 0..capacity-1; :meth:`ensure` grows the table.

    Accuracy: that of :func:`predictor_weights` etc. Cost: amortised O(1) per lag (each lag
    is computed once per process and order); memory 3 doubles per lag.

    ``alpha`` is trusted (a float in (0, 1], checked where it entered: the steppers'
    constructors or :class:`~fohssv_sim.params.ModelParameters`).
    """

    def __init__(self, alpha: float, capacity: int = 1024) -> None:
        self.alpha = float(alpha)   # trusted: checked where it entered (steppers, ModelParameters)
        self._lock = threading.Lock()
        self._cap = 0
        self._bc_rev = np.empty((0, 2))
        self._a0 = np.empty(0)
        self._grow(max(int(capacity), 16))

    @property
    def capacity(self) -> int:
        return self._cap

    def _grow(self, cap: int) -> None:
        old = self._cap
        k = np.arange(old, cap, dtype=np.float64)
        bc_rev = np.empty((cap, 2))
        a0 = np.empty(cap)
        bc_rev[cap - old:] = self._bc_rev
        a0[:old] = self._a0
        # lags old..cap-1 go to rows cap-1-old .. 0
        bc_rev[cap - old - 1::-1, 0] = _b_lag(self.alpha, k)
        bc_rev[cap - old - 1::-1, 1] = _c_lag(self.alpha, k)
        a0[old:] = _a0(self.alpha, k)
        bc_rev.flags.writeable = False
        a0.flags.writeable = False
        self._bc_rev, self._a0, self._cap = bc_rev, a0, cap

    def ensure(self, n: int) -> WeightTable:
        """Make indices 0..n available (grows the capacity by doubling). Returns self."""
        if n >= self._cap:
            with self._lock:
                cap = self._cap
                while cap <= n:
                    cap *= 2
                if cap > self._cap:
                    self._grow(cap)
        return self

    @property
    def bc_rev(self) -> np.ndarray:
        return self._bc_rev

    @property
    def b(self) -> np.ndarray:
        return self._bc_rev[::-1, 0]

    @property
    def c(self) -> np.ndarray:
        return self._bc_rev[::-1, 1]

    @property
    def a0(self) -> np.ndarray:
        return self._a0


@lru_cache(maxsize=8)
def weight_table(alpha: float) -> WeightTable:
    """Shared :class:`WeightTable` for ``alpha`` (one per order, grown on demand; the 8 most
    recently used orders are kept). ``alpha`` is trusted, as for :class:`WeightTable`.
    """
    return WeightTable(alpha)
