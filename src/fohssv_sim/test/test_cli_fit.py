"""`fohssv fit` (issue 23) on bags written from in-process runs: the population kernel against
the plant stepped period by period, and bad input refused in one line with exit 2."""

import hashlib
import json
import re
import subprocess
from pathlib import Path

import numpy as np
from ament_index_python.packages import get_package_prefix

from fohssv_sim.analysis.population import run_population, run_population_reference
from fohssv_sim.bag.synthetic import write_simulation
from fohssv_sim.control import make
from fohssv_sim.models import AffineLaw
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'


def run(*args):
    return subprocess.run([str(FOHSSV), *args], capture_output=True, text=True, timeout=300)


def run_main(*args, stdout: list | None = None):
    """The command's own entry point (``fohssv_sim.cli.main``, what the console script calls)
    in this process (a process start per case would only add its imports). Returns (exit
    status, stderr); ``stdout`` (a list) receives what it printed."""
    import contextlib
    import io

    from fohssv_sim.cli import main

    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        code = main(list(args))
    if stdout is not None:
        stdout.append(out.getvalue())
    return code, err.getvalue()


def _bag(path: Path, commands: bool = True, duration: float = 0.02) -> Path:
    p = ModelParameters(fractional_order=0.81)
    r = simulate(p, make('state_feedback'), duration, control_period=1e-4, sample_every=5)
    write_simulation(path, r, {**p.to_dict(), 'control_period': 1e-4, 'duration': duration,
                               'initial_state': [0.0] * 4}, commands=commands)
    return path


def test_population_equals_the_plant_stepped_period_by_period():
    """One compiled call for points differing in alpha, V and the planing offset gives the
    numbers of make_plant + Plant.advance per period, open loop and closed loop, bit for bit;
    a point that blows up is marked failed in both, in the same period. (Its states before
    that are compared to 1e-12 relative, not bit for bit: on one machine of this kind the
    alpha = 0.3 point, which leaves every bound within two periods, differed by one ulp
    after its first period, where the three points that stay finite agree bit for bit.)"""
    ps = [ModelParameters(fractional_order=a, speed=v, planing_offset=w)
          for a, v, w in [(0.81, 75.0, 1.9), (0.7, 80.0, 'consistent'), (1.0, 75.0, 2.5),
                          (0.3, 75.0, 1.9)]]
    rng = np.random.default_rng(3)
    inputs = rng.uniform(-0.02, 0.02, (400, 2))
    law = AffineLaw.from_controller(make('state_feedback')).packed
    for kw in ({'inputs': inputs}, {'law': law}):
        got = run_population(ps, 400, 5, duration=1.0, **kw)
        ref = run_population_reference(ps, 400, 5, duration=1.0, **kw)
        assert np.array_equal(got.failed, ref.failed)
        assert list(got.failed) == [False, False, False, True]
        assert np.array_equal(got.states[:3], ref.states[:3])
        bad = np.isnan(got.states[3]).any(axis=1)
        assert np.array_equal(bad, np.isnan(ref.states[3]).any(axis=1)) and bad.any()
        np.testing.assert_allclose(got.states[3][~bad], ref.states[3][~bad], rtol=1e-12,
                                   atol=0.0)
    r = simulate(ps[0], make('state_feedback'), 0.04, control_period=1e-4, sample_every=5)
    got = run_population(ps[:1], 400, 5, law=law, duration=0.04)
    assert np.array_equal(got.states[0], r.state)        # the batch runner's closed loop


def test_a_law_with_memory_runs_point_by_point_as_the_batch_runner_runs_it():
    """fractional_pid has no compiled form: the fit's point-by-point path (a fresh law per
    point, its command held per period) gives simulate()'s closed loop bit for bit, for each
    of two points run one after the other (the second does not inherit the first's memory)."""
    ps = [ModelParameters(fractional_order=a) for a in (0.81, 0.9)]
    got = run_population_reference(ps, 400, 5, controller=lambda: make('fractional_pid'),
                                   duration=0.04)
    assert not got.failed.any()
    for i, p in enumerate(ps):
        r = simulate(p, make('fractional_pid'), 0.04, control_period=1e-4, sample_every=5)
        assert np.array_equal(got.states[i], r.state), p.fractional_order
        assert np.array_equal(got.inputs[i], r.inputs[:-1]), p.fractional_order


