"""simulate() keeps samples without changing the run: every k-th step of a run that keeps
every step is, bit for bit, what the run keeping every k-th step gives; both end where one
kernel call over all the steps ends; the interpreted plant records the same rows;
simulate_batch gives each point its own run."""

import numpy as np
import pytest

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.batch import simulate_batch
from fohssv_sim.models import AffineLaw, StateOutOfBounds, make_plant
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

X_START = (0.0, 2.5, 0.0, 0.0)      # the tail on the wall from the start: Fp is not zero
MODELS = {'delay-free': {}, 'delayed': {}, 'fractional': {'fractional_order': 0.85}}


def _params(model: str) -> ModelParameters:
    return ModelParameters(model=model, speed=75.0, **MODELS[model])


def _same_rows(every, kept, k):
    for name in ('t', 'state', 'planing_force', 'inputs'):
        np.testing.assert_array_equal(getattr(kept, name), getattr(every, name)[::k],
                                      err_msg=name)


@pytest.mark.parametrize('model', MODELS)
@pytest.mark.parametrize('k', [1, 7, 50])
def test_keeping_every_kth_step_gives_every_kth_row_of_keeping_all(model, k):
    p = _params(model)
    duration = 0.02
    every = simulate(p, StateFeedback(), duration, initial_state=X_START)
    kept = simulate(p, StateFeedback(), duration, initial_state=X_START, sample_every=k)
    n = every.metadata['steps']
    assert every.state.shape == (n + 1, 4) and kept.state.shape == (n // k + 1, 4)
    _same_rows(every, kept, k)
    assert np.all(every.planing_force[:10] != 0.0)
    # one kernel call over all the steps, nothing kept: the same last state
    plant = make_plant(p, X_START, duration=duration)
    plant.advance(AffineLaw.from_controller(StateFeedback()), n)
    np.testing.assert_array_equal(every.state[-1], plant.state)
    # the input of a row is the law's at that row's state (clamped eq. 31)
    law = AffineLaw.from_controller(StateFeedback())
    for i in (0, n // 2, n):
        assert tuple(every.inputs[i]) == law(every.t[i], every.state[i])


@pytest.mark.parametrize('model', MODELS)
def test_zero_order_hold_rows_inside_and_across_control_periods(model):
    # hold of 5 steps; rows every 3 fall inside periods and on control instants (period by
    # period); rows every 5 or 15 only on control instants (the law sampled in compiled code);
    # 0.0103 s is no whole number of periods (the last one is partial)
    p = _params(model)
    period = 5 * p.step
    every = simulate(p, StateFeedback(), 0.0103, control_period=period, initial_state=X_START)
    for k in (3, 5, 15):
        kept = simulate(p, StateFeedback(), 0.0103, control_period=period,
                        initial_state=X_START, sample_every=k)
        _same_rows(every, kept, k)
    # the input is held: constant over each period, changed at the control instants
    u = every.inputs[:, 1]
    assert np.all(u[1:5] == u[0]) and np.all(u[6:10] == u[5])
    assert u[5] != u[0]


@pytest.mark.parametrize('model', MODELS)
def test_a_run_leaving_the_bounds_stops_at_the_same_control_instant_sampled_or_not(model):
    # open loop (zero gains) from the wall: the state passes |w| = V at some control instant;
    # the affine law sampled in compiled code and the same law as a plain callable (period by
    # period, the bounds checked after each) stop there with the same words
    p = _params(model)
    ctl = StateFeedback(depth_gain=0.0, pitch_gain=0.0, pitch_rate_gain=0.0)
    errors = []
    for law in (ctl, lambda t, x: ctl.command(t, x)):
        with pytest.raises(StateOutOfBounds, match='beyond physical bounds') as err:
            simulate(p, law, 0.5, control_period=5 * p.step, initial_state=X_START,
                     sample_every=10)
        errors.append(str(err.value))
    assert errors[0] == errors[1]


def test_a_law_the_kernels_cannot_run_is_recorded_interpreted_with_the_same_rows():
    # a plain callable: the plant steps it interpreted; its rows as the kernel path's
    p = _params('delay-free')
    ctl = StateFeedback()
    law = AffineLaw.from_controller(ctl)
    every = simulate(p, lambda t, x: law(t, x), 0.005, initial_state=X_START)
    kept = simulate(p, lambda t, x: law(t, x), 0.005, initial_state=X_START, sample_every=4)
    _same_rows(every, kept, 4)
    compiled = simulate(p, ctl, 0.005, initial_state=X_START)
    np.testing.assert_allclose(every.state, compiled.state, rtol=0, atol=1e-12)
    np.testing.assert_allclose(every.inputs, compiled.inputs, rtol=0, atol=1e-12)


@pytest.mark.parametrize('model', MODELS)
def test_the_interpreted_plant_records_what_the_compiled_one_does(model):
    p = _params(model)
    kw = dict(initial_state=X_START, sample_every=3)
    compiled = simulate(make_plant(p, duration=0.004), StateFeedback(), 0.004, **kw)
    python = simulate(make_plant(p, engine='python', duration=0.004), StateFeedback(), 0.004,
                      **kw)
    np.testing.assert_array_equal(python.t, compiled.t)
    for name in ('state', 'planing_force', 'inputs'):
        np.testing.assert_allclose(getattr(python, name), getattr(compiled, name), rtol=1e-12,
                                   atol=1e-12, err_msg=name)


def test_progress_is_reported_per_chunk_up_to_the_end():
    seen = []
    simulate(_params('delay-free'), StateFeedback(), 0.01, progress=seen.append)
    assert 50 <= len(seen) <= 101 and seen == sorted(seen) and seen[-1] == 1.0


@pytest.mark.parametrize('model', MODELS)
@pytest.mark.parametrize('hold', [None, 5])
def test_simulate_batch_gives_each_points_own_run_sample_by_sample(model, hold):
    # points differing in speed, gains and initial state, kept from t = 4 ms on; the last
    # point starts beyond |w| <= V: it fails alone, its samples NaN
    ps = [ModelParameters(model=model, speed=v, **MODELS[model]) for v in (70.0, 75.0, 80.0)]
    ctls = [StateFeedback(pitch_gain=g) for g in (-30.0, -25.0, -20.0)]
    x0 = [X_START, (0.0, -2.0, 0.01, 0.0), (0.0, 90.0, 0.0, 0.0)]
    cp = hold and hold * ps[0].step
    b = simulate_batch(ps, ctls, 0.01, control_period=cp, initial_states=x0, sample_every=5,
                       record_from=0.004)
    assert list(b.failed) == [False, False, True] and np.isnan(b.states[2]).all()
    for i in (0, 1):
        r = simulate(ps[i], ctls[i], 0.01, control_period=cp, initial_state=x0[i],
                     sample_every=5)
        keep = r.t >= 0.004
        assert keep.sum() < r.t.size - 10
        np.testing.assert_array_equal(b.t, r.t[keep])
        np.testing.assert_array_equal(b.states[i], r.state[keep])
