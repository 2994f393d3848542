"""Continuation of the vehicle's orbits checked against second methods: Matignon's alpha_c,
long simulations, shooting against harmonic balance, and the harmonic count."""

import numpy as np
import pytest

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.continuation.harmonic import hopf_point, initial_guess
from fohssv_sim.continuation.run import start_orbit
from fohssv_sim.continuation.shooting import Field, ShootingProblem
from fohssv_sim.continuation.vehicle import VehicleSystem
from fohssv_sim.params import ModelParameters, ParameterError
from fohssv_sim.simulate import simulate


@pytest.mark.parametrize('speed', [75.0, 80.0, 84.5])
def test_fom_hopf_point_is_on_the_matignon_boundary(speed):
    """Harmonic balance's amplitude -> 0 limit (a nonlinear solve in the frequency domain)
    against alpha_c = min |arg lambda| / (pi/2) of the equilibrium's Jacobian (eigenvalues),
    from a guess 0.02 away."""
    system = VehicleSystem(ModelParameters(speed=speed), StateFeedback(), 'fractional_order')
    eq = system.equilibrium(0.85)
    prob = system.harmonic_balance(4)
    guess = initial_guess(prob, eq.state, eq.jacobian, eq.critical_order + 0.02, 1e-3)
    p_h, *_ = hopf_point(prob, guess, eq.critical_order + 0.02, 1e-3)
    assert abs(p_h - eq.critical_order) < 1e-3
    assert abs(p_h - eq.critical_order) < 1e-6      # what it achieves


def crossings(t, w, level):
    up = np.where((w[:-1] < level) & (w[1:] >= level))[0]
    frac = (level - w[up]) / (w[up + 1] - w[up])
    return t[up] + frac * (t[up + 1] - t[up])


def test_delay_free_orbit_by_shooting_equals_a_long_simulation():
    """Shooting (compiled RK4 split at contact) against RK4 at the model's step over 1.5 s:
    period to 1e-4, amplitude to 1e-3; the trivial multiplier 1 to 1e-6."""
    params = ModelParameters(model='delay-free', speed=75.0)
    system = VehicleSystem(params, StateFeedback(), 'speed')
    prob = ShootingProblem(system.field(), rtol=1e-10)
    u = start_orbit(system, 75.0, settle=0.5, window=0.2)
    from fohssv_sim.continuation.driver import newton

    u, _ = newton(lambda v: prob.residual(v, 75.0), lambda v: prob.jacobian(v, 75.0)[:, :-1],
                  u, 1e-10, 8)
    mu = prob.multipliers(u, 75.0)
    assert abs(mu[0] - 1.0) < 1e-6
    assert np.all(np.abs(mu[1:]) < 1.0)                       # a stable orbit
    # the compiled RK4 (1000 steps, split at contact) against DOP853 (rtol 1e-9, its error a
    # hundredth of the bounds below) restarted at contact: the same orbit and multipliers
    dop = ShootingProblem(system.field(compiled=False), rtol=1e-9)
    assert np.max(np.abs(dop.residual(u, 75.0))) < 1e-7
    assert np.max(np.abs(np.sort(np.abs(dop.multipliers(u, 75.0))) - np.sort(np.abs(mu)))) \
        < 1e-6
    orbit = prob.samples(u, 75.0, 2000)
    amp = 0.5 * (orbit[:, 1].max() - orbit[:, 1].min())

    r = simulate(params, StateFeedback(), 1.5, sample_every=4)
    keep = r.t > 0.7
    t, w = r.t[keep], r.state[keep, 1]
    period = np.mean(np.diff(crossings(t, w, w.mean())))
    assert u[-1] == pytest.approx(period, rel=1e-4)
    assert amp == pytest.approx(0.5 * (w.max() - w.min()), rel=1e-3)


