"""Continuation on textbook cases with closed-form answers (fohssv_sim.continuation)."""

import math

import numpy as np
import pytest

from fohssv_sim.continuation.driver import ContinuationError, Settings, continue_branch
from fohssv_sim.continuation.harmonic import HarmonicBalance, converge_harmonics, hopf_point
from fohssv_sim.continuation.shooting import Field, ShootingProblem


class Circle:
    """u^2 + p^2 = 1: folds at p = +-1, which natural continuation in p cannot pass."""

    def residual(self, u, p):
        return np.array([u[0] ** 2 + p ** 2 - 1.0])


def test_pseudo_arclength_passes_a_fold_and_locates_it():
    pts, bifs = continue_branch(Circle(), (np.array([-1.0]), 0.0), 2.0,
                                settings=Settings(ds=0.1, ds_max=0.2, max_points=40),
                                limit=-0.5)
    folds = [b for b in bifs if b.kind == 'fold']
    assert folds and abs(folds[0].value - 1.0) < 2e-3      # the parabola's vertex, p = 1
    assert pts[-1].u[0] > 0.0       # went round the fold onto the other half of the circle
    for pt in pts:
        assert abs(pt.u[0] ** 2 + pt.p ** 2 - 1.0) < 1e-9


def test_start_far_from_a_solution_is_refused():
    with pytest.raises(ContinuationError, match='not near a solution'):
        continue_branch(Circle(), (np.array([5.0]), 3.0), 2.0,
                        settings=Settings(max_iter=3))


def hopf_normal_form(x, mu):
    r2 = x[0] ** 2 + x[1] ** 2
    return np.array([mu * x[0] - x[1] - x[0] * r2, x[0] + mu * x[1] - x[1] * r2])


def test_hopf_normal_form_by_shooting():
    """Orbits r = sqrt(mu), T = 2 pi; multipliers 1 and exp(-4 pi mu) (radial exponent
    -2 mu): all from the normal form's polar equations r' = mu r - r^3, phi' = 1."""
    prob = ShootingProblem(Field(hopf_normal_form, 2), rtol=1e-10)
    pts, bifs = continue_branch(prob, (np.array([1.0, 0.05, 6.0]), 1.0), 0.1,
                                settings=Settings(ds=0.3, ds_max=0.5))
    assert pts[-1].p == 0.1 and len(pts) >= 3
    for pt in pts:
        assert math.hypot(*pt.u[:2]) == pytest.approx(math.sqrt(pt.p), rel=1e-8)
        assert pt.u[-1] == pytest.approx(2.0 * math.pi, rel=1e-8)
    mu = prob.multipliers(pts[-1].u, pts[-1].p)
    assert abs(mu[0] - 1.0) < 1e-6
    assert mu[1].real == pytest.approx(math.exp(-4.0 * math.pi * 0.1), rel=1e-6)
    assert not [b for b in bifs if b.kind != 'fold']


def fractional_hopf(alpha):
    """D^alpha z = (p + i - |z|^2) z, z = x + i y: harmonic balance with one harmonic is
    exact (|z|^2 z stays on e^{i w t}); z = r e^{i w t} needs (i w)^alpha = p - r^2 + i, so
    w = (1 / sin(alpha pi/2))^(1/alpha) and r^2 = p - cot(alpha pi/2); at alpha = 1 the
    classical normal form."""
    def rhs(X, p):
        x, y = X
        r2 = x * x + y * y
        return np.array([p * x - y - x * r2, x + p * y - y * r2])
    return HarmonicBalance(rhs, 2, 3, lambda p: alpha)


@pytest.mark.parametrize('alpha', [0.6, 0.85, 1.0])
def test_fractional_hopf_normal_form_by_harmonic_balance(alpha):
    prob = fractional_hopf(alpha)
    p_c = 1.0 / math.tan(alpha * math.pi / 2.0)
    omega = (1.0 / math.sin(alpha * math.pi / 2.0)) ** (1.0 / alpha)
    c = np.zeros((2, 7))
    c[0, 1] = c[1, 2] = 0.1
    guess = prob.pack(c, 1.2 * omega)                    # 20 % off in frequency
    p_h, u1, p1, u2, p2 = hopf_point(prob, guess, p_c + 0.05, 1e-3)
    assert p_h == pytest.approx(p_c, abs=1e-9)
    assert u1[-1] == pytest.approx(omega, rel=1e-9)
    pts, _ = continue_branch(prob, (u2, p2), p_c + 1.0, direction=np.append(u2 - u1, p2 - p1),
                             settings=Settings(ds=0.05, ds_max=0.3))
    assert pts[-1].p == pytest.approx(p_c + 1.0)
    for pt in pts:
        assert prob.amplitude(pt.u) == pytest.approx(math.sqrt(pt.p - p_c), rel=1e-7)
        assert pt.u[-1] == pytest.approx(omega, rel=1e-9)


def test_harmonic_count_stops_when_the_frequency_settles():
    """Exact with one harmonic: the frequency does not move from H = 2 to 4."""
    prob = fractional_hopf(0.8)
    omega = (1.0 / math.sin(0.4 * math.pi)) ** 1.25
    c = np.zeros((2, 7))
    c[0, 1] = c[1, 2] = 0.5
    got, u, history = converge_harmonics(prob, prob.pack(c, omega), 1.0, start=2)
    assert [h for h, _ in history] == [2, 4]
    assert history[-1][1] == pytest.approx(omega / (2 * math.pi), rel=1e-10)


