"""The compiled stepping kernels against the interpreted reference and an exact solution.

* Same trajectory: every model's closed loop (eq. 31, held over 1e-4 s as through ROS, and
  continuous) run compiled and interpreted agrees to 1e-12 of its range, planing included.
* Independent check of the compiled FOM kernel: in the linear regime (exact planing, no wall
  contact) the FOM is D^a x = A x + b, whose solution is the Mittag-Leffler series
  x(t) = sum_k A^k b t^(a(k+1)) / Gamma(a(k+1) + 1), evaluated here in 40-digit mpmath; the
  compiled run converges to it at the ABM scheme's order.
* Shared state: interpreted and compiled steps can alternate on one plant (they advance the
  same arrays); a non-finite state is reported at the same step by both engines.
* The 'soe' horizon follows the run (``soe_horizon_steps='auto'``).
"""

import math
import warnings

import mpmath
import numpy as np
import pytest

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim import kernels
from fohssv_sim.coefficients import coefficients
from fohssv_sim.models import AffineLaw, make_plant
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate
from fohssv_sim.solvers import SOE_HORIZON_MIN, SOE_HORIZON_OPEN

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason='numba not installed')

MODELS = ('delay-free', 'delayed', 'fractional')
X_START = (0.0, 1.5, 0.0, 0.0)     # w beyond the contact velocity: planing from the start


def run(model, engine, duration, control_period, law=None):
    p = ModelParameters(model=model)
    plant = make_plant(p, X_START, engine=engine, duration=duration)
    ctl = StateFeedback()
    return simulate(plant, law or ctl, duration, control_period=control_period,
                    initial_state=X_START)


def rel_diff(a, b):
    return np.max(np.abs(a.state - b.state)) / np.max(np.abs(b.state))


@pytest.mark.parametrize('model', MODELS)
def test_compiled_equals_interpreted_with_the_command_held(model):
    fast = run(model, 'compiled', 0.1, 1e-4)
    ref = run(model, 'python', 0.1, 1e-4)
    assert np.array_equal(fast.t, ref.t)
    assert np.max(np.abs(ref.planing_force)) > 1.0        # the planing branches were taken
    assert rel_diff(fast, ref) <= 1e-12, rel_diff(fast, ref)
    assert np.max(np.abs(fast.inputs - ref.inputs)) <= 1e-12 * np.max(np.abs(ref.inputs))
    scale = np.max(np.abs(ref.planing_force))
    assert np.max(np.abs(fast.planing_force - ref.planing_force)) <= 1e-12 * scale


@pytest.mark.parametrize('model', MODELS)
def test_compiled_affine_law_equals_the_controller_at_every_stage(model):
    ctl = StateFeedback()
    fast = run(model, 'compiled', 0.1, None)                      # AffineLaw, compiled
    # interpreted, with the controller's own command() called at every stage
    ref = run(model, 'python', 0.1, None, law=lambda t, x: ctl.command(t, x))
    assert np.max(np.abs(ref.planing_force)) > 1.0
    assert rel_diff(fast, ref) <= 1e-12, rel_diff(fast, ref)


def test_affine_law_clamps_like_the_controller():
    ctl = StateFeedback(max_cavitator_deflection=0.01)
    law = AffineLaw.from_controller(ctl)
    for x in ([0.0, 0.0, 0.3, 0.0], [0.0, 0.0, -0.3, 0.0], [0.1, 0.2, 0.001, -0.4]):
        assert law(0.0, x) == ctl.command(0.0, x)
    assert AffineLaw.from_controller(object()) is None


def mittag_leffler_series(A, b, t, alpha, digits=40):
    """sum_k A^k b t^(a(k+1)) / Gamma(a(k+1)+1) in mpmath (x(0) = 0)."""
    with mpmath.workdps(digits):
        A = mpmath.matrix(A.tolist())
        term = mpmath.matrix(b.tolist())
        ta = mpmath.mpf(t) ** alpha
        total = mpmath.matrix(4, 1)
        power = ta
        for k in range(400):
            add = term * (power / mpmath.gamma(alpha * (k + 1) + 1))
            total += add
            if k > 10 and mpmath.norm(add) < mpmath.mpf(10) ** (-digits + 5) * mpmath.norm(total):
                break
            term = A * term
            power *= ta
        return np.array([float(v) for v in total])