def test_bad_input_is_one_line_and_exit_2(tmp_path):
    bag = _bag(tmp_path / 'run')
    silent = _bag(tmp_path / 'no_commands', commands=False)
    cases = [((str(silent), '--fit', 'fractional_order'), 'no command messages'),
             ((str(bag), '--fit', 'model'), "--fit model: not numeric"),
             ((str(bag), '--fit', 'fractional_order,drag'), '--fit drag: not a model parameter'),
             ((str(bag), '--fit', 'step'), '--fit step: a solver setting'),
             ((str(bag), '--fit', 'fractional_order', '--bounds', 'fractional_order=0.5:1.5'),
              '1.5 is outside the allowed range (0, 1]'),
             ((str(bag), '--fit', 'fractional_order', '--bounds', 'speed=60:80'),
              '--bounds speed: not among the fitted names'),
             ((str(bag), '--fit', 'fractional_order', '--window', '5:6'),
              '--window 5:6 s holds 0 state sample(s)'),
             ((str(bag), '--fit', 'fractional_order', '--controller', 'nope'),
              "--controller nope: unknown controller 'nope'"),
             ((str(bag), '--fit', 'fractional_order', '--controller', 'state_feedback',
               '--gain', 'pitch_gain=x'), '--gain: ')]
    for args, text in cases[1:]:
        code, err = run_main('fit', *args, '--out', str(tmp_path / 'out'))
        assert code == 2, (args, err)
        assert text in err and 'Traceback' not in err, (args, err)
        assert len(err.strip().splitlines()) == 1, err
    out = run('fit', *cases[0][0], '--out', str(tmp_path / 'out'))    # one through the script
    assert out.returncode == 2 and cases[0][1] in out.stderr, out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and 'Traceback' not in out.stderr
    code, err = run_main('fit', str(tmp_path / 'missing'), '--fit', 'fractional_order')
    assert code == 1 and 'no such file' in err     # a bag error, as `check`


def _edited_bag(path: Path, *, scale: float = 1.0, last_t: float | None = None,
                control_period=1e-4) -> Path:
    """A 0.02 s run whose states are multiplied by ``scale``, whose last state is moved to
    ``last_t``, or whose recorded control period is ``control_period`` (any JSON value)."""
    p = ModelParameters(fractional_order=0.81)
    r = simulate(p, make('state_feedback'), 0.02, control_period=1e-4, sample_every=5)
    r.state = r.state * scale
    if last_t is not None:
        r.t = r.t.copy()
        r.t[-1] = last_t
    write_simulation(path, r, {**p.to_dict(), 'control_period': control_period,
                               'duration': 0.02, 'initial_state': [0.0] * 4})
    return path


def test_extreme_input_is_one_line_and_exit_2(tmp_path):
    """Issue 51 item 7: states scaled by 1e300 (a residual that overflows was reported as 0,
    'reproduces'), legal but extreme bounds (the coefficients overflow), a string control
    period, a state at t = 1e5 s, a plugin that raises; and the noise options."""
    bag = _bag(tmp_path / 'run')
    huge = _edited_bag(tmp_path / 'huge', scale=1e300)
    late = _edited_bag(tmp_path / 'late', last_t=1e5)
    text = _edited_bag(tmp_path / 'text', control_period='abc')
    fast = ('--population', '4', '--profile-points', '5', '--no-step-check', '--workers', '1')
    closed = ('--controller', 'state_feedback')
    cases = [((str(huge), '--fit', 'fractional_order', *closed), 'overflow any residual'),
             ((str(bag), '--fit', 'speed', '--bounds', 'speed=1e-300:1e300', *closed),
              "model's coefficients overflow or are refused"),
             ((str(text), '--fit', 'fractional_order'), "control_period 'abc' is not a "
              'positive number of seconds'),
             ((str(late), '--fit', 'fractional_order'), 'a state at t = 100000 s is'),
             ((str(bag), '--fit', 'fractional_order', '--noise', 'z=-1'),
              '--noise z=-1.0: need a finite number > 0'),
             ((str(bag), '--fit', 'fractional_order', '--noise', 'x=1'), '--noise x: not a '
              'state'),
             ((str(bag), '--fit', 'fractional_order', '--measure', 'z,x'),
              "--measure 'z,x': give states among z, w, theta, q")]
    for args, want in cases:
        code, err = run_main('fit', *args, *fast, '--out', str(tmp_path / 'out'))
        assert code == 2, (args, err)
        assert want in err and 'Traceback' not in err, (args, err)
        assert len(err.strip().splitlines()) == 1, err