def test_grazing_of_a_switching_surface_is_found_where_the_orbit_touches_it():
    """The normal form's circle of radius sqrt(mu) touches the line x = 0.5 at mu = 0.25."""
    field = Field(hopf_normal_form, 2, switches=lambda x, mu: (x[0] - 0.5,))
    prob = ShootingProblem(field, rtol=1e-9)
    _, bifs = continue_branch(prob, (np.array([0.6, 0.0, 2 * math.pi]), 0.36), 0.16,
                              settings=Settings(ds=0.05, ds_max=0.1))
    (graze,) = [b for b in bifs if b.kind.startswith('grazing')]
    assert graze.value == pytest.approx(0.25, abs=5e-3)


def hutchinson(harmonics=6):
    """Delayed logistic equation x' = r x(t) (1 - x(t - 1)) (tau = 1, p = r): about x = 1
    the linearisation y' = -r y(t - 1) has lambda = i omega where omega tau = pi/2 and
    omega = r, so the Hopf point is r tau = pi/2 with period 4 tau."""
    def rhs(X, r, Xd):
        return r * X * (1.0 - Xd)
    return HarmonicBalance(rhs, 1, harmonics, lambda r: 1.0, delay=lambda r: 1.0)


def test_delayed_logistic_hopf_point_by_harmonic_balance():
    prob = hutchinson()
    c = np.zeros((1, 13))
    c[0, 0] = 1.0
    c[0, 1] = 0.01
    p_h, u1, *_ = hopf_point(prob, prob.pack(c, 1.3), 1.8, 1e-3)     # r, omega 15 % off
    assert p_h == pytest.approx(math.pi / 2, abs=1e-8)
    assert u1[-1] == pytest.approx(math.pi / 2, rel=1e-5)


def test_delayed_harmonic_balance_jacobian_matches_differences():
    from fohssv_sim.continuation.driver import fd_jacobian

    prob = hutchinson(4)
    rng = np.random.default_rng(3)
    u = np.append(np.concatenate([[1.0], 0.2 * rng.standard_normal(7)]), 1.4)
    J = prob.jacobian(u, 1.9)
    F = fd_jacobian(lambda y: prob.residual(y[:-1], y[-1]), np.append(u, 1.9))
    assert np.allclose(J, F, rtol=1e-6, atol=1e-6)


def test_dde_monodromy_of_a_constant_delay_equation_has_the_lambert_w_multipliers():
    """y' = -a y(t - tau) over any T: the Floquet multipliers are exp(lambda T) with lambda the
    characteristic roots lambda = -a e^{-lambda tau}, lambda_k = W_k(-a tau) / tau (Lambert
    W). The discretised monodromy operator's two leading multipliers converge to them with
    RK4's fourth order (observed errors 3e-6, 1e-7, 1e-8, 7e-10 at 20-160 steps)."""
    from scipy.special import lambertw

    from fohssv_sim.continuation.monodromy import dde_monodromy

    a, tau, T = 1.0, 1.0, 1.7
    exact = np.exp(lambertw(-a * tau, 0) / tau * T)            # and its conjugate (k = -1)

    def coefficients(t):
        return np.zeros((t.size, 1, 1)), np.full((t.size, 1, 1), -a)

    errors = []
    for steps in (20, 40, 80, 160):
        mu = np.linalg.eigvals(dde_monodromy(coefficients, 1, T, tau, steps))
        lead = mu[np.argsort(-np.abs(mu))][:2]
        errors.append(np.max(np.abs(np.sort_complex(lead) -
                                    np.sort_complex(np.array([exact, exact.conjugate()])))))
    assert errors[-1] < 1e-8
    order = np.log2(errors[0] / errors[-1]) / 3
    assert order > 3.5


def test_delayed_logistic_orbit_has_the_trivial_multiplier_1():
    """The Hutchinson orbit at r = 1.75 (past its Hopf point r = pi/2, amplitude 0.9), by
    harmonic balance with 24 harmonics (smooth: exact to round-off): the discretised
    monodromy operator's multiplier nearest 1 converges to 1 (observed 5e-5, 6e-7, 2e-7,
    1e-8 at 32-256 steps), the orbit is stable, and the leading nontrivial multiplier (0.466)
    agrees between 128 and 256 steps to 1e-6."""
    prob = hutchinson(24)
    c = np.zeros((1, 49))
    c[0, 0], c[0, 1] = 1.0, 0.01
    p_h, u1, p1, u2, p2 = hopf_point(prob, prob.pack(c, 1.3), 1.8, 1e-3)
    pts, _ = continue_branch(prob, (u2, p2), 1.75, direction=np.append(u2 - u1, p2 - p1),
                             settings=Settings(ds=0.05, ds_max=0.2))
    u = pts[-1].u
    assert pts[-1].p == 1.75 and prob.amplitude(u) > 0.5
    coarse, fine = prob.multipliers(u, 1.75, 128), prob.multipliers(u, 1.75, 256)
    assert abs(fine[0] - 1.0) < 1e-7
    assert abs(coarse[0] - 1.0) > abs(fine[0] - 1.0)
    assert np.max(np.abs(fine[1:])) < 1.0
    assert abs(abs(coarse[1]) - abs(fine[1])) < 1e-6