def test_compiled_fom_converges_to_the_mittag_leffler_solution():
    alpha, T, u = 0.85, 0.02, (0.002, -0.004)
    errors, steps = [], (4e-4, 2e-4, 1e-4)
    for h in steps:
        p = ModelParameters(fractional_order=alpha, planing_form='exact', step=h)
        c = coefficients(p)
        plant = make_plant(p)
        assert plant.engine == 'compiled'
        plant.advance(u, round(T / h))
        assert abs(plant.state[1]) < 0.5 * c.contact_velocity      # no wall contact: linear
        exact = mittag_leffler_series(c.A, c.B @ np.array(u) + c.G, T, alpha)
        errors.append(np.max(np.abs(plant.state - exact)) / np.max(np.abs(exact)))
    order = np.diff(np.log(errors)) / np.diff(np.log(steps))
    assert errors[-1] < 1e-4, errors
    assert np.all((order > 1.5) & (order < 2.3)), order      # ABM: about 1 + alpha


@pytest.mark.parametrize('model', MODELS)
def test_interpreted_and_compiled_steps_share_the_plant_state(model):
    p = ModelParameters(model=model)
    a = make_plant(p, X_START)
    b = make_plant(p, X_START)
    u = (0.0, -0.01)
    a.advance(u, 400)
    for _ in range(20):                      # alternate: 7 interpreted, 13 compiled steps
        b.advance(lambda t, x: u, 7)         # a plain callable runs interpreted
        b.advance(u, 13)
    assert a.n == b.n == 400
    np.testing.assert_allclose(b.state, a.state, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize('model', MODELS)
def test_non_finite_state_reported_at_the_same_step_by_both_engines(model):
    p = ModelParameters(model=model, step=0.01)       # unstable at this step from w = 1e300
    fails = []
    for engine in ('compiled', 'python'):
        plant = make_plant(p, (0.0, 1e300, 0.0, 0.0), engine=engine)
        with pytest.raises(FloatingPointError, match=r'state became non-finite at t='):
            plant.advance((0.0, 0.0), 1000)
        assert plant.status == 'failed' and 0 < plant.n < 1000
        fails.append(plant.n)
        with pytest.raises(RuntimeError, match='reset'):
            plant.advance((0.0, 0.0), 1)
        plant.reset((0.0, 0.0, 0.0, 0.0))
        plant.advance((0.0, 0.0), 10)                 # usable again after reset
        assert plant.n == 10 and np.isfinite(plant.state).all()
    assert fails[0] == fails[1]


def test_soe_horizon_follows_the_run():
    p = ModelParameters()
    assert make_plant(p).horizon_steps == SOE_HORIZON_OPEN                   # open-ended
    assert make_plant(p, duration=2.0).horizon_steps == SOE_HORIZON_MIN     # short run
    long_run = 1e4                                                           # s
    assert make_plant(p, duration=long_run).horizon_steps == math.ceil(long_run / p.step) + 1
    assert make_plant(ModelParameters(solver='abm')).horizon_steps is None
    small = make_plant(ModelParameters(soe_horizon_steps=1000))
    assert small.horizon_steps == 1000
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        small.advance((0.0, 0.0), 1000)                  # within the horizon: silent
    with pytest.warns(RuntimeWarning, match='beyond horizon_steps=1000'):
        small.advance((0.0, 0.0), 100)


def test_engine_is_checked():
    with pytest.raises(ValueError, match="engine='fast' is not one of 'auto', 'compiled'"):
        make_plant(ModelParameters(), engine='fast')
    assert 'interpreted' in make_plant(ModelParameters(solver='abm')).describe()
    assert 'compiled' in make_plant(ModelParameters()).describe()


# -- sampled drivers (advance_sampled): the hosted plant's bursts ------------------------------

X_PLANING = (0.0, 4.0, 0.0, 0.0)   # far enough beyond contact for the exact planing force too


def _per_period(model, law, periods, hold, limits, x0=X_PLANING):
    """The reference: one compiled call per period with the command held, the law evaluated
    in Python after each sample (what the hosted plant did per sample), the bounds and the
    deflection limits checked there. Rows [z, w, theta, q, Fp, df, dc] and the status."""
    plant = make_plant(ModelParameters(model=model), x0, duration=1.0)
    u, rows = (0.0, 0.0), []
    for _ in range(periods):
        plant.advance(u, hold)
        x = plant.x
        row = [*x, plant.planing_force, math.nan, math.nan]
        rows.append(row)
        if not (abs(x[1]) <= limits[2] and abs(x[2]) <= limits[3]):
            return np.array(rows), 2
        uf, uc = law(0.0, x)
        if not (abs(uf) <= limits[0] and abs(uc) <= limits[1]):
            return np.array(rows), 3
        row[5:7] = u = (uf, uc)
    return np.array(rows), 0


def _sampled(model, law, periods, hold, limits, burst, x0=X_PLANING):
    plant = make_plant(ModelParameters(model=model), x0, duration=1.0)
    out, rows, held = np.full((burst, 7), math.nan), [], (0.0, 0.0)
    while len(rows) < periods:
        done, status = plant.advance_sampled(law, held, hold, min(burst, periods - len(rows)),
                                             np.asarray(limits, dtype=float), out)
        rows.extend(out[:done].tolist())
        out[:] = math.nan
        if status:
            return np.array(rows), status
        held = rows[-1][5:7]
    return np.array(rows), 0


@pytest.mark.parametrize('model', MODELS)
def test_sampled_bursts_equal_one_call_per_period_bit_for_bit(model):
    """The hosted plant's bursts (an affine law sampled and held inside the kernel) give the
    very numbers of one kernel call per control period with eq. 31 evaluated in Python, for
    bursts of 1, 7 and 64 periods (the burst boundaries fall at different samples)."""
    law = AffineLaw.from_controller(StateFeedback())
    limits = (1.0, 1.0, 75.0, math.pi / 2)
    ref, status = _per_period(model, law, 400, 5, limits)
    assert status == 0 and np.max(np.abs(ref[:, 4])) > 1.0      # planing branches taken
    for burst in (1, 7, 64):
        got, status = _sampled(model, law, 400, 5, limits, burst)
        assert status == 0
        assert np.array_equal(got, ref, equal_nan=True), (burst, np.nanmax(np.abs(got - ref)))


@pytest.mark.parametrize('model', MODELS)
def test_sampled_bursts_stop_where_the_per_period_path_stops(model):
    """A destabilising law leaves the physical bounds (status 2) and a law beyond the
    plant's deflection limits is refused (status 3) at the same sample, with the same rows,
    as the per-period path."""
    unstable = AffineLaw(np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 2.0, 40.0, 2.0]]))
    ref, status = _per_period(model, unstable, 5000, 5, (1e9, 1e9, 75.0, math.pi / 2))
    assert status == 2
    got, st = _sampled(model, unstable, 5000, 5, (1e9, 1e9, 75.0, math.pi / 2), 64)
    assert st == 2 and np.array_equal(got, ref, equal_nan=True)
    law = AffineLaw.from_controller(StateFeedback())
    limits = (1e-4, 1e-4, 75.0, math.pi / 2)    # eq. 31 soon asks for more than this
    ref, status = _per_period(model, law, 400, 5, limits)
    assert status == 3 and len(ref) < 400
    got, st = _sampled(model, law, 400, 5, limits, 64)
    assert st == 3 and len(got) == len(ref)
    assert np.array_equal(got[:, :5], ref[:, :5])
    assert np.array_equal(got[:-1], ref[:-1], equal_nan=True)


