"""The measurement noise of a run and the test of "reproduces" against it.

**Estimate.** Per state, from the data alone: the fourth difference of five consecutive
samples d_k = x_{k-2} - 4 x_{k-1} + 6 x_k - 4 x_{k+1} + x_{k+2} removes a smooth signal (its
part is h^4 times the fourth derivative, h the control period: 1e-4 of the amplitude for a
150 Hz tail-slap cycle sampled at 1e-4 s) and leaves 70 sigma^2 of white noise (1 + 16 + 36 +
16 + 1); sigma = 1.4826 MAD(d) / sqrt(70) (the median absolute deviation: a planing contact's
sharp turn moves a few d_k, not the median). It assumes dense sampling (the signal's fourth
difference small against the noise); otherwise give the noise per state (``--noise
z=...,theta=...``, in the state's unit). The noise used is never below ``floor`` times the
state's standard deviation over the window (the solver and model precision that clean data
are judged against).

**Test.** With the model right and the noise white and Gaussian, the residuals e = x_model -
x_data in noise units make T = mean(e^2 / sigma^2) (over the compared samples and measured
states, nu = N - p of them free) a chi^2_nu / nu variable; with sigma estimated from nu_s
effective samples, T is F(nu, nu_s). The run is reproduced when T is at most the 99 % quantile
of that F (the printed "residual / noise" is sqrt(T): about 1 at the noise floor). nu_s is the
MAD's efficiency (0.37) times the number of fourth differences over 5 (neighbouring ones share
samples): conservative.

Pure: numpy, scipy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: The smallest noise assumed, as a fraction of each state's standard deviation over the window.
DEFAULT_NOISE_FLOOR = 1e-3
#: The level of the test (the probability of refusing a right model).
TEST_LEVEL = 0.01
MAD_EFFICIENCY = 0.37


@dataclass(frozen=True)
class Noise:
    """Per state (z, w, theta, q): ``sigma`` used, ``estimated`` from the data (NaN where
    given or too few samples), ``given`` (None: estimated), ``floor`` (floor x std), and the
    effective dof of the estimate (inf: all given)."""

    sigma: np.ndarray
    estimated: np.ndarray
    given: tuple[float | None, ...]
    floor: np.ndarray
    dof: float
    measured: tuple[bool, ...] = (True,) * 4

    def to_dict(self) -> dict:
        return {'sigma': self.sigma.tolist(),
                'estimated': [None if not math.isfinite(v) else float(v)
                              for v in self.estimated],
                'given': list(self.given), 'floor': self.floor.tolist(),
                'dof': self.dof if math.isfinite(self.dof) else None,
                'at_floor': [bool(s <= f) for s, f in zip(self.sigma, self.floor)],
                'measured': list(self.measured)}


#: The order of the differences and the noise variance they carry, sum of the squared
#: binomial coefficients C(4, i).
ORDER, NOISE_GAIN = 4, 70.0


def difference_sigma(x: np.ndarray) -> tuple[float, int]:
    """(sigma, number of differences) of a series with NaN gaps (fourth differences of
    five consecutive finite samples only; NaN with fewer than 3 of them)."""
    x = np.asarray(x, dtype=float)
    d = np.diff(x, ORDER)                      # NaN wherever a sample of the five is missing
    d = d[np.isfinite(d)]
    if d.size < 3:
        return math.nan, int(d.size)
    mad = float(np.median(np.abs(d - np.median(d))))
    return 1.4826 * mad / math.sqrt(NOISE_GAIN), int(d.size)


def estimate(states: np.ndarray, scale: np.ndarray, given: Sequence[float | None],
             floor: float = DEFAULT_NOISE_FLOOR,
             measured: Sequence[bool] = (True,) * 4) -> Noise:
    """The noise of each ``measured`` state of ``states`` (samples x 4, NaN gaps) over the
    window; ``scale`` the states' standard deviations there."""
    est = np.full(4, math.nan)
    counts = []
    for j in range(4):
        if given[j] is None and measured[j]:
            est[j], n = difference_sigma(states[:, j])
            counts.append(n)
    fl = floor * np.asarray(scale, dtype=float)
    sigma = np.array([float(g) if g is not None else (est[j] if math.isfinite(est[j]) else 0.0)
                      for j, g in enumerate(given)])
    sigma = np.maximum(sigma, fl)
    dof = MAD_EFFICIENCY * min(counts) / (ORDER + 1) if counts else math.inf
    return Noise(sigma=sigma, estimated=est, given=tuple(given), floor=fl,
                 dof=max(dof, 1.0), measured=tuple(bool(m) for m in measured))


def critical(nu: int, noise_dof: float, level: float = TEST_LEVEL) -> float:
    """The largest mean(e^2 / sigma^2) consistent with the noise at ``level``."""
    from scipy.stats import chi2, f

    nu = max(int(nu), 1)
    if not math.isfinite(noise_dof):
        return float(chi2.ppf(1 - level, nu) / nu)
    return float(f.ppf(1 - level, nu, noise_dof))


def judge(ratio: float, nu: int, noise: Noise) -> tuple[bool, float]:
    """(consistent with the noise, the critical value) of T = ``ratio``."""
    c = critical(nu, noise.dof)
    return bool(math.isfinite(ratio) and ratio <= c), c


def effective_fraction(rows: np.ndarray) -> float:
    """n_eff / n of residual rows (samples x states): (1 - rho) / (1 + rho), rho the lag-1
    autocorrelation of the residual averaged over the states that vary (the AR(1) count of
    independent samples: 1 for white residuals, near 0 for the smooth residual of a model
    that cannot follow the run). Its intervals are widened by sqrt(n / n_eff)."""
    rho = []
    for col in np.asarray(rows, dtype=float).T:
        c = col - col.mean()
        d = float(c @ c)
        if col.size > 2 and d > 0:
            rho.append(float(c[1:] @ c[:-1]) / d)
    if not rho:
        return 1.0
    r = min(max(float(np.mean(rho)), 0.0), 1.0 - 1e-12)
    return (1.0 - r) / (1.0 + r)
