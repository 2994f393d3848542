"""Fractional integral and Caputo derivative of a sampled signal, online, O(1) per sample.

For a signal f sampled on a uniform grid t_n = t_0 + n h (several channels at once):

* :class:`OnlineIntegral` -- the Riemann-Liouville integral of order lam in (0, 1],
  I^lam f(t_n) = 1/Gamma(lam) int_{t_0}^{t_n} (t_n - s)^(lam-1) f(s) ds, by the product
  trapezoidal rule (f linear between samples; exact for piecewise-linear f): the corrector
  weights of the ABM scheme (docs/model.md §5.4),
  I^lam f(t_n) ~= h^lam/Gamma(lam+2) [a_{0,n} f_0 + sum_{j=1}^{n-1} a_{j,n} f_j + f_n];
* :class:`OnlineCaputoDerivative` -- the Caputo derivative of order mu in (0, 1] by the L1
  scheme (f linear between samples; exact for piecewise-linear f, error O(h^(2-mu)) for smooth
  f): D^mu f(t_n) ~= h^(1-mu)/Gamma(2-mu) sum_{j=0}^{n-1} b(n-1-j) (f_{j+1} - f_j)/h with
  b(k) = (k+1)^(1-mu) - k^(1-mu), the predictor weights of order 1 - mu; mu = 1 is the
  backward difference.

Both keep their history in an :class:`~.soe.SOEHistory` (the FOM solver's), so a call costs the
same at every n: the last 16-48 lags are summed with exact weights, older ones through a sum of
exponentials whose weights are within ``tolerance`` (relative, default 1e-10) of the exact ones
for every lag up to ``horizon_steps`` (default 1e12). Pure numpy; no ROS imports.
"""

from __future__ import annotations

import numpy as np

from ._stored import gamma
from ._validate import check_alpha, check_positive_int, check_step
from .soe import SOEHistory
from .soe_kernel import soe_modes

__all__ = ['OnlineIntegral', 'OnlineCaputoDerivative']


def _history(order: float, step: float, channels: int, tolerance: float,
             horizon_steps: int) -> SOEHistory:
    modes = soe_modes(order, tolerance, horizon_steps)
    cp = step ** order / gamma(order + 1.0)
    cc = step ** order / gamma(order + 2.0)
    return SOEHistory(np.array([order]), [modes], channels, np.array([cp]), np.array([cc]))


class _Online:
    """Shared by the two operators: checked order, step and channel count."""

    def __init__(self, order: float, step: float, channels: int) -> None:
        self.order = check_alpha(order)
        self.step = check_step(step)
        self.channels = check_positive_int(channels, 'channels', low=1)
        self.n = 0

    def _sample(self, values) -> np.ndarray:
        return np.asarray(values, dtype=float).reshape(self.channels)


class OnlineIntegral(_Online):
    """I^order of ``channels`` signals sampled every ``step`` s (see the module docstring).

    ``update(f_n)`` takes the samples at t_n (n = 0, 1, ...) and returns I^order f(t_n) (0 at
    n = 0). Accuracy: exact for piecewise-linear f up to the SOE tolerance; O(h^2) for smooth
    f. Cost: O(1) per call (about 100-200 modes and lags times ``channels``).

    Raises:
        ValueError: order outside (0, 1], step not finite > 0, channels < 1, or a sample of
            the wrong length.
    """

    def __init__(self, order: float, step: float, channels: int = 1, *,
                 tolerance: float = 1e-10, horizon_steps: int = 10**12) -> None:
        super().__init__(order, step, channels)
        self._hist = _history(self.order, self.step, self.channels, tolerance, horizon_steps)
        self._cc = self._hist.cc[0]
        self.reset()

    def reset(self) -> None:
        """Forget the history (the next sample is t_0)."""
        self._hist.reset()
        self.n = 0

    def update(self, values) -> np.ndarray:
        f = self._sample(values)
        n = self.n
        if n == 0:
            out = np.zeros(self.channels)
        else:
            out = self._hist.sums(n - 1)[1] + self._cc * f    # f_0 .. f_{n-1}, then f_n
        self._hist.push(n, f)
        self.n = n + 1
        return out


class OnlineCaputoDerivative(_Online):
    """D^order (Caputo, L1 scheme) of ``channels`` signals sampled every ``step`` s.

    ``update(f_n)`` returns D^order f(t_n) (0 at n = 0). Accuracy: exact for piecewise-linear
    f up to the SOE tolerance; O(h^(2-order)) for smooth f. Cost: O(1) per call.

    Raises:
        ValueError: order outside (0, 1], step not finite > 0, channels < 1, or a sample of
            the wrong length.
    """

    def __init__(self, order: float, step: float, channels: int = 1, *,
                 tolerance: float = 1e-10, horizon_steps: int = 10**12) -> None:
        super().__init__(order, step, channels)
        beta = 1.0 - self.order
        self._hist = (None if beta == 0.0 else
                      _history(beta, self.step, self.channels, tolerance, horizon_steps))
        self.reset()

    def reset(self) -> None:
        """Forget the history (the next sample is t_0)."""
        if self._hist is not None:
            self._hist.reset()
        self.n = 0
        self._last: np.ndarray | None = None

    def update(self, values) -> np.ndarray:
        f = self._sample(values)
        n = self.n
        self.n = n + 1
        last, self._last = self._last, f.copy()
        if n == 0:
            return np.zeros(self.channels)
        slope = (f - last) / self.step               # g_{n-1}: the slope over [t_{n-1}, t_n]
        if self._hist is None:
            return slope                             # order 1: the backward difference
        self._hist.push(n - 1, slope)
        return self._hist.sums(n - 1)[0].copy()      # predictor weights of order 1 - mu
