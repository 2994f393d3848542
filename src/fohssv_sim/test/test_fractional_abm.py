"""ABMStepper: convergence to Mittag-Leffler solutions, agreement with pycaputo's PECE, the
alpha = 1 limit, input semantics and argument checking."""

import math

import mpmath as mp
import numpy as np
import pymittagleffler
import pytest
from pycaputo.controller import make_fixed_controller
from pycaputo.derivatives import CaputoDerivative
from pycaputo.events import StepCompleted
from pycaputo.fode import caputo
from pycaputo.stepping import evolve
from scipy.special import gamma

from fohssv_sim.fractional import ABMStepper, abm_weights

from linear4 import A4, X4

A2 = np.array([[-1.0, 2.0], [-2.0, -1.0]])          # eigenvalues -1 +- 2i
X2 = np.array([1.0, 0.5])


def linear(A):
    return lambda t, x, u: A @ x


def mittag_leffler_solution(A, x0, t, alpha):
    """x(t) = E_alpha(A t^alpha) x0 by eigendecomposition (pymittagleffler on eigenvalues)."""
    lam, V = np.linalg.eig(A)
    c = np.linalg.solve(V, x0.astype(complex))
    e = np.asarray(pymittagleffler.mittag_leffler(lam * t ** alpha, alpha, 1.0))
    return (V @ (e * c)).real


def run(stepper, n, u=None):
    xs = [stepper.x]
    for _ in range(n):
        xs.append(stepper.step(u))
    return np.array(xs)


def test_mittag_leffler_reference_is_independent():
    # pymittagleffler against the defining series in 40-digit mpmath
    for alpha in (0.5, 0.85, 0.95):
        for z in (-1 + 2j, -1 - 2j, -3.0 + 0j, 0.5 + 0.1j):
            with mp.workdps(40):
                zz, aa = mp.mpc(z), mp.mpf(alpha)
                ref = mp.nsum(lambda k, zz=zz, aa=aa: zz ** k / mp.gamma(aa * k + 1), [0, mp.inf])
            got = complex(pymittagleffler.mittag_leffler(np.array([z]), alpha, 1.0)[0])
            assert abs(got - complex(ref)) < 1e-13 * max(1.0, abs(complex(ref)))


@pytest.mark.parametrize('alpha', [0.5, 0.85, 0.95])
def test_convergence_order_against_mittag_leffler(alpha):
    T = 1.0
    exact = mittag_leffler_solution(A2, X2, T, alpha)
    hs, errs = [], []
    for N in (40, 80, 160, 320):
        xs = run(ABMStepper(linear(A2), alpha, T / N, X2), N)
        hs.append(T / N)
        errs.append(np.max(np.abs(xs[-1] - exact)))
    slope = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(slope - (1.0 + alpha)) < 0.15, (alpha, slope, errs)
    assert errs[-1] < 1e-4


@pytest.mark.parametrize('alpha', [0.6, 0.85])
def test_matches_pycaputo_pece(alpha):
    N, h = 200, 0.01
    m = caputo.PECE(
        ds=tuple(CaputoDerivative(alpha) for _ in range(4)),
        control=make_fixed_controller(h, tstart=0.0, nsteps=N),
        source=lambda t, y: A4 @ y,
        y0=(X4.copy(),),
        corrector_iterations=1,
    )
    theirs = np.array([ev.y for ev in evolve(m, dtinit=h) if isinstance(ev, StepCompleted)])
    ours = run(ABMStepper(linear(A4), alpha, h, X4), N)
    assert theirs.shape == ours.shape
    scale = np.max(np.abs(theirs), axis=1, keepdims=True)
    assert np.max(np.abs(ours - theirs) / scale) < 1e-9


def vdp(t, x, u):
    """A nonlinear test field (damped Van der Pol-like)."""
    return np.array([x[1], -x[0] - 0.5 * (x[0] ** 2 - 1.0) * x[1] - 0.3 * x[1]])


def heun(f, x0, h, N):
    x, out = np.array(x0, dtype=float), [np.array(x0, dtype=float)]
    for n in range(N):
        k1 = f(n * h, x, None)
        x = x + h / 2 * (k1 + f((n + 1) * h, x + h * k1, None))
        out.append(x)
    return np.array(out)


def test_alpha_one_is_trapezoidal_pece_in_integral_form():
    h, N = 0.05, 60
    # independent implementation: predictor x0 + h sum f_j, corrector trapezoid with f^P last
    F, x, ref = [], X2.copy(), [X2.copy()]
    for n in range(N):
        F.append(vdp(n * h, x, None))
        S = np.sum(F, axis=0)
        xp = X2 + h * S
        x = X2 + h * (S - F[0] / 2 + vdp((n + 1) * h, xp, None) / 2)
        ref.append(x)
    ours = run(ABMStepper(vdp, 1.0, h, X2), N)
    np.testing.assert_allclose(ours, np.array(ref), rtol=1e-12, atol=1e-14)


def test_alpha_one_is_heun_for_linear_systems():
    # for affine f the integral-form scheme telescopes to Heun's x_n + h/2 (f_n + f(x_n + h f_n))
    h, N = 0.02, 200
    f = linear(A4)
    np.testing.assert_allclose(run(ABMStepper(f, 1.0, h, X4), N), heun(f, X4, h, N),
                               rtol=1e-12, atol=1e-14)


