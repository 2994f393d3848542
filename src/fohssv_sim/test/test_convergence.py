"""Observed convergence of the three models' solvers (short runs).

The full step-halving study behind the default steps (params.DEFAULT_STEPS: V = 75 m/s, 2 s,
halving the default step changes the last 0.5 s by less than a stated tolerance) runs in
``make bench`` (``bench/bench_convergence.py``, which checks those tolerances); here a short
run of each model at three steps h, h/2, h/4 checks the same property in seconds: the change
from halving shrinks at an observed order above 1 (measured: delay-free 1.5, delayed 1.2,
FOM 1.3 with h = 8e-5 s over 0.2 s; the planing force's kinks keep it below the schemes'
smooth orders).
"""

import numpy as np
import pytest

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.batch import simulate_batch
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

SAMPLE = 4e-4     # compare on a common 0.4 ms grid
DURATION = 0.2    # s: long enough for the planing force to act (tail slap starts ~0.05 s)
STEP = 8e-5       # s: h, h/2, h/4 = 8e-5, 4e-5, 2e-5


def observed_order(params: ModelParameters, steps=(STEP, STEP / 2, STEP / 4)) -> float:
    """log2 of the ratio of the successive changes max |x(h) - x(h/2)| on a common grid."""
    runs = [simulate_batch([params.replace(step=h)], [StateFeedback()], DURATION,
                           sample_every=round(SAMPLE / h)) for h in steps]
    assert all(np.array_equal(runs[0].t, r.t) for r in runs)
    d1, d2 = (np.abs(a.states[0] - b.states[0]).max() for a, b in zip(runs, runs[1:]))
    assert d2 > 0.0
    return float(np.log2(d1 / d2))


@pytest.mark.parametrize('params', [ModelParameters(model='delay-free'),
                                    ModelParameters(model='delayed'),
                                    ModelParameters(solver='soe')],
                         ids=['delay-free', 'delayed', 'fractional-soe'])
def test_halving_the_step_converges_at_an_observed_order_above_one(params):
    assert observed_order(params) > 1.0


def test_alpha_one_fom_is_the_integer_model_with_smooth_planing():
    # ABM at alpha = 1 is the trapezoidal predictor-corrector: second order, so its distance
    # to the RK4 solution of the same ODE (smooth Fp) must shrink about 4x per halving.
    diffs = []
    for h in (4e-5, 2e-5, 1e-5):
        fom = simulate_batch([ModelParameters(solver='soe', step=h, fractional_order=1.0)],
                             [StateFeedback()], 0.3)
        ref = simulate(ModelParameters(model='delay-free', planing_form='smooth', step=h),
                       StateFeedback(), 0.3)
        assert np.abs(ref.planing_force).max() > 10.0   # planing is part of the comparison
        diffs.append(np.abs(fom.states[0] - ref.state).max())
    orders = np.log2(np.array(diffs[:-1]) / np.array(diffs[1:]))
    assert np.all(orders > 1.8), orders
    assert diffs[-1] < 1e-5
