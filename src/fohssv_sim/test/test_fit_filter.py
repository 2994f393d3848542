"""Open-loop replays fitted over the whole record through the model's Kalman filter (issue 49,
:mod:`fohssv_sim.analysis.fit.observer`).

The data are independent of the fit (as in test_fit_noise.py): closed-loop runs of the exact
predictor-corrector ('abm') at half the fit's step, the delayed model by RK4, written as a
bag with plain rosbags whose metadata say alpha = 0.85 (never the truth, 0.81); the fit
replays the recorded commands without the controller (open loop), so the unstable vehicle
departs from the data within tens of milliseconds of any error. The memory is checked against
an exact run: the filter's predictions at the truth reproduce the exact solver to rounding; a
replay started afresh from the data (its memory cut) does not.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_fit_noise import TRUTH, _bag, _run

from fohssv_sim.analysis.fit import (
    FitSpec,
    base_from_run,
    data_from_run,
    observer,
    resolve_bounds,
    run_fit,
)
from fohssv_sim.analysis.fit.problem import Problem
from fohssv_sim.analysis.population import run_population
from fohssv_sim.bag import load_run
from fohssv_sim.control import make
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

CP = 1e-4


def _open_fit(bag: Path, tmp: Path, names=('fractional_order',), **kw):
    run = load_run(bag)
    base = base_from_run(run)
    data = data_from_run(run, base)
    kw = {'population': 8, 'starts': 1, 'profile_points': 5, 'fine_points': 3, **kw}
    spec = FitSpec(names=tuple(names), bounds=resolve_bounds(names, {}, base),
                   base=base.to_dict(), **kw)
    return run_fit(spec, data, tmp / 'out')


def _problem(bag: Path, step: float) -> Problem:
    run = load_run(bag)
    base = base_from_run(run).replace(step=step)
    names = ('fractional_order',)
    return Problem(FitSpec(names=names, bounds=resolve_bounds(names, {}, base),
                           base=base.to_dict()), data_from_run(run, base))


def test_the_filter_carries_the_memory_of_the_whole_record(tmp_path):
    """Data from the exact predictor-corrector at the fit's own step (h = 1e-5 s, alpha =
    0.81, 0.11 s, through the first tail-slap contacts): the filter's predictions at the
    truth follow them to 1e-8 of each state's spread, while a single replay from x(0)
    departs by more than 1e-3 (the two solvers' rounding and truncation, amplified by the
    instability through the contacts), and a replay started afresh from the data at t = 0.1 s
    (the Caputo problem from that instant: its memory cut) departs by more than 1e-3 within
    a millisecond."""
    h = 1e-5
    p = ModelParameters(fractional_order=TRUTH, solver='abm', step=h)
    r = simulate(p, make('state_feedback'), 0.11, control_period=CP, sample_every=10)
    bag = _bag(tmp_path / 'run', r)
    pr = _problem(bag, h)
    assert pr.mode == 'filter'
    run, _ = pr.simulate([[TRUTH]], pr.index.size)
    err = np.abs((run.states[0] - r.state) / pr.scale)
    assert err.max() < 1e-8, err.max()
    fit_p = pr.params_for([TRUTH])
    n = pr.index.size
    replay = run_population([fit_p], n, pr.hold, inputs=pr.data.inputs[:n],
                            initial_state=pr.data.initial_state, duration=pr.data.duration)
    assert np.nanmax(np.abs((replay.states[0] - r.state) / pr.scale)) > 1e-3
    k = 1000                                  # t = 0.1 s
    fresh = run_population([fit_p], 10, pr.hold, inputs=pr.data.inputs[k:k + 10],
                           initial_state=r.state[k], duration=pr.data.duration)
    assert np.abs((fresh.states[0] - r.state[k:k + 11]) / pr.scale).max() > 1e-3


@pytest.fixture(scope='module')
def clean_open():
    """The independent run the open-loop fits replay: 0.15 s (20 ms past the first contact)."""
    return _run(duration=0.15)


def test_whole_record_open_loop_fit_with_noise(clean_open, tmp_path, monkeypatch):
    """10 % noise on every state: alpha inside its interval, the run reproduced over the whole
    record (not a horizon of its first tens of milliseconds), at the noise floor, by the
    filter's prediction errors. A filter that takes each sample whole (a process noise of
    1e3 of each state's spread per period, far above the measurement's) predicts nothing and
    keeps the noise in the memory: the same fit then lands far from the truth (0.968 [0.934,
    1]). (The half-step check stays on: the fit's step alone moves alpha by about 6e-4
    here.)"""
    bag = _bag(tmp_path / 'run', clean_open, 0.10, 2)
    res = _open_fit(bag, tmp_path, population=4)
    lo, hi = res.intervals['fractional_order']
    assert res.reproduces, res.message
    assert lo <= TRUTH <= hi, res.message
    assert res.horizon_end == pytest.approx(0.15), res.message
    assert 'at the noise floor' in res.message
    assert res.settings['loop'].startswith('open') and 'Kalman' in res.settings['loop']
    monkeypatch.setattr(observer, 'PROCESS_NOISE', 1e3)
    whole = _open_fit(bag, tmp_path / 'whole', population=4, step_check=False)
    assert abs(whole.values['fractional_order'] - TRUTH) > 0.05, whole.message


def test_the_filter_tracks_the_unmeasured_states(clean_open, tmp_path):
    """Depth and pitch measured, w and q not, noise-free: the filter's predictions follow the
    unmeasured w and q (never read) to 2e-2 of their spread over the whole 0.15 s, through the
    planing contacts (w and q continued from segments fitted to z and theta alone, the
    earlier multiple shooting, left the state's domain after 0.08-0.09 s)."""
    bag = _bag(tmp_path / 'run', clean_open, states=(0, 2))
    run = load_run(bag)
    base = base_from_run(run)
    names = ('fractional_order',)
    pr = Problem(FitSpec(names=names, bounds=resolve_bounds(names, {}, base),
                         base=base.to_dict(), weights=(1, 0, 1, 0)), data_from_run(run, base))
    run, _ = pr.simulate([[TRUTH]], pr.index.size)
    assert not run.failed[0]
    err = np.abs(run.states[0] - clean_open.state) / clean_open.state.std(axis=0)
    assert err[:, [1, 3]].max() < 2e-2, err.max(axis=0)


def test_threads_split_the_points_not_the_numbers(clean_open, tmp_path):
    """Three points run in one call and split over two threads (the kernel releases the
    GIL): the same numbers, bit for bit (the points are independent)."""
    bag = _bag(tmp_path / 'run', clean_open, 0.05, 3)
    run = load_run(bag)
    base = base_from_run(run)
    names = ('fractional_order',)
    pr = Problem(FitSpec(names=names, bounds=resolve_bounds(names, {}, base),
                         base=base.to_dict()), data_from_run(run, base))
    pts, upto = [[0.8], [0.81], [0.82]], 300
    one, _ = pr.simulate(pts, upto, threads=1)
    two, _ = pr.simulate(pts, upto, threads=2)
    assert np.array_equal(one.states, two.states, equal_nan=True)
    assert np.array_equal(pr.residuals(pts, upto, threads=1), pr.residuals(pts, upto, threads=2))


def test_open_loop_with_a_state_unmeasured_says_alpha_is_not_identifiable(tmp_path):
    """Depth and pitch only, open loop: the fit runs over the whole record, but alpha is
    reported not identifiable, and why (over ten seeds its interval held the truth in 3 at
    1 % noise, in none at 5 %: docs/fit.md, Limits)."""
    bag = _bag(tmp_path / 'run', _run(duration=0.05), 0.01, 1, states=(0, 2))
    res = _open_fit(bag, tmp_path, population=2, weights=(1, 0, 1, 0), step_check=False,
                    profile_points=3)
    assert res.identifiable == {'fractional_order': False}, res.message
    assert 'not identifiable' in res.message and 'w, q not measured' in res.message
    assert '--controller NAME' in res.message
    assert res.horizon_end == pytest.approx(0.05), res.message


def test_the_filter_is_the_kalman_filter_of_the_one_period_map():
    """Away from the planing contacts (w = 0: no planing force, no slope) the filter's
    covariance, updated period after period with nothing to correct, settles where the
    discrete algebraic Riccati equation of F = I + c A (scipy's solver, a second method)
    puts it: with z and theta measured, and with every state."""
    from scipy.linalg import solve_discrete_are

    from fohssv_sim.coefficients import coefficients
    from fohssv_sim.kernels import unpack_coefficients

    p = ModelParameters(fractional_order=TRUTH)
    co = coefficients(p)
    scale = np.array([0.014, 0.48, 0.0072, 0.085])
    sigma = 0.05 * scale
    for m in (np.array([1, 0, 1, 0], bool), np.ones(4, bool)):
        (c,), Q, R, mm = observer.settings([p], CP, scale, sigma, m)
        F = np.eye(4) + c * np.asarray(co.A)
        P = np.diag(Q)
        y, y0 = np.zeros(4), np.zeros(4)
        for _ in range(20000):
            observer.update(P, y, y0, np.zeros(4), c, unpack_coefficients(co.kernel), True,
                            Q, R, mm, np.zeros(4))
        H = np.eye(4)[m]
        prior = solve_discrete_are(F.T, H.T, np.diag(Q), np.diag(R[m]))
        assert np.allclose(F @ P @ F.T + np.diag(Q), prior, rtol=1e-6, atol=0), m
        assert not y.any() and not y0.any()


def test_whole_record_open_loop_two_parameters_with_default_bounds(tmp_path):
    """alpha and the planing offset (truth 2.1; the bag says 'consistent', 1.64 at V = 75;
    the short-horizon fit excluded 2.1) from an open-loop replay of the whole record: both
    truths inside their intervals."""
    r = _run(duration=0.15, planing_offset=2.1)
    bag = _bag(tmp_path / 'run', r, 0.01, 8)
    names = ('fractional_order', 'planing_offset')
    res = _open_fit(bag, tmp_path, names=names)
    assert res.reproduces, res.message
    for n, truth in zip(names, (TRUTH, 2.1)):
        lo, hi = res.intervals[n]
        assert lo <= truth <= hi, (n, res.message)
        assert res.identifiable[n], res.message


def test_a_delayed_model_replay_is_not_reproduced_over_the_whole_record(tmp_path):
    """The delayed model's run (RK4, tau = L/V) replayed open loop through the FOM: no alpha
    reproduces it over the whole record, residual and noise side by side."""
    r = _run('delayed', duration=0.15)
    bag = _bag(tmp_path / 'run', r, 0.01, 4)
    res = _open_fit(bag, tmp_path, step_check=False, population=4)
    assert not res.reproduces, res.message
    assert res.horizon_end == pytest.approx(0.15), res.message
    v = res.settings['verdict']
    assert v['noise_ratio'] > v['noise_bound']
    assert 'x the noise' in res.message and 'noise z' in res.message, res.message
