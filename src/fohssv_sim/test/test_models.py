"""The integer-order models against exact solutions and each other."""

import math

import numpy as np
import pytest
from scipy.linalg import expm

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.coefficients import coefficients
from fohssv_sim.models import DelayedModel, DelayFreeModel, make_plant
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate, steps_per_period

U = (0.002, -0.004)   # small constant deflections: the tail stays inside the cavity


def exact_linear(params, t, u=U):
    """x(t) of x' = A x + B u + G from x(0) = 0 by the augmented matrix exponential
    (valid while |w| stays below the contact velocity, so Fp = 0)."""
    c = coefficients(params)
    M = np.zeros((5, 5))
    M[:4, :4] = c.A
    M[:4, 4] = c.B @ np.array(u) + c.G
    return (expm(M * t) @ np.r_[np.zeros(4), 1.0])[:4]


def run(params, u, duration):
    plant = make_plant(params)
    for _ in range(round(duration / params.step)):
        plant.step(u)
    return plant


def test_rk4_matches_matrix_exponential_in_the_linear_regime():
    p = ModelParameters(model='delay-free', step=1e-4)
    plant = run(p, U, 0.05)
    assert abs(plant.state[1]) < 0.5 * coefficients(p).contact_velocity  # no planing
    assert np.allclose(plant.state, exact_linear(p, plant.t), rtol=1e-9, atol=1e-12)


def test_rk4_observed_order_is_four():
    errors = []
    steps = (2e-3, 1e-3, 5e-4)
    for h in steps:
        p = ModelParameters(model='delay-free', step=h)
        plant = run(p, U, 0.05)
        errors.append(np.max(np.abs(plant.state - exact_linear(p, 0.05))))
    slopes = np.diff(np.log(errors)) / np.diff(np.log(steps))
    assert np.all(np.abs(slopes - 4.0) < 0.3), slopes


def test_callable_constant_input_equals_held_input():
    p = ModelParameters(model='delay-free')
    a, b = make_plant(p), make_plant(p)
    for _ in range(500):
        a.step(U)
        b.step(lambda t, x: U)
    assert np.array_equal(a.state, b.state) and a.t == b.t == 500 * p.step


def test_time_is_exact_multiple_of_the_step():
    p = ModelParameters(model='delay-free')
    plant = run(p, U, 0.01)
    assert plant.n == 1000 and plant.t == 1000 * 1e-5


def test_delayed_with_zero_delay_equals_delay_free():
    # closed loop with tail slap (planing active), 0.3 s
    a = simulate(ModelParameters(model='delay-free'), StateFeedback(), 0.3)
    b = simulate(ModelParameters(model='delayed', advection_delay=0.0), StateFeedback(), 0.3)
    assert np.abs(a.planing_force).max() > 10.0   # the comparison includes planing
    assert np.allclose(a.state, b.state, rtol=1e-10, atol=1e-12)


def test_delayed_tends_to_delay_free_as_delay_shrinks():
    ref = simulate(ModelParameters(model='delay-free'), StateFeedback(), 0.2)
    diffs = []
    for tau in (4e-4, 2e-4, 1e-4):
        r = simulate(ModelParameters(model='delayed', advection_delay=tau), StateFeedback(), 0.2)
        diffs.append(np.abs(r.state - ref.state).max())
    assert diffs[0] > diffs[1] > diffs[2]
    assert diffs[2] < 0.7 * diffs[0] / 2   # at least first order in tau


def test_delayed_history_before_zero_is_the_initial_state():
    # x(s) = x(0) for s <= 0: a state at rest in the cavity sees no planing until t = tau
    p = ModelParameters(model='delayed', step=1e-4, advection_delay=0.01)
    x0 = (0.0, 0.0, 0.0, 0.0)
    plant = DelayedModel(p, x0)
    assert plant.planing_force == 0.0
    for _ in range(50):
        plant.step((0.0, 0.0))
    assert plant.planing_force == 0.0


def test_non_finite_state_fails_with_time_and_state_and_refuses_more_steps():
    p = ModelParameters(model='delay-free')
    plant = DelayFreeModel(p, (0.0, 1e308, 0.0, 1e308))
    with pytest.raises(FloatingPointError, match=r't=1e-05 s: \[z, w, theta, q\]'):
        plant.step((0.0, 0.0))
    assert plant.status == 'failed'
    with pytest.raises(RuntimeError, match='reset'):
        plant.step((0.0, 0.0))
    plant.reset((0.0, 0.0, 0.0, 0.0))
    plant.step((0.0, 0.0))
    assert plant.status == 'running'


def test_bad_initial_state_is_rejected():
    with pytest.raises(ValueError, match='4 finite numbers'):
        DelayFreeModel(ModelParameters(model='delay-free'), (0.0, math.nan, 0.0, 0.0))
    with pytest.raises(ValueError, match='4 finite numbers'):
        DelayFreeModel(ModelParameters(model='delay-free'), (0.0, 0.0))


def test_zero_order_hold_holds_the_command_over_the_period():
    p = ModelParameters(model='delay-free')
    r = simulate(p, StateFeedback(), 0.01, control_period=1e-4)
    dc = r.inputs[:, 1]
    k = 10
    for i in range(0, len(dc) - k, k):
        assert np.all(dc[i:i + k] == dc[i])
    with pytest.raises(ValueError, match='whole multiple of the integration step'):
        steps_per_period(1.5e-5, 1e-5)
    with pytest.raises(ValueError, match='duration'):
        simulate(p, StateFeedback(), -1.0)


def test_deflection_limit_default_does_not_bind_in_the_reference_loops():
    # clamping at the generous default must leave the eq. 31 loop unchanged
    for model in ('delay-free', 'delayed'):
        p = ModelParameters(model=model)
        a = simulate(p, StateFeedback(), 0.5)
        b = simulate(p, StateFeedback(max_cavitator_deflection=1.5), 0.5)
        assert np.array_equal(a.state, b.state)
