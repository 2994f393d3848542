"""Equilibria and Matignon stability against independent computations."""

import math

import mpmath
import numpy as np
import pytest
from scipy.optimize import brentq

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.coefficients import coefficients
from fohssv_sim.equilibria import critical_order, find_equilibria, matignon_stable
from fohssv_sim.params import ModelParameters
from fohssv_sim.planing import planing_exact

KZ, KTH, KQ = 15.0, -30.0, -0.3   # eq. 31


def reduced_equilibrium(speed):
    """Eq. 31 closed loop at rest: q = 0, theta = w/V; eliminating delta_c between the w and q
    rows leaves one scalar equation in w, solved by bracketing (a second, independent method).
    """
    c = coefficients(ModelParameters(speed=speed, planing_form='exact'))

    def g(w):
        return (c.g + w * (c.a22 - c.b22 * c.a42 / c.b42)
                + planing_exact(w, c) * (c.d2 - c.b22 * c.d4 / c.b42))

    wc = c.contact_velocity
    w = brentq(g, wc * (1 + 1e-12), 3 * wc, xtol=1e-15)
    fp = planing_exact(w, c)
    dc = -(c.a42 * w + c.d4 * fp) / c.b42
    theta = w / c.V
    z = (dc - KTH * theta) / KZ
    return c, np.array([z, w, theta, 0.0])


def analytic_jacobian(c, x):
    """J = A + B K + D dFp/dw e_w^T, with dFp/dw from a 30-digit derivative of eq. 10."""
    K = np.array([[0, 0, 0, 0], [KZ, 0, KTH, KQ]], dtype=float)
    mpmath.mp.dps = 30
    rp, V, L, R, rcd = map(mpmath.mpf, (c.R_prime, c.V, c.L, c.R, c.Rc_dot))

    def fp(w):
        h = L * w / (R * V) - rp
        return -V**2 * (1 - (rp / (h + rp))**2) * (1 + h) / (1 + 2 * h) * (w - rcd) / V

    dfp = float(mpmath.diff(fp, mpmath.mpf(x[1])))
    J = c.A + c.B @ K
    J[:, 1] += c.D * dfp
    return J


@pytest.mark.parametrize('speed', [75.0, 84.5, 90.0])
def test_equilibrium_matches_reduced_scalar_equation(speed):
    c, expected = reduced_equilibrium(speed)
    found = find_equilibria(ModelParameters(speed=speed, planing_form='exact'), StateFeedback())
    assert len(found) == 1
    assert np.allclose(found[0].state, expected, rtol=1e-9, atol=1e-12)


def test_equilibrium_at_84_5_is_near_the_papers_quoted_point():
    # the paper quotes (0.04, 1.803, 0.02, 0.001) at V = 84.5 (Fig. 7); docs/model.md §9.1: L = 1.8
    # puts the model's equilibrium within rounding of the depth and pitch, w within 4 %.
    e = find_equilibria(ModelParameters(speed=84.5), StateFeedback())[0]
    assert round(e.state[0], 2) == 0.04 and round(e.state[2], 2) == 0.02
    assert e.state[1] == pytest.approx(1.803, rel=0.04)


@pytest.mark.parametrize('speed', [75.0, 84.5])
def test_critical_order_from_the_eigenvalue_formula(speed):
    c, x = reduced_equilibrium(speed)
    lam = np.linalg.eigvals(analytic_jacobian(c, x))
    expected = min(abs(math.atan2(v.imag, v.real)) for v in lam) / (math.pi / 2)
    e = find_equilibria(ModelParameters(speed=speed, planing_form='exact'), StateFeedback())[0]
    assert e.critical_order == pytest.approx(expected, abs=1e-6)
    assert np.allclose(np.sort_complex(e.eigenvalues), np.sort_complex(lam), rtol=1e-5)
    assert e.stable(expected - 0.01) and not e.stable(expected + 0.01)


def test_matignon_wedge():
    lam = [complex(-1, 1), complex(-1, -1)]   # |arg| = 3 pi / 4
    assert critical_order(lam) == pytest.approx(1.5)
    assert matignon_stable(lam, 1.0)
    lam = [complex(1, 1), complex(1, -1)]     # |arg| = pi / 4: stable for alpha < 0.5
    assert matignon_stable(lam, 0.49) and not matignon_stable(lam, 0.51)


def test_open_loop_has_a_zero_eigenvalue_so_no_order_is_stable():
    # docs/model.md §6: open-loop eigenvalues {0, 0, -31.197, 15.546}: unstable for every alpha
    lam = np.linalg.eigvals(coefficients(ModelParameters()).A)
    assert critical_order(lam) == 0.0
    assert not matignon_stable(lam, 0.01)