def test_alpha_one_nonlinear_second_order_and_close_to_heun():
    # for nonlinear f both converge at order 2 and differ from each other by O(h^2)
    from scipy.integrate import solve_ivp

    T = 2.0
    exact = solve_ivp(lambda t, x: vdp(t, x, None), (0, T), X2, rtol=1e-13, atol=1e-14,
                      method='DOP853').y[:, -1]
    err_abm, diff = [], []
    for N in (100, 200, 400):
        h = T / N
        x_abm = run(ABMStepper(vdp, 1.0, h, X2), N)[-1]
        x_heun = heun(vdp, X2, h, N)[-1]
        err_abm.append(np.max(np.abs(x_abm - exact)))
        diff.append(np.max(np.abs(x_abm - x_heun)))
    assert 3.5 < err_abm[0] / err_abm[1] < 4.5 and 3.5 < err_abm[1] / err_abm[2] < 4.5
    assert 3.5 < diff[0] / diff[1] < 4.5 and 3.5 < diff[1] / diff[2] < 4.5
    assert diff[-1] > 1e-8          # genuinely different schemes for nonlinear f


def test_callable_input_semantics_match_spec_loop():
    # u(t, x) evaluated at (t_n, x_n) for f_n and at (t_{n+1}, x^P_{n+1}) for the corrector,
    # checked against a direct implementation of docs/model.md §5.4 with its indexing of the weights
    alpha, h, N = 0.8, 0.02, 40
    B = np.array([0.0, 1.0])

    def rhs(t, x, u):
        return A2 @ x + B * u[0]

    def u_fb(t, x):
        return np.array([math.sin(3 * t) - 0.5 * x[0]])

    cp, cc = h ** alpha / gamma(alpha + 1), h ** alpha / gamma(alpha + 2)
    F, x, ref = [], X2.copy(), [X2.copy()]
    for n in range(N):
        F.append(rhs(n * h, x, u_fb(n * h, x)))
        b, a = abm_weights(alpha, n)
        Fa = np.array(F)
        xp = X2 + cp * (b @ Fa)
        t1 = (n + 1) * h
        x = X2 + cc * (a[:n + 1] @ Fa + a[n + 1] * rhs(t1, xp, u_fb(t1, xp)))
        ref.append(x)
    st = ABMStepper(rhs, alpha, h, X2)
    ours = run(st, N, u_fb)
    np.testing.assert_allclose(ours, np.array(ref), rtol=1e-12, atol=1e-14)
    assert st.n == N and st.t == pytest.approx(N * h)
    np.testing.assert_allclose(st.last_rhs, F[-1], rtol=1e-12)


def test_array_input_is_held_and_reset_restarts():
    st = ABMStepper(lambda t, x, u: -x + u, 0.9, 0.1, [0.0])
    a = run(st, 20, np.array([1.0]))
    assert st.status == 'running' and st.n == 20
    st.reset([0.0])
    assert st.n == 0 and st.t == 0.0 and st.last_rhs is None
    b = run(st, 20, np.array([1.0]))
    np.testing.assert_array_equal(a, b)
    assert 0.5 < a[-1, 0] < 1.0                       # relaxes towards u = 1
    x = st.x
    x[0] = 99.0
    assert st.x[0] != 99.0                            # x is a copy


def test_history_grows_beyond_capacity():
    st = ABMStepper(linear(A2), 0.7, 0.01, X2, capacity=16)
    ref = ABMStepper(linear(A2), 0.7, 0.01, X2, capacity=4096)
    np.testing.assert_array_equal(run(st, 300), run(ref, 300))


def test_nonfinite_state_raises_and_marks_failed():
    st = ABMStepper(lambda t, x, u: 1e200 * x * x, 0.8, 0.1, [1.0])
    with np.errstate(all='ignore'):
        with pytest.raises(FloatingPointError, match=r'non-finite state at t=.* s'):
            for _ in range(10):
                st.step()
    assert st.status == 'failed'
    with pytest.raises(RuntimeError, match='reset'):
        st.step()
    st.reset([0.0])
    assert st.status == 'running'


@pytest.mark.parametrize('bad', [1.3, 0.0, -0.5, float('nan'), 'abc', None])
def test_bad_alpha_message(bad):
    with pytest.raises(ValueError, match=r'fractional_order alpha=.* is outside \(0, 1\] '
                                         r'\(dimensionless\)'):
        ABMStepper(linear(A2), bad, 0.01, X2)


def test_bad_alpha_names_value():
    with pytest.raises(ValueError, match=r'alpha=1\.3 '):
        ABMStepper(linear(A2), 1.3, 0.01, X2)


@pytest.mark.parametrize('bad', [0.0, -1e-3, float('inf'), float('nan'), 'x'])
def test_bad_step_message(bad):
    with pytest.raises(ValueError, match=r'step h=.* is outside \(0, inf\) \(s\)'):
        ABMStepper(linear(A2), 0.8, bad, X2)


@pytest.mark.parametrize('bad', [[1.0, float('nan')], [float('inf'), 0.0], [[1.0, 2.0]], [],
                                 'ab'])
def test_bad_x0_message(bad):
    with pytest.raises(ValueError, match=r'x0'):
        ABMStepper(linear(A2), 0.8, 0.01, bad)


def test_rhs_shape_checked():
    st = ABMStepper(lambda t, x, u: np.zeros(3), 0.8, 0.01, X2)
    with pytest.raises(ValueError, match=r'rhs returned shape \(3,\)'):
        st.step()
