"""Planing force: eq. 10 evaluated independently, continuity, limits and the forms' relations."""

import math

import mpmath
import numpy as np
import pytest

from fohssv_sim.coefficients import coefficients
from fohssv_sim.params import ModelParameters
from fohssv_sim.planing import (
    planing_delayed,
    planing_exact,
    planing_exact_array,
    planing_smooth,
    planing_smooth_array,
)

C = coefficients(ModelParameters())


def reference_exact(w):
    """Eq. 10 with eqs. 12-14 written out from docs/model.md §3.3, in 40-digit arithmetic."""
    mpmath.mp.dps = 40
    w = mpmath.mpf(w)
    L, R, V = mpmath.mpf('1.8'), mpmath.mpf('0.0508'), mpmath.mpf(75)
    rp, rcd = mpmath.mpf(C.R_prime), mpmath.mpf(C.Rc_dot)
    hs = L * w / (R * V)
    if hs > rp:
        h, ap = hs - rp, (w - rcd) / V
    elif hs < -rp:
        h, ap = -hs - rp, (w + rcd) / V
    else:
        return 0.0
    return float(-V**2 * (1 - (rp / (h + rp))**2) * (1 + h) / (1 + 2 * h) * ap)


@pytest.mark.parametrize('w', [-4.0, -2.5, -1.7, -1.0, 0.0, 1.0, 1.65, 1.7, 2.0, 3.5])
def test_exact_form_matches_high_precision_evaluation(w):
    assert planing_exact(w, C) == pytest.approx(reference_exact(w), rel=1e-12, abs=1e-12)


def test_force_pushes_the_tail_back_and_vanishes_inside_the_cavity():
    wc = C.contact_velocity
    assert planing_exact(0.99 * wc, C) == 0.0 and planing_exact(-0.99 * wc, C) == 0.0
    assert planing_exact(1.2 * wc, C) < 0.0 < planing_exact(-1.2 * wc, C)  # docs/model.md §9.3


def test_exact_form_is_continuous_at_contact():
    wc = C.contact_velocity
    for sign in (1.0, -1.0):
        assert abs(planing_exact(sign * wc * (1 + 1e-9), C)) < 1e-6


def test_smooth_form_tends_to_exact_as_k_grows():
    sharp = coefficients(ModelParameters(tanh_sharpness=1e6))
    for w in (-3.0, -2.0, -1.0, 0.5, 1.9, 2.5, 3.0):
        assert planing_smooth(w, sharp) == pytest.approx(planing_exact(w, sharp), rel=1e-6,
                                                         abs=1e-9)


def test_smooth_immersion_is_clipped_at_zero():
    # near |w| ~ w0 the tanh form of h dips slightly below 0 (docs/model.md §5.2); clipped,
    # Fp stays finite
    ws = np.linspace(-2 * C.w0, 2 * C.w0, 20001)
    fp = planing_smooth_array(ws, C)
    assert np.all(np.isfinite(fp))
    inside = np.abs(ws) < 0.9 * C.w0
    assert np.max(np.abs(fp[inside])) < 1e-3


def test_array_forms_equal_scalar_forms():
    ws = np.linspace(-4, 4, 801)
    assert np.array_equal(planing_exact_array(ws, C), [planing_exact(w, C) for w in ws])
    assert np.allclose(planing_smooth_array(ws, C), [planing_smooth(w, C) for w in ws],
                       rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize('w', [-3.0, -1.8, 0.3, 1.7, 2.6])
def test_delayed_form_with_no_delay_is_the_exact_form(w):
    theta, z = 0.02, 0.04
    got = planing_delayed(z, theta, z, w, theta, C, 'paper')
    assert got == pytest.approx(planing_exact(w, C), rel=1e-13, abs=1e-13)


def test_geometric_immersion_option():
    # h* = (z - z_tau + L theta)/R: with z = z_tau and theta = w/V it equals L w /(R V)
    w = 2.2
    got = planing_delayed(0.0, w / C.V, 0.0, w, 0.0, C, 'geometric')
    alpha_p = w / C.V + (w - C.Rc_dot) / C.V
    h = C.L * w / (C.R * C.V) - C.R_prime
    rp = C.R_prime
    expected = -C.V**2 * (1 - (rp / (h + rp))**2) * (1 + h) / (1 + 2 * h) * alpha_p
    assert got == pytest.approx(expected, rel=1e-13)
    assert math.isfinite(got)
