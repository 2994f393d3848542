"""The follower's filter: an extended Kalman filter of the FOM, one control period at a time.

Multiple shooting (:mod:`.shooting`) starts every segment with the memory of the measured
trajectory, which a *follower* builds: the model run beside the segments over the whole
record, corrected at every control instant towards the sample. How much of each sample it
takes is this filter's gain. Taking the sample whole (the follower restarted from it) puts the
measurement noise into the memory, where f, nonlinear through the planing force, turns it into
a bias of alpha growing as the noise squared; an unmeasured state (w and q of a vehicle that
measures depth and pitch) cannot be taken from a sample at all. The filter answers both: it
weighs each sample against the model's one-period prediction and corrects all four states
from the measured ones.

**The filter.** Over one period the FOM moves a correction d of its state by about
(I + c J) d, J the Jacobian of f (eq. 17's A, with the planing force's slope dFp/dw at the
follower's w in the w column) and c = h^alpha / Gamma(alpha + 1) (the weight of the last
period in the Caputo integral, h the control period): the one-period map the covariance P is
propagated through, P <- F P F^T + Q. The measured states (rows H) of noise R = sigma^2
(:mod:`.noise`, the estimate the test of "reproduces" uses) give the gain K = P H^T (H P H^T +
R)^-1, the correction K e of the innovation e = sample - follower, and P <- (I - K H) P. The
correction shifts the follower's state and its Volterra constant x0 (x = x0 + I^alpha f), so
it stays outside the fractional dynamics, and its history of f is kept. The initial state is
known (P starts at Q).

**Q**, the model's error per period the filter allows: :data:`PROCESS_NOISE` of each state's
standard deviation over the window (1 in the state's unit for a state not measured, whose
samples the fit never reads). Small against the noise of a measured run, so the filter follows
the model between samples and averages the noise over many of them; with noise-free data
(the noise at its floor, 1e-3 of the spread) it takes most of each sample. At the truth the
innovations are the noise and the filter is unbiased; at a wrong alpha the prediction errs
and the follower, hence each segment's memory, departs from the data, which the segments'
residual sees.

Pure: numpy, numba (the update is compiled into the shooting kernel).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ...params import ModelParameters
from ...physics import jitable, planing_exact, planing_smooth

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
def update(P, y, y0, e, c, co, smooth, Q, R, m):
    """One period of the filter, in place: P (4, 4) propagated through I + c J(y) (``co``
    the model's coefficients, ``smooth`` its planing form) and corrected by the innovations
    ``e`` of the states ``m`` (this sample's measured ones); the state ``y`` and its Volterra
    constant ``y0`` moved by K e."""
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
    K = PH @ np.linalg.inv(S)
    d = K @ e
    for i in range(4):
        y[i] += d[i]
        y0[i] += d[i]
    P[:, :] = P - K @ P