def _fom_arrays(plant):
    """Copies of every array a FOM plant's kernel advances, and its scalars."""
    st = plant._stepper
    H, W, fill, eps_k, ET, a0_coef, a0_small, alpha, cp, cc, last_f, bad = plant._kernel_args
    arrays = [st.live_state(), plant._x0a, plant._cv, plant._law, H, W, fill, eps_k, ET,
              a0_coef, a0_small, last_f, bad]
    return [a.copy() for a in arrays], (alpha, cp, cc)


def test_held_call_equals_the_dispatcher_bit_for_bit():
    """The FOM kernel through its C entry point (kernels.FomHeldCall) against the same kernel
    through numba's dispatcher, on two copies of the same arrays: 400 control periods of 5
    steps under eq. 31 held over each (12 folds of the SOE window), every array equal after
    every period; then a state whose right-hand side overflows stops both at the same step
    with the same non-finite state reported."""
    plant = make_plant(ModelParameters(), X_START, duration=1.0)
    plant.advance((0.0, -0.01), 7)                  # a history that is not the start's
    (x, x0, cv, law, H, W, fill, eps_k, ET, a0c, a0s, last_f, bad), (alpha, cp, cc) = \
        _fom_arrays(plant)
    held = kernels.FomHeldCall.build(x, x0, cv, True, law, H, W, fill, eps_k, ET, a0c, a0s,
                                     alpha, cp, cc, last_f, bad)
    assert held is not None and held.x is x
    ref, _ = _fom_arrays(plant)
    ctl = StateFeedback()
    n = plant.n
    for _ in range(400):
        law[8:10] = ref[3][8:10] = ctl.command(0.0, tuple(ref[0]))
        a = held.call(n, 5)
        b = kernels.fom_soe_run(ref[0], ref[1], n, 5, ref[2], True, ref[3], False, *ref[4:11],
                                alpha, cp, cc, ref[11], ref[12])
        assert a == b == 5
        for mine, theirs in zip((x, H, fill, last_f), (ref[0], ref[4], ref[6], ref[11])):
            assert np.array_equal(mine, theirs)
        fp = plant._fp(ref[0][1], plant.coefficients)     # interpreted, at the same state
        assert abs(held.values[held.FP] - fp) <= 1e-12 * max(1.0, abs(fp))
        n += 5
    assert abs(x[1]) > 0.1                           # a trajectory that moved
    x[1] = ref[0][1] = 1e307                         # its right-hand side overflows
    law[8:10] = ref[3][8:10] = (0.0, 0.0)
    a = held.call(n, 50)
    b = kernels.fom_soe_run(ref[0], ref[1], n, 50, ref[2], True, ref[3], False, *ref[4:11],
                            alpha, cp, cc, ref[11], ref[12])
    assert a == b < 50, (a, b)
    assert np.array_equal(bad, ref[12], equal_nan=True) and not np.isfinite(bad).all()