def test_fom_at_order_one_harmonic_balance_equals_shooting():
    """At alpha = 1 the FOM is an ODE: harmonic balance (frequency domain, 16 and 32
    harmonics) against shooting (time domain) on the same smooth closed loop, at V = 75 m/s:
    the frequency to 1e-4 at 32 harmonics, the error falling by more than 4 as H doubles."""
    from fohssv_sim.planing import planing_smooth

    system = VehicleSystem(ModelParameters(speed=75.0), StateFeedback(), 'fractional_order')

    def f(x, p):
        return system.rhs(x[:, None], p)[:, 0]

    # Newton's Jacobian in the matrix form of eq. 17, df/dx = A + B K' + D Fp'(w) e_w (K'
    # the gain rows of the unclamped inputs, Fp' by central differences), as the vehicle's
    # own field forms it: the variational equations call it at every stage (differencing
    # f itself there cost 2.5 s); the orbit is the root of f's flow map either way
    _, c = system.at(1.0)
    _, K, k0 = system.law(1.0)

    def dfdx(x, p):
        free = np.abs(K @ x + k0) < np.asarray(system.limits)
        w = float(x[1])
        d = 1e-7 * max(1.0, abs(w))
        slope = (planing_smooth(w + d, c.kernel) - planing_smooth(w - d, c.kernel)) / (2 * d)
        J = c.A + c.B @ (free[:, None] * K)
        J[:, 1] += c.D * slope
        return J

    shoot = ShootingProblem(Field(f, 4, dfdx=dfdx), rtol=1e-10)
    # the delay-free simulation is a start near the smooth model's orbit (k = 300 s/m)
    df = VehicleSystem(ModelParameters(model='delay-free', speed=75.0), StateFeedback(),
                       'speed')
    u0 = start_orbit(df, 75.0, settle=0.5, window=0.2)
    from fohssv_sim.continuation.driver import newton

    u, _ = newton(lambda v: shoot.residual(v, 1.0), lambda v: shoot.jacobian(v, 1.0)[:, :-1],
                  u0, 1e-10, 10)
    T = u[-1]
    orbit = shoot.samples(u, 1.0, 512).T                      # (4, 512) over one period
    prob = system.harmonic_balance(8)
    coef = np.fft.rfft(orbit, axis=1)[:, :9] / 512
    c = np.zeros((4, 17))
    c[:, 0] = coef[:, 0].real
    c[:, 1::2] = 2 * coef[:, 1:].real
    c[:, 2::2] = -2 * coef[:, 1:].imag
    # rotate the phase so that w's b_1 = 0
    phi = np.arctan2(c[1, 2], c[1, 1])
    k = np.arange(1, 9)
    a, b = c[:, 1::2].copy(), c[:, 2::2].copy()
    c[:, 1::2] = a * np.cos(k * phi) + b * np.sin(k * phi)
    c[:, 2::2] = b * np.cos(k * phi) - a * np.sin(k * phi)
    u = prob.pack(c, 2 * np.pi / T)
    errors = []
    for H in (16, 32):
        prob_h = system.harmonic_balance(H)
        u = prob.resized(u, H)
        u, _ = newton(lambda v, q=prob_h: q.residual(v, 1.0),
                      lambda v, q=prob_h: q.jacobian(v, 1.0)[:, :-1], u, 1e-9, 20)
        errors.append(abs(prob_h.frequency_hz(u) * T - 1.0))
        prob = prob_h
    assert errors[-1] < 1e-4
    # the frequency converges as the harmonic count doubles (observed: 4e-4 at 16, 7e-5 at
    # 32, 5e-6 at 64: faster than H^-2 once the tanh contact is resolved)
    assert errors[1] < errors[0] / 4


def test_a_parameter_that_is_not_numeric_is_refused():
    with pytest.raises(ParameterError, match="'model' is not a numeric model parameter"):
        VehicleSystem(ModelParameters(), StateFeedback(), 'model')