def test_default_output_folder_is_named_after_the_job_and_claimed(tmp_path, monkeypatch):
    """Like every command: reports/fit/<bag>-<hash of the job>, with job.json naming the
    bag's sha256; a folder holding another fit job is refused (exit 2), not overwritten."""
    bag = _bag(tmp_path / 'run')
    # the folder is the point, not the fit; the default --workers (one per core): the fit
    # cases' one case of the local stage on threads (its speculative Jacobian)
    fast = ('--population', '8', '--profile-points', '5', '--no-step-check',
            '--controller', 'state_feedback')
    monkeypatch.chdir(tmp_path)
    printed: list[str] = []
    code, err = run_main('fit', str(bag), '--fit', 'fractional_order', *fast, stdout=printed)
    assert code == 0, err
    folders = list((tmp_path / 'reports' / 'fit').iterdir())
    assert len(folders) == 1 and re.fullmatch(r'run-[0-9a-f]{8}', folders[0].name), folders
    assert str(Path('reports') / 'fit' / folders[0].name) in printed[0]
    sha = hashlib.sha256(b''.join(f.read_bytes() for f in sorted(bag.glob('*.mcap'))))
    job = json.loads((folders[0] / 'job.json').read_text())
    assert job['fit']['bag_sha256'] == sha.hexdigest()
    assert json.loads((folders[0] / 'fit.json').read_text())['bag_sha256'] == sha.hexdigest()
    code, err = run_main('fit', str(bag), '--fit', 'fractional_order', '--window', '0:0.01',
                         *fast, '--out', str(folders[0]))
    assert code == 2 and 'holds a different fit job' in err, err
    assert len(err.strip().splitlines()) == 1


def test_cycle_features_of_an_exact_waveform():
    """The cycle detector on w(t) = m + A (sin 2 pi f t + 0.3 sin(4 pi f t + 0.5)): frequency
    f, mean m and the peak-to-peak of the formula (evaluated densely here), period 1."""
    from fohssv_sim.analysis.fit import cycle_features

    f, m, a = 131.7, 1.25, 0.4
    t = np.arange(0, 0.5, 1e-4)

    def w(t):
        return m + a * (np.sin(2 * np.pi * f * t) + 0.3 * np.sin(4 * np.pi * f * t + 0.5))

    got = cycle_features(t, w(t))
    dense = w(np.linspace(0, 1 / f, 100_001))
    assert abs(got['frequency'] - f) / f < 1e-4
    assert abs(got['amplitude'] - np.ptp(dense)) / np.ptp(dense) < 1e-3
    assert abs(got['mean'] - m) < 2e-3 * a        # 65.85 periods: the part period's share
    assert got['label'] == 'periodic-1'