@pytest.mark.parametrize('hold', [5, 1, 7, 16, 17])
def test_period_prepared_ahead_equals_the_kernel_bit_for_bit(hold):
    """The plant's compiled sample prepares each period's input-free part after the previous
    sample (kernels._prepare_period: the sums over f_0, the SOE modes and the window's values
    from before the period, a fold of the window due in the period) and finishes it when the
    command comes (fom_soe_prepared_run). Against fom_soe_run on a copy of the same arrays,
    through the C entry point's table: every array equal after every period of 4000 steps
    under eq. 31, and the planing force, with a single step run whole every 7th period (so
    the window's folds, every K = 32 steps, fall at every position of a period); a period
    with more steps than the n0 = 16 values a fold keeps is not prepared (the kernel runs it
    whole)."""
    plant = make_plant(ModelParameters(), X_START, duration=1.0)
    plant.advance((0.0, -0.01), 7)
    (x, x0, cv, law, H, W, fill, eps_k, ET, a0c, a0s, last_f, bad), (alpha, cp, cc) = \
        _fom_arrays(plant)
    assert ET.shape[1] == 32 and W.shape[0] - 1 - 32 == 16
    held = kernels.FomHeldCall.build(x, x0, cv, True, law, H, W, fill, eps_k, ET, a0c, a0s,
                                     alpha, cp, cc, last_f, bad)
    ref, _ = _fom_arrays(plant)
    P, M = np.zeros((hold, 8)), np.zeros((4, eps_k.shape[2]))
    ctl = StateFeedback()
    n = plant._stepper.n
    periods = prepared = shifts = 0
    fold_at = set()
    while n < 4000:
        shift = periods % 7 == 6
        shifts += shift
        steps = 1 if shift else hold
        ok = not shift and kernels._fom_prepare_jit(held._table, held._floats, n, steps, P, M)
        prepared += ok
        law[8:10] = ref[3][8:10] = ctl.command(0.0, tuple(ref[0]))
        before = int(fill[0])
        if ok:
            a = kernels._fom_prepared_jit(held._table, held._floats, n, steps, P, M)
        else:
            a = held.call(n, steps)
        if int(fill[0]) < before + steps:               # folded in this period: where
            fold_at.add(48 - before)
        b = kernels.fom_soe_run(ref[0], ref[1], n, steps, ref[2], True, ref[3], False,
                                *ref[4:11], alpha, cp, cc, ref[11], ref[12])
        assert a == b == steps
        for mine, theirs in zip((x, H, fill, last_f), (ref[0], ref[4], ref[6], ref[11])):
            assert np.array_equal(mine, theirs)
        fp = plant._fp(ref[0][1], plant.coefficients)
        assert abs(held.values[held.FP] - fp) <= 1e-12 * max(1.0, abs(fp))
        n += steps
        periods += 1
    assert prepared == (0 if hold > 16 else periods - shifts)
    if hold > 1:
        assert fold_at >= set(range(min(hold, 16))), fold_at   # at every step of a period
    assert abs(x[1]) > 0.1