def test_delay_free_field_equals_the_models_closed_loop_and_its_jacobian():
    """The field's matrix form and Jacobian against the model's own closed-loop right-hand
    side (equilibria.closed_loop_rhs) and its central differences, in and out of contact."""
    from fohssv_sim.equilibria import closed_loop_rhs, jacobian

    params = ModelParameters(model='delay-free', speed=84.5)
    field = VehicleSystem(params, StateFeedback(), 'speed').field()
    ref = closed_loop_rhs(params, StateFeedback())
    for x in ([0.04, 1.0, 0.02, 0.3], [0.05, 2.3, 0.021, -1.0], [0.0, -2.5, -0.01, 2.0]):
        x = np.array(x)
        assert np.allclose(field.f(x, 84.5), ref(x), rtol=1e-13, atol=1e-12)
        assert np.allclose(field.dfdx(x, 84.5), jacobian(ref, x), rtol=1e-6, atol=1e-6)


def test_an_interrupted_branch_resumes_from_its_checkpoint(tmp_path):
    """Stopped after three points, the branch carries on from branch.json and ends on the
    same orbit at the end of the range as a run without interruption."""
    from fohssv_sim.continuation.branch import load_branch
    from fohssv_sim.continuation.run import follow_orbits

    params = ModelParameters(speed=84.5)
    args = (params, StateFeedback(), 'fractional_order', 0.74, 0.77)
    whole = follow_orbits(*args, points=4, harmonics=8)

    def stop(text):
        if text.startswith('point 4:'):
            raise KeyboardInterrupt

    path = tmp_path / 'branch.json'
    with pytest.raises(KeyboardInterrupt):
        follow_orbits(*args, points=4, harmonics=8, checkpoint=path, progress=stop)
    part = load_branch(path)
    assert not part.complete and len(part.points) == 3
    done = follow_orbits(*args, points=4, harmonics=8, checkpoint=path, resume=part)
    assert done.complete and load_branch(path).complete
    assert [b['kind'] for b in done.bifurcations] == [b['kind'] for b in whole.bifurcations]
    assert done.points[-1]['value'] == whole.points[-1]['value'] == 0.77
    assert done.points[-1]['frequency_hz'] == pytest.approx(whole.points[-1]['frequency_hz'],
                                                            rel=1e-8)
    # stability by simulation reaches the points computed before the interruption too
    assert all(q['stable'] is not None for q in done.points)
    assert done.points[-1]['stable'] == whole.points[-1]['stable']


def test_delayed_orbit_by_harmonic_balance_equals_a_long_simulation():
    """The delayed model (tau = L/V) at V = 75 m/s: harmonic balance of the DDE with 64
    harmonics against RK4 by the method of steps over 2.5 s, period to 1e-4 and amplitude
    to 1e-3 (observed: 4e-5 and 5e-5)."""
    from fohssv_sim.continuation.driver import newton
    from fohssv_sim.continuation.run import _guess_from_simulation

    params = ModelParameters(model='delayed', speed=75.0)
    system = VehicleSystem(params, StateFeedback(), 'speed')
    prob = system.harmonic_balance_delayed(64)
    u = _guess_from_simulation(system, prob, 75.0)
    u, _ = newton(lambda v: prob.residual(v, 75.0), lambda v: prob.jacobian(v, 75.0)[:, :-1],
                  u, 1e-9, 30)
    x = prob.signal(u, 4096)

    r = simulate(params, StateFeedback(), 2.5, sample_every=2)
    keep = r.t > 1.5
    t, w = r.t[keep], r.state[keep, 1]
    period = np.mean(np.diff(crossings(t, w, w.mean())))
    assert 1.0 / prob.frequency_hz(u) == pytest.approx(period, rel=1e-4)
    assert 0.5 * (x[1].max() - x[1].min()) == pytest.approx(0.5 * (w.max() - w.min()),
                                                             rel=1e-3)
    # stability from the discretised monodromy operator: the orbit the simulation settles on
    # is stable; the trivial multiplier 1 is met to ~1e-3 (observed 1e-4 to 8e-3 over 200
    # to 2048 steps: the Fourier orbit's error at the contact kinks, not the grid's) and the
    # leading nontrivial one (0.43) agrees between 256 and 1024 steps to 1e-2
    mu = prob.multipliers(u, 75.0, 256)
    fine = prob.multipliers(u, 75.0, 1024)
    assert abs(mu[0] - 1.0) < 1e-2 and abs(fine[0] - 1.0) < 1e-2
    assert np.max(np.abs(mu[1:])) < 0.6
    assert abs(abs(mu[1]) - abs(fine[1])) < 1e-2


