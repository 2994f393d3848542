"""SOEStepper: kernel tolerance over the horizon, deviation from the exact ABM, bounded state."""

import mpmath as mp
import numpy as np
import pytest

from fohssv_sim.fractional import (
    ABMStepper,
    SOEStepper,
    soe_kernel_error,
    soe_modes,
    solve_abm_fft,
)

from linear4 import A4, B4, X4


def rhs(t, x, u):
    return A4 @ x + B4 @ u


@pytest.mark.parametrize('alpha', [0.05, 0.5, 0.85, 0.99])
def test_kernel_tolerance_met_over_horizon(alpha):
    rep = soe_kernel_error(alpha)                      # tolerance 1e-10, horizon 1e8
    assert rep.max <= 1e-10, rep
    assert rep.kernel <= 1e-10, rep
    assert rep.n_lags_checked > 5000
    assert rep.n_modes < 120


def test_kernel_tolerance_other_settings():
    assert soe_kernel_error(0.7, tolerance=1e-12, horizon_steps=10**6).max <= 1e-12
    assert soe_kernel_error(0.7, tolerance=1e-6, horizon_steps=10**9, n_exact=8).max <= 1e-6
    assert soe_modes(0.7, 1e-6).n_modes < soe_modes(0.7, 1e-12).n_modes


def test_tail_weights_against_mpmath_at_large_lags():
    # independent of the weights module: 50-digit textbook weights at lags up to the horizon
    alpha = 0.85
    modes = soe_modes(alpha)
    ks = [16, 17, 100, 12345, 10**6, 3 * 10**7, 10**8]
    b, c = modes.tail_weights(ks)
    with mp.workdps(50):
        a = mp.mpf(alpha)
        for i, k in enumerate(ks):
            K = mp.mpf(k)
            eb = (K + 1) ** a - K ** a
            ec = (K + 2) ** (a + 1) - 2 * (K + 1) ** (a + 1) + K ** (a + 1)
            assert abs(mp.mpf(float(b[i])) / eb - 1) < 1e-10
            assert abs(mp.mpf(float(c[i])) / ec - 1) < 1e-10


def test_modes_are_cached():
    assert soe_modes(0.85) is soe_modes(0.85)
    st1 = SOEStepper(rhs, 0.85, 1e-3, X4)
    st2 = SOEStepper(rhs, 0.85, 1e-4, X4)       # the step does not enter the (lag-unit) modes
    assert st1.modes is st2.modes


@pytest.mark.parametrize('alpha', [0.6, 0.85])
def test_soe_matches_exact_with_input_changing_every_step(alpha):
    h, N = 1e-3, 4000
    U = np.sin(50.0 * h * np.arange(N))[:, None]
    ref = solve_abm_fft(rhs, alpha, h, X4, N, u=U).x          # = ABMStepper (tested)
    st = SOEStepper(rhs, alpha, h, X4)
    got = np.array([X4] + [st.step(U[n]) for n in range(N)])
    dev = np.max(np.abs(got - ref), axis=1)
    assert np.max(dev / np.max(np.abs(ref), axis=1)) <= 1e-8
    assert np.max(dev) > 0.0                                    # the tail really is approximate


def test_soe_matches_abmstepper_directly():
    alpha, h, N = 0.75, 2e-3, 600
    a = ABMStepper(rhs, alpha, h, X4)
    s = SOEStepper(rhs, alpha, h, X4)
    for n in range(N):
        u = np.array([np.sin(50 * n * h)])
        xa, xs = a.step(u), s.step(u)
        assert np.max(np.abs(xs - xa)) <= 1e-8 * np.max(np.abs(xa))


def test_soe_long_run_matches_exact():
    # 1e5 steps: the modes carry lags up to 1e5
    alpha, h, N = 0.85, 1e-3, 100_000
    U = (np.sin(50.0 * h * np.arange(N)) + 0.5)[:, None]
    ref = solve_abm_fft(rhs, alpha, h, X4, N, u=U).x
    st = SOEStepper(rhs, alpha, h, X4)
    got = np.empty_like(ref)
    got[0] = X4
    for n in range(N):
        got[n + 1] = st.step(U[n])
    assert np.max(np.abs(got - ref)) <= 1e-8 * np.max(np.abs(ref))
    tail = slice(N // 2, None)
    assert np.max(np.abs(got[tail] - ref[tail]) / np.abs(ref[tail]).max(axis=1)[:, None]) <= 1e-8


def test_soe_alpha_one_equals_abm():
    h, N = 0.01, 500
    a = ABMStepper(rhs, 1.0, h, X4)
    s = SOEStepper(rhs, 1.0, h, X4)
    assert s.modes.n_modes == 1
    for _ in range(N):
        np.testing.assert_allclose(s.step(np.array([0.3])), a.step(np.array([0.3])),
                                   rtol=1e-12, atol=1e-13)


def test_soe_memory_is_bounded():
    st = SOEStepper(rhs, 0.85, 1e-3, X4)
    sizes = []
    for n in range(5000):
        st.step(np.array([0.0]))
        if n in (100, 4999):
            sizes.append(sum(v.nbytes for v in vars(st._hist).values()
                             if isinstance(v, np.ndarray)))
    assert sizes[0] == sizes[1]


def test_soe_reset_and_callable_input():
    def u_fb(t, x):
        return np.array([-0.5 * x[0]])

    st = SOEStepper(rhs, 0.8, 1e-2, X4)
    a = np.array([st.step(u_fb) for _ in range(300)])
    st.reset(X4)
    b = np.array([st.step(u_fb) for _ in range(300)])
    np.testing.assert_array_equal(a, b)
    ref = ABMStepper(rhs, 0.8, 1e-2, X4)
    c = np.array([ref.step(u_fb) for _ in range(300)])
    assert np.max(np.abs(a - c)) <= 1e-8 * np.max(np.abs(c))


def test_soe_warns_beyond_horizon():
    st = SOEStepper(rhs, 0.8, 1e-2, X4, horizon_steps=200)
    with pytest.warns(RuntimeWarning, match='horizon_steps=200'):
        for _ in range(300):
            st.step(np.array([0.0]))


def test_soe_bad_arguments():
    with pytest.raises(ValueError, match=r'alpha=0\.0 is outside \(0, 1\]'):
        SOEStepper(rhs, 0.0, 1e-3, X4)
    with pytest.raises(ValueError, match='tolerance'):
        SOEStepper(rhs, 0.5, 1e-3, X4, tolerance=0.5)
    with pytest.raises(ValueError, match='horizon_steps'):
        SOEStepper(rhs, 0.5, 1e-3, X4, horizon_steps=0)
    with pytest.raises(ValueError, match=r'step h=nan'):
        SOEStepper(rhs, 0.5, float('nan'), X4)
    with pytest.raises(ValueError, match='x0'):
        SOEStepper(rhs, 0.5, 1e-3, [np.nan, 1.0, 0.0, 0.0])