def test_held_call_refuses_arrays_it_cannot_address():
    plant = make_plant(ModelParameters(), X_START)
    (x, x0, cv, law, H, W, fill, eps_k, ET, a0c, a0s, last_f, bad), (alpha, cp, cc) = \
        _fom_arrays(plant)
    args = [x, x0, cv, True, law, H, W, fill, eps_k, ET, a0c, a0s, alpha, cp, cc, last_f, bad]
    for i, wrong, message in ((5, H[:, :, ::2], 'H: a writeable C-contiguous float64'),
                              (7, fill.astype(np.float64), 'fill: a writeable C-contiguous '
                               'int64'),
                              (0, np.zeros(5), r'x: shape \(5,\), not \(4,\)')):
        bad_args = list(args)
        bad_args[i] = wrong
        with pytest.raises(ValueError, match=message):
            kernels.FomHeldCall.build(*bad_args)


def test_fom_plant_binds_its_held_call_again_after_interpreted_steps_and_a_reset():
    """A plant stepping with a held input uses the C entry point bound to the stepper's state
    array; interpreted steps replace that array and a reset replaces the history, and the
    next held-input call binds to the new arrays (test_interpreted_and_compiled_steps_share_
    the_plant_state checks the numbers across such a switch)."""
    plant = make_plant(ModelParameters(), X_START)
    plant.advance((0.0, -0.01), 5)
    first = plant._held_call
    assert isinstance(first, kernels.FomHeldCall)
    assert first.x is plant._stepper.live_state()
    assert plant.planing_force == plant._fp(plant.x[1], plant.coefficients)   # the kernel's
    plant.advance(lambda t, x: (0.0, -0.01), 3)       # interpreted: a new state array
    assert plant._stepper.live_state() is not first.x
    assert plant.planing_force == plant._fp(plant.x[1], plant.coefficients)
    plant.advance((0.0, -0.01), 5)
    assert plant._held_call is not first and plant._held_call.x is plant._stepper.live_state()
    second = plant._held_call
    plant.reset()
    plant.advance((0.0, -0.01), 5)
    assert plant._held_call is not second and plant.n == 5