def test_fom_orbit_by_harmonic_balance_equals_a_long_caputo_simulation():
    """alpha = 0.85, V = 75 m/s: the branch's orbit (32 harmonics) against the Caputo model
    simulated from rest (SOE solver, its default step) over 1.5 s, the last 0.3 s measured.
    Period to 1e-4 (observed 3e-5). Amplitude to 2e-3 (observed 1.1e-3): a Caputo solution
    approaches the periodic one algebraically, and the simulated amplitude still falls
    between 0.9-1.2 s and 1.2-1.5 s."""
    from fohssv_sim.continuation.run import follow_orbits

    params = ModelParameters(speed=75.0)
    b = follow_orbits(params, StateFeedback(), 'fractional_order', 0.7, 0.85, points=6,
                      harmonics=32)
    orbit = b.points[-1]
    assert orbit['value'] == 0.85
    r = simulate(params.replace(fractional_order=0.85), StateFeedback(), 1.5)
    keep = r.t > 1.2
    t, w = r.t[keep], r.state[keep, 1]
    period = np.mean(np.diff(crossings(t, w, w.mean())))
    assert orbit['period_s'] == pytest.approx(period, rel=1e-4)
    assert orbit['w_amplitude'] == pytest.approx(0.5 * (w.max() - w.min()), rel=2e-3)


def test_fom_fold_found_by_continuation_is_confirmed_by_simulations_on_either_side():
    """V = 75 m/s: the branch (16 harmonics) leaves the Hopf point backwards (subcritical) and
    turns at a fold. Simulations of the Caputo model (SOE solver), independent of harmonic
    balance: between fold and Hopf, a run started near the large orbit (the state a run at
    alpha = 0.76 reaches, where it is the only attractor) stays on it, at the branch's stable
    amplitude there, and one started near the equilibrium decays; 0.002 below the fold the
    same large-orbit start decays too. (At the solver's default step the simulated fold lies
    5e-4 to 1e-3 below the harmonic-balance one, at half the step within 4e-4 of it: the
    solver's step error.)"""
    from fohssv_sim.continuation.run import follow_orbits
    from fohssv_sim.params import ModelParameters

    params = ModelParameters(model='fractional', speed=75.0)
    b = follow_orbits(params, StateFeedback(), 'fractional_order', 0.72, 0.74, points=20,
                      harmonics=16)
    kinds = {x['kind']: x['value'] for x in b.bifurcations}
    hopf, fold = kinds['hopf'], kinds['fold']
    assert fold < hopf                                        # subcritical: the branch turns
    between = 0.5 * (fold + hopf)
    after_fold = [q for q in b.points if q['stable']]
    big = min(after_fold, key=lambda q: abs(q['value'] - between))['w_amplitude']

    def amplitude(alpha, x0, duration=2.0):
        r = simulate(params.replace(fractional_order=alpha), StateFeedback(), duration,
                     sample_every=10, initial_state=x0)
        w = r.state[r.t > duration - 0.5, 1]
        return 0.5 * (w.max() - w.min())

    x_big = simulate(params.replace(fractional_order=0.76), StateFeedback(), 2.0,
                     sample_every=10).state[-1].tolist()
    eq = VehicleSystem(params, StateFeedback(), 'fractional_order').equilibrium(between)
    x_eq = (np.asarray(eq.state) + [0.0, 0.01, 0.0, 0.0]).tolist()
    assert amplitude(between, x_big) == pytest.approx(big, rel=0.1)   # stays on the orbit
    assert amplitude(between, x_eq) < 0.1 * big                        # decays
    assert amplitude(fold - 0.002, x_big) < 1e-3 * big                 # beyond: decays


