"""``fohssv tune`` (issue 24): the score's order, resume to the same winner, the scheduled law,
and bad input refused in one line. The search on a real graph: tests/test_graph_tune.py."""

import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_prefix

from fohssv_controller.scheduled import Scheduled
from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.analysis.tune import (
    CHECK_RTOL,
    Bound,
    TuneError,
    TuneSpec,
    run_tune,
    score,
    step_flags,
    summary_lines,
)
from fohssv_sim.params import ParameterError

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'

SMALL = dict(controller='state_feedback', bounds=(Bound('pitch_rate_gain', -1.0, -0.1),
                                                  Bound('vertical_velocity_gain', 0.0, 0.3)),
             envelope_speeds=(75.0,), envelope_alphas=(0.8, 0.9), duration=0.04,
             transient=0.02, budget=10, population=5, seed=7, chunk_size=4)
# (one V: the scenarios share each candidate's equilibrium; 0.04 s runs: resume is about the
# chunks and the optimiser's sequence, not the classes. Its search scores the RMS effort,
# which differs between candidates from the first sample: the peak |Fp| of so short a run is
# the gains' common start, every candidate ties, and differential evolution stops, converged.
# Seed 3: continued to a third generation, the search finds a new winner there)
RESUME = {**SMALL, 'objective': 'effort', 'seed': 3}
#: the FOM's default step (docs/model.md), the step of these searches
RESUME_STEP = 2e-5


def _row(outcome='steady', alpha_c=0.9, alpha=0.85, peak_fp=30.0):
    return {'outcome': outcome, 'alpha_c': alpha_c, 'alpha': alpha, 'peak_fp': peak_fp}


def test_score_orders_lexicographically():
    spec = TuneSpec(**SMALL)
    # classes first, then the margin's shortfall below min_margin, then the metric
    ranked = [
        [_row(peak_fp=10.0), _row(alpha_c=0.871, peak_fp=20.0)],        # margin 0.021: ties
        [_row(peak_fp=25.0), _row(alpha_c=0.95, peak_fp=25.0)],
        [_row(alpha_c=0.86, peak_fp=1.0), _row(peak_fp=1.0)],           # margin 0.01 < 0.02
        [_row(alpha_c=0.80, peak_fp=1.0), _row(peak_fp=1.0)],           # Matignon-unstable
        [_row('periodic', peak_fp=1.0), _row(alpha_c=2.0, peak_fp=1.0)],
        [_row('periodic'), _row('periodic')],
        [_row('chaotic'), _row()],
        [_row('diverged', peak_fp=math.inf), _row()]]
    values = [score(rows, spec, affine=True)['value'] for rows in ranked]
    assert values == sorted(values) and len(set(values)) == len(values)
    s = score(ranked[0], spec, affine=True)
    assert s['margin'] == pytest.approx(0.021) and s['metric'] == 20.0
    assert s['not_steady'] == 0 and s['outcome'] == 'steady'
    # without a linearisation the margin is not a level: the metric decides
    no_lin = score(ranked[3], spec, affine=False)
    assert no_lin['margin'] is None and no_lin['value'] < score(ranked[0], spec, True)['value']


def test_peak_metric_can_leave_out_the_start_up_transient():
    """peak-fp takes the whole run's peak |Fp| by default (the start-up transient in it); with
    peak_after_transient the peak after the transient: two candidates' rows whose order the
    two metrics reverse. The option enters a search's identity only when set, so searches run
    before it resume."""
    rows = [{**_row(peak_fp=500.0), 'peak_fp_window': 30.0},
            {**_row(peak_fp=400.0), 'peak_fp_window': 40.0}]
    whole, after = TuneSpec(**SMALL), TuneSpec(**SMALL, peak_after_transient=True)
    assert score(rows, whole, affine=True)['metric'] == 500.0
    assert score(rows, after, affine=True)['metric'] == 40.0
    assert score(rows[1:], whole, True)['value'] < score(rows[:1], whole, True)['value']
    assert score(rows[:1], after, True)['value'] < score(rows[1:], after, True)['value']
    assert 'peak_after_transient' not in whole.identity()
    assert after.identity()['peak_after_transient'] is True


