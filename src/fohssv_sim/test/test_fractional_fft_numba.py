"""solve_abm_fft's compiled engine (numba rhs) returns the ABMStepper numbers (to 1e-12).

The reference is the direct ABM stepper with the interpreted right-hand side of
test_fractional_fft.py; the compiled rhs below is the same function (t-dependent, with an
input that changes every step), so a wrong time, input row, weight or history index in the
compiled loop shows up as a difference.
"""

import math

import numpy as np
import pytest

from fohssv_sim.fractional import solve_abm_fft

from linear4 import A4, B4, X4
from test_fractional_fft import direct, rel_err, rhs

numba = pytest.importorskip('numba')
B4_COL = B4[:, 0].copy()


@numba.njit
def rhs_jit(t, x, u):
    return A4 @ x + B4_COL * u[0] + 0.2 * np.sin(x) + 0.1 * np.sin(3.0 * t)


@numba.njit
def blow_up_after_20_jit(t, x, u):
    return -x if t <= 20.0 else 1e200 * x * x


@numba.njit
def wrong_shape_midway_jit(t, x, u):
    return x[:1] if 0.25 < t < 0.35 else -x


def test_compiled_and_interpreted_rhs_are_the_same_function():
    x, u = np.array([0.3, -1.0, 2.0, 0.5]), np.array([0.7])
    for t in (0.0, 0.4, 2.5):
        np.testing.assert_allclose(rhs_jit(t, x, u), rhs(t, x, u), rtol=1e-14)


@pytest.mark.parametrize('N', [1, 127, 128, 129, 300, 5000])
@pytest.mark.parametrize('alpha', [0.4, 0.85, 1.0])
def test_compiled_equals_direct(alpha, N):
    h = 2.0 / max(N, 10)
    U = np.sin(50.0 * h * np.arange(N))[:, None]       # changes every step
    ref, fref = direct(alpha, h, N, u_seq=U)
    sol = solve_abm_fft(rhs_jit, alpha, h, X4, N, u=U, engine='numba')
    assert rel_err(sol.x, ref) < 1e-12
    assert rel_err(sol.f[:N], fref) < 1e-12


def test_compiled_constant_input_and_t0():
    from fohssv_sim.fractional import ABMStepper

    alpha, h, N = 0.85, 1e-3, 3000
    st = ABMStepper(rhs, alpha, h, X4, t0=1.5)
    ref = np.array([X4] + [st.step(np.array([0.1])) for _ in range(N)])
    sol = solve_abm_fft(rhs_jit, alpha, h, X4, N, u=np.array([0.1]), t0=1.5, engine='numba')
    assert rel_err(sol.x, ref) < 1e-12
    # auto picks the compiled engine for a numba rhs and an array input: the same numbers
    auto = solve_abm_fft(rhs_jit, alpha, h, X4, N, u=np.array([0.1]), t0=1.5)
    np.testing.assert_array_equal(auto.x, sol.x)


def test_compiled_nonfinite_midway_raises_at_the_same_step_as_interpreted():
    def blow_up(t, x, u):
        return -x if t <= 20.0 else 1e200 * x * x

    msgs = []
    with np.errstate(all='ignore'):
        for f, engine in ((blow_up, 'python'), (blow_up_after_20_jit, 'numba')):
            with pytest.raises(FloatingPointError, match=r'non-finite state at t=') as exc:
                solve_abm_fft(f, 0.8, 0.1, [1.0], 400, engine=engine)
            msgs.append(str(exc.value))
    step = int(msgs[1].split('(step ')[1].split(',')[0])
    assert 200 < step < 400                   # past the first compiled block of 128 steps
    assert f't={0.1 * step!r} s (step {step},' in msgs[1]
    assert msgs[0] == msgs[1]


def test_compiled_wrong_shape_midway_raises():
    msg = r'rhs returned shape \(1,\) at t=0\.26 s \(step 26\), expected \(2,\)'
    with pytest.raises(ValueError, match=msg):
        solve_abm_fft(wrong_shape_midway_jit, 0.8, 0.01, [1.0, 0.5], 100, engine='numba')


def test_engine_choice():
    def u_fb(t, x):
        return np.array([math.cos(7 * t) - 0.3 * x[0]])

    # auto with a callable input falls back to the interpreted loop and stays exact
    ref, _ = direct(0.7, 0.004, 400, u_call=u_fb)
    assert rel_err(solve_abm_fft(rhs_jit, 0.7, 0.004, X4, 400, u=u_fb).x, ref) < 1e-12
    with pytest.raises(ValueError, match=r"engine='numba' needs rhs compiled with numba\.njit"):
        solve_abm_fft(rhs, 0.5, 0.1, X4, 10, u=np.array([0.0]), engine='numba')
    with pytest.raises(ValueError, match=r"not a callable"):
        solve_abm_fft(rhs_jit, 0.5, 0.1, X4, 10, u=u_fb, engine='numba')
    with pytest.raises(ValueError, match=r"engine='fast' is not one of 'auto', 'python', 'numba'"):
        solve_abm_fft(rhs, 0.5, 0.1, X4, 10, engine='fast')


def test_object_mode_function_is_not_taken_for_compiled():
    obj_rhs = numba.jit(forceobj=True)(rhs)
    with pytest.raises(ValueError, match=r"needs rhs compiled with numba\.njit"):
        solve_abm_fft(obj_rhs, 0.5, 0.1, X4, 10, u=np.array([0.0]), engine='numba')
    ref, _ = direct(0.5, 0.01, 200, u_const=np.array([0.2]))
    assert rel_err(solve_abm_fft(obj_rhs, 0.5, 0.01, X4, 200, u=np.array([0.2])).x, ref) < 1e-12
