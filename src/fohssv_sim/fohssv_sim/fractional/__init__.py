"""Numerics for Caputo fractional-order systems  D^a x = f(t, x, u),  0 < a <= 1.

The Adams-Bashforth-Moulton predictor-corrector of Diethelm, Ford & Freed (2002) (spec
section 5), on a uniform grid t_n = t0 + n h, in three forms that give the same numbers:

* :class:`ABMStepper` -- exact, online, O(n) per step (the reference);
* :func:`solve_abm_fft` -- exact, offline, O(N log^2 N) via FFT-blocked history sums;
* :class:`SOEStepper` -- online, O(1) per step: recent lags exact, the tail by a
  sum-of-exponentials kernel with relative tolerance (default 1e-10);

plus batched versions (:class:`BatchABM`, :class:`BatchSOE`) advancing P systems of the same
order and step together, :func:`group_by_alpha` and the cancellation-free weights
(:mod:`.weights`). Which solver a model uses is chosen by name in :mod:`fohssv_sim.solvers`.
Pure numpy/scipy; no ROS imports.
"""

from .abm import ABMStepper, BatchABM
from .batch import group_by_alpha
from .fft import ABMSolution, solve_abm_fft
from .operators import OnlineCaputoDerivative, OnlineIntegral
from .soe import BatchSOE, SOEHistory, SOEStepper
from .soe_kernel import SOEErrorReport, SOEModes, soe_kernel_error, soe_modes
from .weights import (
    WeightTable,
    abm_weights,
    corrector_start_weights,
    corrector_weights,
    predictor_weights,
    weight_table,
)

__all__ = [
    'ABMStepper',
    'SOEStepper',
    'OnlineIntegral',
    'OnlineCaputoDerivative',
    'SOEHistory',
    'BatchABM',
    'BatchSOE',
    'group_by_alpha',
    'solve_abm_fft',
    'ABMSolution',
    'SOEModes',
    'SOEErrorReport',
    'soe_modes',
    'soe_kernel_error',
    'abm_weights',
    'predictor_weights',
    'corrector_weights',
    'corrector_start_weights',
    'WeightTable',
    'weight_table',
]