def test_step_check_flags_a_changed_class_or_a_moved_metric():
    def rows(*cases):
        return [{'scenario': k, 'alpha': 0.8, 'speed': 60.0 + k, 'outcome': o, 'peak_fp': m}
                for k, (o, m) in enumerate(cases)]

    at_h = rows(('steady', 100.0), ('steady', 100.0), ('periodic', 200.0), ('steady', 50.0),
                ('diverged', math.inf), ('steady', 0.0))
    half = rows(('steady', 100.0 * (1 + CHECK_RTOL / 2)),    # within the tolerance
                ('steady', 100.0 * (1 + 2 * CHECK_RTOL)),    # the metric moved: flagged
                ('steady', 200.0),                           # the class changed: flagged
                ('steady', 50.0), ('diverged', math.inf),    # unchanged (inf == inf)
                ('steady', 1.0))                             # from 0: an infinite change
    flags, changes = step_flags(at_h, half, 'peak_fp')
    assert [f['scenario'] for f in flags] == [1, 2, 5]
    assert changes[:5] == pytest.approx([CHECK_RTOL / 2, 2 * CHECK_RTOL, 0.0, 0.0, 0.0])
    assert flags[1]['half_step_outcome'] == 'steady' and math.isinf(changes[5])


def test_scheduled_law_interpolates_its_table_and_is_eq31_by_default():
    x = [0.01, 0.3, 0.02, -0.1]
    for v in (50.0, 75.0, 130.0):
        assert Scheduled(speed=v).command(0.0, x) == StateFeedback().command(0.0, x)
    law = Scheduled(speed=90.0, pitch_rate_gain_2=-0.5, pitch_rate_gain_3=-1.0,
                    vertical_velocity_gain_3=0.2)          # rows at 80 and 100 m/s
    ref = StateFeedback(pitch_rate_gain=-0.75, vertical_velocity_gain=0.1)
    assert law.command(0.0, x) == pytest.approx(ref.command(0.0, x), abs=1e-15)
    assert law.affine()[0][1] == pytest.approx([15.0, 0.1, -30.0, -0.75])
    assert Scheduled(speed=200.0, pitch_rate_gain_4=-2.0).gains_at(200.0)[3] == -2.0
    with pytest.raises(ParameterError, match='speed_3=70.0 is not above speed_2=80.0'):
        Scheduled(speed_3=70.0)


class _Tick:
    """A clock for :func:`generation_line` that says nothing about time."""

    def tick(self, computed):
        return 0.0, None


@pytest.fixture
def client(dask_client):
    return dask_client


@pytest.fixture(scope='module')
def resume_search(tmp_path_factory, dask_cluster):
    """The search of ``RESUME`` run once for the tests below that read it or change a copy of
    its folder (its chunks and optimiser sequence are the same in every run)."""
    from dask.distributed import Client

    folder = tmp_path_factory.mktemp('tune') / 'search'
    with Client(dask_cluster) as client:
        return run_tune(TuneSpec(**RESUME), folder, client=client), folder


def test_interrupted_search_resumes_to_the_same_winner(tmp_path, client, resume_search):
    spec = TuneSpec(**RESUME)
    full, folder = resume_search
    shutil.copytree(folder, tmp_path / 'full')
    rec = full.record
    assert len(rec['generations']) == 2 and full.computed_chunks == 6   # 10 points / 4
    # the winner's generation numbered from 1, as the progress lines number them
    from fohssv_sim.cli.tune import generation_line

    g = rec['winner']['generation']
    assert f'winner (generation {g + 1}, ' in '\n'.join(summary_lines(full))
    assert generation_line(rec['generations'][g], 2, 2, _Tick()).startswith(
        f'generation {g + 1}/2')
    # interrupted in the second generation: one chunk written, the rest not; no final record
    part = tmp_path / 'part'
    shutil.copytree(tmp_path / 'full', part)
    gen1 = part / 'generations' / 'gen_0001' / 'chunks'
    for f in sorted(gen1.glob('chunk_*.csv'))[1:]:
        f.unlink()
    side = json.loads((part / 'tune.json').read_text())
    side['generations'] = side['generations'][:1]
    side.pop('winner')
    side['status'] = 'running'
    (part / 'tune.json').write_text(json.dumps(side))
    again = run_tune(spec, part, client=client)
    assert (again.computed_chunks, again.reused_chunks) == (2, 4)
    assert again.winner['values'] == rec['winner']['values']
    assert again.winner['score'] == json.loads((tmp_path / 'full' / 'tune.json').read_text())[
        'winner']['score']
    assert [g['best_value'] for g in again.record['generations']] == [
        g['best_value'] for g in rec['generations']]
    # a larger budget continues the same search: two generations read back, one more run
    more = run_tune(TuneSpec(**{**RESUME, 'budget': 15}), part, client=client)
    assert (more.computed_chunks, more.reused_chunks) == (3, 6)
    assert [g['best_value'] for g in more.record['generations'][:2]] == [
        g['best_value'] for g in rec['generations']]
    with pytest.raises(TuneError, match='holds a different search'):
        run_tune(TuneSpec(**{**RESUME, 'seed': 8}), part, client=client)


