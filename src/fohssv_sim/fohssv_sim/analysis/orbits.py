"""Orbit diagrams: local maxima after a transient, and a stated classification of each orbit.

Method (recorded with every result as :data:`METHOD`):

1. The signal (w by default) over the sampling window, after the transient.
2. ``steady`` (one class for the whole steady side) when the peak-to-peak range is below the
   steady tolerance ``steady_rtol * scale``, or when the range still shrinks. The tolerance is
   relative to the state's scale (``scale``: by default the largest |value| over the window,
   1.87 m/s for w at the eq. 31 equilibrium), not absolute: the default ``steady_rtol`` 1e-4 of
   that scale is far above what the step resolves (the default FOM solver at its converged
   step stays within 4.2e-9 of max|x| of the exact ABM) and above the algebraic tail of a
   fractional approach to the equilibrium (1e-6 to 5e-6 m/s peak-to-peak of w over the
   default window), yet far below the smallest cycle: the eq. 31 loop's tail-slap cycle
   appears with 0.05-0.07 m/s peak-to-peak of w at the first alpha grid value above alpha_c
   (V = 75-90 m/s). Fractional trajectories converge
   algebraically (~t^-alpha), not exponentially, so a window whose range still shrinks is
   steady too (converging: the peak-to-peak range of the window's last quarter is below 0.8
   times its first quarter's). ``converging`` tells those apart in the classification.
3. A window above the tolerance without local maxima whose range does not shrink is
   ``drifting`` (monotone motion, not settled, not oscillating).
4. Local maxima, refined by a parabola through the three samples around each.
5. ``periodic`` with period count p when the last maxima repeat with period p (p <= max_period)
   to within ``rel_tol`` of the window's range; p is the number of distinct maxima per period,
   as an orbit diagram shows them.
6. Otherwise ``aperiodic`` (quasi-periodic or chaotic), with the 0-1 test for chaos
   (Gottwald & Melbourne 2004, 2009; correlation method, median over 100 frequencies c in
   (pi/5, 4pi/5)) applied to the sequence of maxima: K near 1 suggests chaos, near 0
   quasi-periodic motion. K is reported, not thresholded into a verdict by itself.

The stability boundary alpha* of a sweep is where ``steady`` changes to an oscillating class
(:data:`OSCILLATING`) along alpha (:func:`fohssv_sim.analysis.diagrams.alpha_star`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ['METHOD', 'OrbitClass', 'local_maxima', 'classify', 'zero_one_test', 'OSCILLATING',
           'STEADY_RTOL']

METHOD = ('peak-to-peak < steady_rtol * scale (scale: the state\'s largest |value| over the '
          'window) or a shrinking last-vs-first-quarter range -> steady; no local maxima '
          'otherwise -> drifting; maxima repeating with period p <= max_period within rel_tol '
          'of the range -> periodic-p; else aperiodic with the 0-1 test statistic K of the '
          'maxima (Gottwald-Melbourne correlation method)')
#: Default steady tolerance, relative to the state's scale (see the module docstring).
STEADY_RTOL = 1e-4
#: The classes on the oscillating side of the stability boundary.
OSCILLATING = ('periodic', 'aperiodic')


@dataclass(frozen=True)
class OrbitClass:
    """The classification of one orbit."""

    kind: str             # 'steady' | 'drifting' | 'periodic' | 'aperiodic'
    period: int           # distinct maxima per period (periodic), else 0
    n_maxima: int
    amplitude: float      # peak-to-peak of the signal over the window
    k01: float            # 0-1 test statistic (NaN when not computed)
    tolerance: float = float('nan')   # the steady tolerance used (signal's unit)
    converging: bool = False          # steady because the range still shrinks

    @property
    def label(self) -> str:
        return f'periodic-{self.period}' if self.kind == 'periodic' else self.kind

    def to_dict(self) -> dict:
        d = asdict(self)
        d['label'] = self.label
        return d


def local_maxima(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Times and values of the strict local maxima of a sampled signal, each refined by the
    parabola through its sample and the two neighbours (error O(dt^3) for smooth peaks)."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if y.size < 3:
        return np.empty(0), np.empty(0)
    i = np.flatnonzero((y[1:-1] > y[:-2]) & (y[1:-1] >= y[2:])) + 1
    y0, y1, y2 = y[i - 1], y[i], y[i + 1]
    denom = y0 - 2.0 * y1 + y2
    with np.errstate(divide='ignore', invalid='ignore'):
        off = np.where(denom != 0.0, 0.5 * (y0 - y2) / denom, 0.0)
    off = np.clip(off, -0.5, 0.5)
    dt = np.gradient(t)[i]
    peak = y1 - 0.25 * (y0 - y2) * off
    return t[i] + off * dt, peak


def zero_one_test(phi: np.ndarray, n_c: int = 100, seed: int = 0) -> float:
    """Median K of the 0-1 test for chaos (correlation method) on the sequence ``phi``.

    Gottwald & Melbourne, Proc. R. Soc. A 460 (2004) 603; SIAM J. Appl. Dyn. Syst. 8 (2009)
    129. Returns NaN for fewer than 20 samples.
    """
    phi = np.asarray(phi, dtype=float)
    n = phi.size
    if n < 20:
        return float('nan')
    phi = phi - phi.mean()
    rng = np.random.default_rng(seed)
    cs = rng.uniform(np.pi / 5, 4 * np.pi / 5, n_c)
    ncut = max(2, n // 10)
    lags = np.arange(1, ncut + 1)
    j = np.arange(1, n + 1)
    ks = []
    mean_sq = phi.mean() ** 2
    for c in cs:
        p = np.cumsum(phi * np.cos(j * c))
        q = np.cumsum(phi * np.sin(j * c))
        M = np.array([np.mean((p[k:] - p[:-k]) ** 2 + (q[k:] - q[:-k]) ** 2) for k in lags])
        D = M - mean_sq * (1 - np.cos(lags * c)) / (1 - np.cos(c))
        if np.std(D) == 0.0:
            ks.append(0.0)
            continue
        ks.append(np.corrcoef(lags, D)[0, 1])
    return float(np.median(ks))


def classify(t: np.ndarray, y: np.ndarray, *, steady_rtol: float = STEADY_RTOL,
             scale: float | None = None, rel_tol: float = 1e-3, max_period: int = 32,
             min_repeats: int = 3) -> tuple[OrbitClass, np.ndarray]:
    """Classify the orbit sampled by (``t``, ``y``) over the window; see the module docstring.

    ``scale``: the state's scale the steady tolerance is relative to (default: the largest
    |y| over the window). Returns the class and the values of the local maxima (the orbit
    diagram's points).
    """
    y = np.asarray(y, dtype=float)
    amplitude = float(np.ptp(y)) if y.size else 0.0
    if scale is None:
        scale = float(np.max(np.abs(y))) if y.size else 0.0
    tol = steady_rtol * scale
    _, peaks = local_maxima(t, y)
    n = int(peaks.size)
    if amplitude <= tol:
        return OrbitClass('steady', 0, n, amplitude, float('nan'), tol), peaks
    quarter = max(3, y.size // 4)
    first, last = np.ptp(y[:quarter]), np.ptp(y[-quarter:])
    if last < 0.8 * first:
        return OrbitClass('steady', 0, n, amplitude, float('nan'), tol, True), peaks
    if peaks.size == 0:
        return OrbitClass('drifting', 0, 0, amplitude, float('nan'), tol), peaks
    rtol = rel_tol * amplitude
    for p in range(1, max_period + 1):
        need = p * (min_repeats + 1)
        if peaks.size < need:
            break
        tail = peaks[-need:]
        if np.all(np.abs(tail[p:] - tail[:-p]) <= rtol):
            return OrbitClass('periodic', p, n, amplitude, float('nan'), tol), peaks
    k = zero_one_test(peaks)
    return OrbitClass('aperiodic', 0, n, amplitude, k, tol), peaks