def test_delay_free_torus_over_a_gain_is_confirmed_by_simulations_on_either_side():
    """Delay-free, V = 75 m/s, over the pitch-rate gain: a complex pair of Floquet multipliers
    leaves the unit circle (torus, near -0.2001). Simulations (the model's RK4) from the orbit
    with w kicked by 0.1 %: 0.005 before the torus point the kick decays (per-cycle maximum
    of w back within 1e-3 of the orbit's, observed 1e-4 after 2.5 s); 0.005 after it grows
    into a modulation of w's maxima over 1e-2 (observed 0.14)."""
    from fohssv_sim.continuation.driver import newton
    from fohssv_sim.continuation.run import follow_orbits

    params = ModelParameters(model='delay-free', speed=75.0)
    b = follow_orbits(params, StateFeedback(), 'pitch_rate_gain', -0.25, -0.15, points=20)
    (torus,) = [x['value'] for x in b.bifurcations if x['kind'] == 'torus']
    assert -0.21 < torus < -0.19
    system = VehicleSystem(params, StateFeedback(), 'pitch_rate_gain')
    prob = ShootingProblem(system.field(), extremum_of=1)
    u = start_orbit(system, -0.22)
    spread = {}
    for g in (torus - 0.005, torus + 0.005):
        u, _ = newton(lambda v, g=g: prob.residual(v, g),
                      lambda v, g=g: prob.jacobian(v, g)[:, :-1], u, 1e-10, 12)
        x0 = u[:4] * np.array([1.0, 1.001, 1.0, 1.0])
        r = simulate(params, StateFeedback(pitch_rate_gain=g), 3.0, initial_state=x0.tolist())
        w, t = r.state[:, 1], r.t
        level = prob.samples(u, g, 200)[:, 1].mean()
        up = np.where((w[:-1] < level) & (w[1:] >= level))[0]
        tops = np.array([w[i:j].max() for i, j in zip(up, up[1:])])
        spread[g] = np.max(np.abs(tops[t[up[:-1]] > 2.5] - u[1]))
    before, after = spread[torus - 0.005], spread[torus + 0.005]
    assert before < 1e-3 and after > 1e-2


@pytest.mark.parametrize('form', ['paper', 'geometric'])
def test_compiled_delayed_planing_equals_the_interpreted_physics(form):
    """The delayed model's planing force as harmonic balance evaluates it (compiled loop)
    equals physics.planing_delayed run interpreted, in and out of contact."""
    from fohssv_sim.physics import planing_delayed

    system = VehicleSystem(ModelParameters(model='delayed', immersion_form=form),
                           StateFeedback(), 'speed')
    rng = np.random.default_rng(1)
    X = rng.normal(0.0, [[0.05], [1.7], [0.03], [0.2]], (4, 400))
    Xd = X + rng.normal(0.0, 0.02, (4, 400))
    _, c = system.at(75.0)
    ref = np.array([planing_delayed(x[0], x[2], xd[0], xd[1], xd[2], c.kernel, form)
                    for x, xd in zip(X.T, Xd.T)])
    zero = np.zeros((4, 400))
    got = system.delayed_rhs(X, 75.0, Xd) - system.delayed_rhs(X, 75.0, X + zero)
    want = np.outer(c.D, ref - np.array([planing_delayed(x[0], x[2], x[0], x[1], x[2],
                                                         c.kernel, form) for x in X.T]))
    assert 0 < np.count_nonzero(ref) < ref.size
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)


def test_delayed_branch_carries_multipliers_and_stability():
    """follow_orbits on the delayed model: every point gets its monodromy multipliers (the
    trivial one first, within 5e-2 of 1 with 16 harmonics: the Fourier orbit's error at the
    contact kinks, observed up to 3.2e-2) and stable = all others inside the unit circle;
    the simulated orbit it starts from is stable, so the first point must be."""
    from fohssv_sim.continuation.run import follow_orbits

    b = follow_orbits(ModelParameters(model='delayed'), StateFeedback(), 'speed', 75.0, 80.0,
                      points=3, harmonics=16)
    assert b.points[0]['stable'] is True
    for q in b.points:
        mu = np.array([complex(*m) for m in q['multipliers']])
        assert abs(mu[0] - 1.0) < 5e-2
        assert q['stable'] == bool(np.max(np.abs(mu[1:])) < 1.0)