def test_continued_search_with_a_new_winner_checks_the_new_winner(tmp_path, client,
                                                                  resume_search):
    """--check-step on a search continued with a larger budget whose winner changed: the new
    winner is re-run at half the step (its own folder; the old winner's check was refused as
    'a different job' before), with the same record as an uninterrupted search of that
    budget. The first search is the module's (its two generations read back, its winner
    checked here)."""
    spec = {**RESUME, 'check_step': True}
    shutil.copytree(resume_search[1], tmp_path / 'cont')
    first = run_tune(TuneSpec(**{**spec, 'budget': 10}), tmp_path / 'cont', client=client)
    assert first.computed_chunks == 0 and 'check_step' in first.record
    more = run_tune(TuneSpec(**{**spec, 'budget': 15}), tmp_path / 'cont', client=client)
    assert first.record['winner']['generation'] < 2 == more.record['winner']['generation']
    fresh = run_tune(TuneSpec(**{**spec, 'budget': 15}), tmp_path / 'fresh', client=client)
    def same(a, b):     # equal records (NaN too)
        return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)

    assert same(more.record['winner'], fresh.record['winner'])
    assert same(more.record['check_step'], fresh.record['check_step'])
    assert more.record['check_step']['step'] == RESUME_STEP / 2
    w = more.record['winner']
    job = json.loads((tmp_path / 'cont' / 'check_step' /
                      f"gen_{w['generation']:04d}_{w['candidate']:03d}" / 'job.json').read_text())
    assert job['spec']['candidates'] == [w['values']] and job['spec']['step_factor'] == 0.5


def test_check_step_added_on_a_rerun_checks_the_search_already_run(tmp_path, client,
                                                                   resume_search):
    """--check-step is not part of a search's identity: a rerun that adds it reads the
    generations back and checks their winner (it was refused as 'a different search', and
    the default folder, named from the identity, was another one: the search ran again)."""
    from fohssv_sim.cli.common import job_name

    plain = TuneSpec(**RESUME)
    checked = TuneSpec(**{**RESUME, 'check_step': True})
    assert job_name('state_feedback', plain.identity()) == job_name('state_feedback',
                                                                    checked.identity())
    first, folder = resume_search
    shutil.copytree(folder, tmp_path / 'search')
    assert 'check_step' not in first.record
    again = run_tune(checked, tmp_path / 'search', client=client)
    assert again.computed_chunks == 0 and again.reused_chunks == first.computed_chunks
    assert again.winner['values'] == first.winner['values']
    assert again.record['check_step']['step'] == RESUME_STEP / 2
    assert len(again.record['check_step']['half_step']) == len(plain.scenarios())


def test_a_generation_folder_of_another_job_is_refused_as_such(tmp_path, client,
                                                               resume_search):
    """A generation folder that holds another job (as those written before --check-step
    left a search's identity: their job.json carries it) is refused with the TuneError
    naming the folder, not with scipy's RuntimeError about its map-like callable (which
    wraps any ValueError raised in a generation: the CLI said 'internal error', exit 70)."""
    spec = TuneSpec(**RESUME)
    shutil.copytree(resume_search[1], tmp_path / 'old')
    job = tmp_path / 'old' / 'generations' / 'gen_0000' / 'job.json'
    d = json.loads(job.read_text())
    d['spec']['tune']['check_step'] = True
    job.write_text(json.dumps(d))
    with pytest.raises(TuneError, match='gen_0000 holds a different job'):
        run_tune(spec, tmp_path / 'old', client=client)


