"""solve_abm_fft returns the ABMStepper numbers (to 1e-12 relative) for every input form."""

import math

import numpy as np
import pytest

from fohssv_sim.fractional import ABMStepper, solve_abm_fft

from linear4 import A4, B4, X4


def rhs(t, x, u):
    return A4 @ x + (B4 @ u if u.size else 0.0) + 0.2 * np.sin(x) + 0.1 * np.sin(3.0 * t)


def direct(alpha, h, N, u_seq=None, u_call=None, u_const=None):
    st = ABMStepper(rhs, alpha, h, X4)
    xs, fs = [X4.copy()], []
    for n in range(N):
        u = u_call if u_call is not None else (u_seq[n] if u_seq is not None else u_const)
        xs.append(st.step(u))
        fs.append(st.last_rhs)
    return np.array(xs), np.array(fs)


def rel_err(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


@pytest.mark.parametrize('N', [1, 2, 31, 63, 64, 65, 129, 257, 1500])
@pytest.mark.parametrize('alpha', [0.4, 0.85, 1.0])
def test_fft_equals_direct_per_step_inputs(alpha, N):
    h = 2.0 / max(N, 10)
    U = np.sin(50.0 * h * np.arange(N))[:, None]       # changes every step
    ref, fref = direct(alpha, h, N, u_seq=U)
    sol = solve_abm_fft(rhs, alpha, h, X4, N, u=U)
    assert sol.x.shape == (N + 1, 4) and sol.t.shape == (N + 1,)
    assert rel_err(sol.x, ref) < 1e-12
    assert rel_err(sol.f[:N], fref) < 1e-12
    np.testing.assert_allclose(sol.t, h * np.arange(N + 1), rtol=1e-15)


def test_fft_equals_direct_callable_and_constant_inputs():
    alpha, h, N = 0.7, 0.004, 2100

    def u_fb(t, x):
        return np.array([math.cos(7 * t) - 0.3 * x[0]])

    ref, _ = direct(alpha, h, N, u_call=u_fb)
    assert rel_err(solve_abm_fft(rhs, alpha, h, X4, N, u=u_fb).x, ref) < 1e-12
    ref, _ = direct(alpha, h, N, u_const=np.array([0.25]))
    assert rel_err(solve_abm_fft(rhs, alpha, h, X4, N, u=np.array([0.25])).x, ref) < 1e-12
    ref, _ = direct(alpha, h, N, u_const=np.zeros(0))
    assert rel_err(solve_abm_fft(rhs, alpha, h, X4, N).x, ref) < 1e-12


def test_fft_long_run_matches_direct():
    # several FFT levels (halves of 64..4096 steps) with a nonzero t0 (rhs depends on t)
    alpha, h, N = 0.85, 1e-3, 8000
    st = ABMStepper(rhs, alpha, h, X4, t0=1.5)
    ref = np.array([X4] + [st.step(np.array([0.1])) for _ in range(N)])
    sol = solve_abm_fft(rhs, alpha, h, X4, N, u=np.array([0.1]), t0=1.5)
    assert rel_err(sol.x, ref) < 1e-12
    assert sol.t[-1] == pytest.approx(1.5 + N * h, rel=1e-15)


def test_fft_zero_steps():
    sol = solve_abm_fft(rhs, 0.5, 0.1, X4, 0)
    np.testing.assert_array_equal(sol.x, X4[None])
    assert sol.t.tolist() == [0.0]


def test_fft_nonfinite_raises():
    with np.errstate(all='ignore'):
        with pytest.raises(FloatingPointError, match=r'non-finite state at t='):
            solve_abm_fft(lambda t, x, u: 1e200 * x * x, 0.8, 0.1, [1.0], 100)


def test_fft_bad_arguments():
    with pytest.raises(ValueError, match=r'alpha=2\.0 is outside \(0, 1\]'):
        solve_abm_fft(rhs, 2.0, 0.1, X4, 10)
    with pytest.raises(ValueError, match=r'step h=-0\.1'):
        solve_abm_fft(rhs, 0.5, -0.1, X4, 10)
    with pytest.raises(ValueError, match='n_steps'):
        solve_abm_fft(rhs, 0.5, 0.1, X4, -3)
    with pytest.raises(ValueError, match='rows'):
        solve_abm_fft(rhs, 0.5, 0.1, X4, 10, u=np.zeros((5, 1)))