def test_cycle_objective_recovers_alpha_and_the_cycle_an_fft_measures(tmp_path):
    """A 0.4 s closed-loop FOM run (alpha = 0.81): the cycle fit's interval covers 0.81, and
    the frequency of w it reports for the run and for the fitted FOM is the one a Hann-window
    FFT of the bag's w (numpy, here, with the peak interpolated) gives; the bag's w repeats
    after 1/f (period 1, checked on the samples here), as the fit's class says."""
    from fohssv_sim.analysis.fit import (
        FitSpec,
        base_from_run,
        data_from_run,
        resolve_bounds,
        run_fit,
    )
    from fohssv_sim.bag import load_run

    bag = _bag(tmp_path / 'run', duration=0.4)
    run_ = load_run(bag)
    base = base_from_run(run_)
    data = data_from_run(run_, base)
    names = ('fractional_order',)
    spec = FitSpec(names=names, bounds=resolve_bounds(names, {'fractional_order': (0.7, 1.0)},
                                                      base),
                   base=base.to_dict(), objective='cycle', window=(0.2, 0.4),
                   controller='state_feedback', population=8, profile_points=7,
                   fine_points=5, step_check=False)
    res = run_fit(spec, data, tmp_path / 'out', threads=1)  # the test workers fill the cores
    lo, hi = res.intervals['fractional_order']
    assert res.reproduces and lo <= 0.81 <= hi, res.message

    keep = (run_.t >= 0.2) & (run_.t <= 0.4)
    t, w = run_.t[keep], run_.state[keep, 1]
    dt = float(np.median(np.diff(t)))
    n = 1 << 18                                    # zero padding: 0.04 Hz bins
    spec_ = np.abs(np.fft.rfft((w - w.mean()) * np.hanning(w.size), n))
    k = int(np.argmax(spec_[1:])) + 1
    y0, y1, y2 = np.log(spec_[k - 1:k + 2])
    f_fft = (k + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)) / (n * dt)
    assert 50 < f_fft < 300                         # a tail-slap cycle, not a drift
    for side in ('data', 'fitted'):
        c = res.cycle[side]
        assert abs(c['frequency'] - f_fft) / f_fft < 5e-3, (side, c, f_fft)
        assert c['label'] == 'periodic-1', (side, c)
        assert abs(c['amplitude'] - np.ptp(w)) <= 0.02 * np.ptp(w), (side, c)
        assert abs(c['mean'] - w.mean()) <= 0.02 * np.ptp(w), (side, c)
    shifted = np.interp(t + 1 / f_fft, t, w)       # period 1: w(t + T) = w(t)
    inside = t + 1 / f_fft <= t[-1]
    assert np.max(np.abs(shifted[inside] - w[inside])) < 0.05 * np.ptp(w)


def test_alpha_tau_legend_names_only_the_kinds_of_point_it_shows(tmp_path):
    """Issue 23's figure alpha*(tau): a 'reproduced' entry only where some speed reproduced,
    a 'not reproduced' one only where some did not (read from the written SVG, whose text
    matplotlib keeps as comments, and from the figure's legend)."""
    from fohssv_sim.analysis.fit import FitSpec, alpha_tau_figure, plot_alpha_tau

    spec = FitSpec(names=('fractional_order',), bounds=((0.5, 1.0),), base={})
    yes, no = 'fractional_order* (reproduced)', 'fractional_order* (best, not reproduced)'
    for flags, labels in [((False, False), {no}), ((True, False), {yes, no}),
                          ((True, True), {yes})]:
        rows = [{'speed': v, 'tau': 1.8 / v, 'name': 'fractional_order', 'value': 0.8,
                 'interval': [0.79, 0.81], 'residual': 0.01 if f else 0.2, 'reproduces': f}
                for v, f in zip((75.0, 85.0), flags)]
        stem = tmp_path / f'alpha_tau_{sum(flags)}'
        paths = plot_alpha_tau(rows, spec, stem, 'caption')
        svg = paths[1].read_text()
        assert {t for t in re.findall(r'<!-- (.*?) -->', svg) if t.startswith(
            'fractional_order* (')} == labels, flags
        legend = {t.get_text() for t in alpha_tau_figure(rows, spec, 'c').axes[0]
                  .get_legend().get_texts()}
        assert legend == labels | {'residual floor at the best α', 'threshold 0.05'}
        assert paths[0].stat().st_size > 5000