def test_fractional_pid_is_tuned_on_simulated_classes_and_metrics_only(tmp_path, client):
    """``fractional_pid`` (issue 24, item 2): no linearisation, so no margin level; its
    tuned gains and fractional orders reach the law that runs, point by point. The winner's
    worst RMS effort is checked against its own closed loops run by ``simulate`` outside the
    search, and the tuned derivative order is shown to change that number."""
    from fohssv_controller.fractional_pid import FractionalPID
    from fohssv_sim.params import ModelParameters
    from fohssv_sim.simulate import simulate

    spec = TuneSpec(**{**RESUME, 'controller': 'fractional_pid',
                       'bounds': (Bound('pitch_kd', -1.0, -0.1),
                                  Bound('derivative_order', 0.5, 1.0))})
    run_tune(spec, tmp_path / 'fpid', client=client)
    rec = json.loads((tmp_path / 'fpid' / 'tune.json').read_text())    # as written
    cands = [c for g in rec['generations'] for c in g['candidates']]
    assert len(cands) == 10 and all(c['valid'] for c in cands)
    # level 2 is skipped: no margin, no shortfall, no equilibrium in the rows
    assert all(c['margin'] is None and c['shortfall'] == 0.0 and not c['linearised']
               for c in cands)
    assert all(r['path'] == 'per-point' and r['alpha_c'] is None
               for r in rec['winner']['scenarios'])
    w = rec['winner']
    assert w['score']['value'] == min(c['value'] for c in cands)
    # the winner's closed loops, run outside the search from its reported values
    rms = {}
    for a in spec.envelope_alphas:
        p = ModelParameters(speed=75.0, fractional_order=a)
        law = FractionalPID(**w['values'])
        run_ = simulate(p, law, spec.duration, control_period=1e-4, sample_every=5)
        rms[a] = float(np.sqrt(np.mean(run_.inputs[:, 1] ** 2)))
        row = next(r for r in w['scenarios'] if r['alpha'] == a)
        assert row['effort_rms'] == pytest.approx(rms[a], rel=1e-12)
    assert w['score']['metric'] == pytest.approx(max(rms.values()), rel=1e-12)
    # the tuned order is not ignored: another derivative order, another effort
    other = {**w['values'],
             'derivative_order': 0.5 if w['values']['derivative_order'] > 0.75 else 1.0}
    p = ModelParameters(speed=75.0, fractional_order=spec.envelope_alphas[0])
    moved = simulate(p, FractionalPID(**other), spec.duration, control_period=1e-4,
                     sample_every=5)
    assert not math.isclose(float(np.sqrt(np.mean(moved.inputs[:, 1] ** 2))),
                            rms[spec.envelope_alphas[0]], rel_tol=1e-6)


def run(*args):
    return subprocess.run([str(FOHSSV), 'tune', *args], capture_output=True, text=True,
                          timeout=120)


ENVELOPE = ('--envelope-speeds', '75', '--envelope-alphas', '0.85')


def test_bad_input_exits_2_with_one_line(tmp_path):
    """The installed command, as a user runs it (the other cases below run its main() in
    this process: the same code after the entry point, without a Python start each)."""
    r = run('--tune', 'pitch_gainz=-1:0', *ENVELOPE, '--out', str(tmp_path / 'bad'))
    assert r.returncode == 2, r.stderr
    assert ("state_feedback has no parameter 'pitch_gainz'; its parameters: depth_gain, "
            'max_cavitator_deflection') in r.stderr and 'Traceback' not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / 'bad').exists()


@pytest.mark.parametrize('args, text', [
    (('--controller', 'lqr', '--tune', 'depth_weight=-5:10'),
     'lqr parameter depth_weight=-5 is outside its allowed range [0, 1e+12] 1/m^2'),
    (('--tune', 'pitch_rate_gain=-1:0', '--envelope-speeds', '75', '--envelope-alphas', ''),
     'the envelope is empty'),
    (('--tune', 'pitch_rate_gain=-1:0', '--envelope-speeds', '', '--envelope-alphas', '0.85'),
     'the envelope is empty'),
    (('--tune', 'pitch_rate_gain=-1:0', '--budget', '0'), 'budget=0 must be >= 1'),
    (('--controller', 'fractional_pid', '--tune', 'derivative_order=0.5:1.5'),
     'fractional_pid parameter derivative_order=1.5 is outside its allowed range (0, 1]'),
    (('--tune', 'pitch_rate_gain=0:-1'), 'need finite bounds LOW < HIGH'),
    (('--tune', 'depth_gain=-1:10:log'), 'a log-scaled bound needs LOW > 0'),
    (('--tune', 'pitch_rate_gain=-1:0', '--objective', 'fast'), "objective 'fast' is not one"),
    (('--tune', 'pitch_rate_gain=-1:0', '--budget', '4'), 'below one generation of 5'),
    (('--controller', 'scheduled', '--tune', 'speed=60:120'), 'follows the model parameter'),
    (('--tune', 'pitch_rate_gain=-1:0', '--gain', 'pitch_rate_gain=-1'), 'is tuned; do not'),
    (('--envelope-alphas', '0.85'), 'nothing to tune'),
])
def test_more_bad_input_is_refused_in_one_line(tmp_path, capsys, args, text):
    from fohssv_sim.cli import main

    full = list(args) + ([] if '--envelope-speeds' in args else ['--envelope-speeds', '75'])
    if '--envelope-alphas' not in full:
        full += ['--envelope-alphas', '0.85']
    assert main(['tune', *full, '--out', str(tmp_path / 'bad')]) == 2
    err = capsys.readouterr().err
    assert text in err and len(err.strip().splitlines()) == 1, err
    assert 'Traceback' not in err
    assert not (tmp_path / 'bad').exists()