def _period(sim, u, state, force):
    """One control period the general way: the held command, advance, the sample written."""
    sim.command = u
    sim.advance()
    sim.write_sample(state, force)


def _quick_period(sim, held, u, state, force):
    """One control period through the HeldPeriod (as the lockstep plant node runs it), or the
    general way where it declines; True when it ran."""
    sim.command = u
    if not held.run(*u):
        sim.advance()
        sim.write_sample(state, force)
        return False
    force[1] = held.settle()
    force[0] = state[0]
    sim.took(u)
    return True


def test_held_period_writes_the_sample_advance_gives_bit_for_bit():
    """The lockstep plant's short path (models.HeldPeriod: the sample written before the
    model's bookkeeping) against the general one (SampledPlant.advance, write_sample) on two
    FOM plants under eq. 31: every sample, the model's time, step count, state and planing
    force equal after every period, across the SOE window's folds and a reset (after which
    the short path declines until the general one has bound the kernel again)."""
    from fohssv_sim.ros.loop import SampledPlant

    p = ModelParameters()
    a, b = (SampledPlant(p, 1e-4, X_START, duration=1.0) for _ in range(2))
    held = b.held_period(sb := [0.0] * 5)
    assert held is not None
    sa, fa, fb = [0.0] * 5, [0.0] * 2, [0.0] * 2
    ctl = StateFeedback()
    ran = 0
    for k in range(700):
        if k == 400:
            a.reset()
            b.reset()
        u = ctl.command(0.0, tuple(sa[1:]))
        _period(a, u, sa, fa)
        ran += _quick_period(b, held, u, sb, fb)
        assert sb == sa and fb == fa, k
        assert (b.samples, b.t, b.plant.n, b.plant.x, b.plant.planing_force, b.command) == (
            a.samples, a.t, a.plant.n, a.plant.x, a.plant.planing_force, a.command), k
    assert ran == 698              # all but the first period and the one after the reset
    assert b.plant._stepper.n == a.plant._stepper.n == 300 * 5
    assert abs(sa[2]) > 0.1                    # a trajectory that moved
    for model in ('delay-free', 'delayed'):   # no short path: the node steps them as before
        assert SampledPlant(ModelParameters(model=model), 1e-4).held_period([0.0] * 5) is None


@pytest.mark.parametrize('start, u, error', [
    ((0.0, 0.0, 1.5, 40.0), (0.0, 0.0), r'state beyond physical bounds at t='),
    (X_START, (math.nan, 0.0), r'state became non-finite at t='),
])
def test_held_period_fails_where_advance_fails_with_its_words(start, u, error):
    """A period that leaves the bounds (pitch past pi/2) or turns non-finite (a NaN command)
    raises from HeldPeriod what SampledPlant.advance raises, at the same sample, with the
    same text, and leaves the plant failed and its sample count as advance does."""
    from fohssv_sim.ros.loop import SampledPlant

    p = ModelParameters()
    out = []
    for short in (False, True):
        sim = SampledPlant(p, 1e-4, start, duration=1.0)
        state, force = [0.0] * 5, [0.0] * 2
        held = sim.held_period(state)
        _period(sim, (0.0, 0.0), state, force)       # binds the kernel call
        with pytest.raises(FloatingPointError, match=error) as info:
            for _ in range(1000):
                if not short:
                    _period(sim, u, state, force)
                    continue
                sim.command = u
                try:
                    assert held.run(*u)
                except FloatingPointError as exc:
                    sim.failed_period(exc)
                    raise
                held.settle()
                sim.took(u)
        out.append((str(info.value), type(info.value), sim.samples, sim.plant.n,
                    sim.plant.status))
    assert out[0] == out[1] and out[0][4] == 'failed', out
