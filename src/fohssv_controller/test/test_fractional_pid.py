"""The fractional PI^lambda D^mu controller and its online operators, against exact results.

* I^lam t^b = Gamma(b+1)/Gamma(b+1+lam) t^(b+lam) and D^mu t^b = Gamma(b+1)/Gamma(b+1-mu)
  t^(b-mu): exact (to the SOE tolerance) for b = 1, where the product-trapezoid and L1 rules
  are exact; for b = 2 the error falls at the rules' orders, 2 and 2 - mu.
* The SOE history against the same sums with every weight exact (O(n) per step).
* lambda = mu = 1 is the integer PID (trapezoidal integral, backward difference).
"""

import math

import numpy as np
import pytest

from fohssv_controller.fractional_pid import FractionalPID
from fohssv_sim.control import load
from fohssv_sim.fractional import OnlineCaputoDerivative, OnlineIntegral, weight_table
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate


def run_operator(op, f, T, h):
    n = round(T / h)
    out = None
    for k in range(n + 1):
        out = op.update([f(k * h)])
    return out[0]


@pytest.mark.parametrize('order', [0.3, 0.85, 1.0])
def test_integral_of_t_is_exact_and_of_t2_second_order(order):
    got = run_operator(OnlineIntegral(order, 1e-3), lambda t: t, 1.0, 1e-3)
    assert got == pytest.approx(1.0 / math.gamma(2.0 + order), rel=1e-9)
    exact = 2.0 / math.gamma(3.0 + order)
    errs = [abs(run_operator(OnlineIntegral(order, h), lambda t: t * t, 1.0, h) - exact)
            for h in (1e-2, 5e-3)]
    assert math.log2(errs[0] / errs[1]) == pytest.approx(2.0, abs=0.15)


@pytest.mark.parametrize('order', [0.3, 0.85, 1.0])
def test_caputo_derivative_of_t_is_exact_and_of_t2_at_order_2_minus_mu(order):
    got = run_operator(OnlineCaputoDerivative(order, 1e-3), lambda t: t, 1.0, 1e-3)
    assert got == pytest.approx(1.0 / math.gamma(2.0 - order), rel=1e-9)
    exact = 2.0 / math.gamma(3.0 - order)
    errs = [abs(run_operator(OnlineCaputoDerivative(order, h), lambda t: t * t, 1.0, h)
                - exact) for h in (1e-2, 5e-3, 2.5e-3)]
    observed = np.diff(np.log2(errs)) * -1.0
    assert np.all(np.abs(observed - (2.0 - order)) < 0.15), observed


def test_soe_history_equals_the_exact_weighted_sums():
    """5000 samples of a random signal: the O(1) operators against the O(n) sums with the
    exact product-trapezoid and L1 weights (weights.py, cancellation-free)."""
    rng = np.random.default_rng(3)
    f = rng.normal(size=5000)
    h, lam, mu = 1e-3, 0.7, 0.4
    I, D = OnlineIntegral(lam, h), OnlineCaputoDerivative(mu, h)
    got_i = np.array([I.update([v])[0] for v in f])
    got_d = np.array([D.update([v])[0] for v in f])
    ti, td = weight_table(lam).ensure(6000), weight_table(1.0 - mu).ensure(6000)
    cap = ti.bc_rev.shape[0]
    ref_i, ref_d = np.zeros(f.size), np.zeros(f.size)
    g = np.diff(f) / h
    for n in range(1, f.size):
        c_lags = ti.bc_rev[cap - n + 1:, 1]            # c(k), lags n-2 .. 0 for j = 1..n-1
        ref_i[n] = h ** lam / math.gamma(lam + 2.0) * (
            ti.a0[n - 1] * f[0] + c_lags @ f[1:n] + f[n])
        cap_d = td.bc_rev.shape[0]
        b_lags = td.bc_rev[cap_d - n:, 0]                # b(k), lags n-1 .. 0
        ref_d[n] = h ** (1.0 - mu) / math.gamma(2.0 - mu) * (b_lags @ g[:n])
    assert np.max(np.abs(got_i - ref_i)) <= 1e-8 * np.max(np.abs(ref_i))
    assert np.max(np.abs(got_d - ref_d)) <= 1e-8 * np.max(np.abs(ref_d))


def test_orders_one_give_the_integer_pid():
    gains = dict(depth_kp=2.0, depth_ki=3.0, depth_kd=0.5, pitch_kp=-4.0, pitch_ki=-1.5,
                 pitch_kd=-0.2, integral_order=1.0, derivative_order=1.0,
                 max_cavitator_deflection=1.5)
    ctl = FractionalPID(**gains)
    rng = np.random.default_rng(7)
    h = 1e-4
    states = rng.normal(scale=0.05, size=(200, 4))
    got = [ctl.command(k * h, x)[1] for k, x in enumerate(states)]
    e = states[:, [0, 2]]
    integral = np.vstack([np.zeros(2), np.cumsum((e[1:] + e[:-1]) * h / 2.0, axis=0)])
    deriv = np.vstack([np.zeros(2), np.diff(e, axis=0) / h])
    ref = (2.0 * e[:, 0] + 3.0 * integral[:, 0] + 0.5 * deriv[:, 0]
           - 4.0 * e[:, 1] - 1.5 * integral[:, 1] - 0.2 * deriv[:, 1])
    np.testing.assert_allclose(got, np.clip(ref, -1.5, 1.5), rtol=1e-9, atol=1e-12)


def test_registered_and_refuses_what_it_cannot_do():
    assert load('fractional_pid') is FractionalPID
    ctl = FractionalPID()
    ctl.command(0.0, [0.0] * 4)
    ctl.command(1e-4, [0.0] * 4)
    with pytest.raises(ValueError, match='uniform samples'):
        ctl.command(3e-4, [0.0] * 4)
    with pytest.raises(ValueError, match='keeps memory'):
        simulate(ModelParameters(model='delay-free'), FractionalPID(), 0.01)
    with pytest.raises(ValueError, match='integral_order'):
        FractionalPID(integral_order=1.5)


def test_closed_loop_with_fractional_terms_stays_bounded():
    """The FOM under PI^0.9 D^0.8 (zero-order hold 1e-4 s) runs, its outputs obey the limits
    and the loop settles near the run without it (small integral and derivative terms)."""
    p = ModelParameters()
    ctl = FractionalPID(depth_ki=1.0, pitch_ki=-1.0, integral_order=0.9,
                        derivative_order=0.8, pitch_kd=-0.3)
    r = simulate(p, ctl, 0.2, control_period=1e-4)
    assert np.isfinite(r.state).all()
    assert np.max(np.abs(r.inputs[:, 1])) <= ctl.params.max_cavitator_deflection
    assert np.max(np.abs(r.state[:, 1])) < 5.0