def test_tune_step_script_reruns_the_winner_as_the_search_scored_it(tmp_path, resume_search):
    """``scripts/tune_step.py`` (the README's step and boundary tables) re-runs a search's
    winner in chosen scenarios at chosen steps: at the search's own step and scenarios it gives
    the outcome and metric the search recorded for the winner (scored there in a batched Dask
    chunk among the other candidates), and a step it is given is the step it runs."""
    import importlib.util

    result, folder = resume_search
    rec = result.record
    script = Path(__file__).resolve().parents[3] / 'scripts' / 'tune_step.py'
    out = tmp_path / 'step.json'
    # the script's own main in this process (a process start would only add its imports)
    loader = importlib.util.spec_from_file_location('tune_step', script)
    mod = importlib.util.module_from_spec(loader)
    loader.loader.exec_module(mod)
    code = mod.main([str(folder), '--alphas', '0.8,0.9', '--speeds', '75',
                     '--steps', f'{RESUME_STEP},{RESUME_STEP / 2}', '--json', str(out)])
    assert code == 0
    got = json.loads(out.read_text())
    assert got['metric'] == 'effort_rms' and got['winner'] == rec['winner']['values']
    scored = {r['alpha']: r for r in rec['winner']['scenarios']}
    at_step = [r for r in got['rows'] if r['step'] == RESUME_STEP]
    assert sorted(r['alpha'] for r in at_step) == [0.8, 0.9]
    for r in at_step:
        assert r['outcome'] == scored[r['alpha']]['outcome']
        assert r['effort_rms'] == pytest.approx(scored[r['alpha']]['effort_rms'], rel=1e-12)
    halved = [r for r in got['rows'] if r['step'] == RESUME_STEP / 2]
    assert len(halved) == 2
    # a different step is a different run (not the search's rows read back)
    assert all(r['effort_rms'] != scored[r['alpha']]['effort_rms'] for r in halved)


def test_a_documented_winner_reruns_to_its_documented_metric():
    """docs/tune_winners/eq31/tune.json (the eq. 31 winner of docs/results.md, in the layout
    scripts/tune_step.py reads) re-run with the tuner's own evaluation in the two scenarios
    that decide its worst peak (alpha = 0.7 at V = 90 and 120 m/s; the search's step, duration,
    transient and ZOH from the file): the outcome and peak |Fp| the file keeps, and the figures
    docs/results.md prints for it (periodic, 119.4 and 161 m^2/s^2)."""
    from fohssv_sim.analysis.tune import run_candidates

    root = Path(__file__).resolve().parents[3]
    rec = json.loads((root / 'docs' / 'tune_winners' / 'eq31' / 'tune.json').read_text())
    spec = {**rec['spec'], 'envelope_alphas': [0.7], 'envelope_speeds': [90.0, 120.0],
            'check_step': False}
    TuneSpec.from_dict(spec).validate()
    rows = run_candidates({'tune': spec, 'candidates': [rec['winner']['values']],
                           'step_factor': 1.0}, range(2))
    kept = {(r['alpha'], r['speed']): r for r in rec['winner']['scenarios']}
    for r, documented in zip(rows, (119.4, 161.0)):
        k = kept[(r['alpha'], r['speed'])]
        assert r['outcome'] == k['outcome'] == 'periodic'
        assert r['peak_fp'] == pytest.approx(k['peak_fp'], rel=1e-9)
        assert abs(r['peak_fp'] - documented) < 0.5, (r, documented)
    assert 'docs/tune_winners' in (root / 'docs' / 'results.md').read_text()
