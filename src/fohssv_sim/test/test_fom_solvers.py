"""The FOM closed loop (V = 75, alpha = 0.85, eq. 31 continuous, 2 s) with every solver:
the bounded-cost 'soe' stepper stays within 1e-6 of the exact ABM answer, which the
FFT-blocked offline solver computes, and the online exact ABM equals it on a shorter run."""

import numpy as np

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.fractional import solve_abm_fft
from fohssv_sim.models import FractionalModel
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate


def exact(duration, alpha=0.85):
    p = ModelParameters(fractional_order=alpha)
    plant = FractionalModel(p)
    law = StateFeedback().command
    n = round(duration / p.step)
    sol = solve_abm_fft(plant.rhs, alpha, p.step, np.zeros(4), n,
                        u=lambda t, x: np.array(law(t, x)))
    return sol.t, sol.x


def test_soe_within_1e_6_of_exact_abm_on_the_fom_closed_loop_over_2_s():
    t, x = exact(2.0)
    r = simulate(ModelParameters(solver='soe'), StateFeedback(), 2.0)
    assert np.array_equal(r.t, t)
    assert np.ptp(x[t >= 1.5, 1]) > 0.1          # the limit cycle, planing included
    rel = np.abs(r.state - x).max() / np.abs(x).max()
    assert rel <= 1e-6, rel


def test_online_abm_equals_fft_abm_on_the_fom_closed_loop():
    t, x = exact(0.2)
    r = simulate(ModelParameters(solver='abm'), StateFeedback(), 0.2)
    assert np.max(np.abs(r.state - x)) <= 1e-12 * np.abs(x).max()
