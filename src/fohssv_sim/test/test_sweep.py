"""Batched runs and orbit-diagram sweeps: against per-point runs, Matignon, and each other."""

import csv
import json
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_prefix
from clirun import fohssv as run_cli

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.analysis.orbits import classify, local_maxima
from fohssv_sim.analysis.sweep import SweepSpec, _chunks, run_chunk
from fohssv_sim.batch import group_points, simulate_batch
from fohssv_sim.equilibria import find_equilibria
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'


@pytest.mark.parametrize('model,extra', [('delay-free', {}), ('fractional', {'solver': 'soe'}),
                                         ('fractional', {'solver': 'abm'})])
def test_batched_points_equal_per_point_runs(model, extra):
    ps = [ModelParameters(model=model, speed=v, **extra) for v in (75.0, 81.0, 88.0)]
    b = simulate_batch(ps, [StateFeedback()], 0.05, sample_every=5)
    for i, p in enumerate(ps):
        r = simulate(p, StateFeedback(), 0.05, sample_every=5)
        assert np.allclose(b.states[i], r.state, rtol=1e-12, atol=1e-14)


def test_soe_batches_points_of_different_order_and_equals_per_point_runs():
    ps = [ModelParameters(solver='soe', speed=84.5, fractional_order=a) for a in (0.7, 0.85, 0.97)]
    assert list(group_points(ps).values()) == [[0, 1, 2]]
    abm = [p.replace(solver='abm') for p in ps]
    assert list(group_points(abm).values()) == [[0], [1], [2]]
    with pytest.raises(ValueError, match='must share fractional_order'):
        simulate_batch(abm, [StateFeedback()], 0.01)
    b = simulate_batch(ps, [StateFeedback()], 0.05, sample_every=5, control_period=1e-4)
    for i, p in enumerate(ps):
        r = simulate(p, StateFeedback(), 0.05, sample_every=5, control_period=1e-4)
        assert np.allclose(b.states[i], r.state, rtol=1e-12, atol=1e-14)
    # an alpha sweep with 'soe' is chunked by size only, not by alpha
    base = ModelParameters(solver='soe').to_dict()
    base.pop('fractional_order')
    base.pop('speed')
    s = SweepSpec(base=base, alphas=tuple(np.linspace(0.6, 0.99, 10)), speeds=(84.5,),
                  chunk_size=4)
    assert _chunks(s) == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9]]


def test_batched_zero_order_hold_equals_per_point_runs():
    ps = [ModelParameters(model='delay-free', speed=v) for v in (75.0, 84.5)]
    b = simulate_batch(ps, [StateFeedback()], 0.05, control_period=1e-4)
    for i, p in enumerate(ps):
        r = simulate(p, StateFeedback(), 0.05, control_period=1e-4)
        assert np.allclose(b.states[i], r.state, rtol=1e-12, atol=1e-14)


def spec(**kw):
    base = ModelParameters(model=kw.pop('model', 'delay-free')).to_dict()
    base.pop('fractional_order')
    base.pop('speed')
    return SweepSpec(base=base, **kw)


def test_sweep_maxima_are_those_of_a_direct_simulation():
    s = spec(alphas=(0.85,), speeds=(75.0,), transient=1.2, window=0.3)
    (row,) = run_chunk(s.to_dict(), [0])
    r = simulate(ModelParameters(model='delay-free'), StateFeedback(), 1.5)
    keep = r.t >= 1.2 - 1e-12
    _, peaks = local_maxima(r.t[keep], r.state[keep, 1])
    assert row['n_maxima'] == peaks.size > 10
    assert np.allclose(row['maxima'], peaks[-64:], rtol=1e-12)
    # the delay-free tail slap at 75 m/s (docs/model.md §8, Fig. 3)
    assert row['label'] == 'periodic-1'


def test_classification_agrees_with_matignon_and_the_root_finder():
    # V = 84.5: alpha_c = 0.757 (eigenvalues of the Jacobian). Below it the FOM must settle on
    # the equilibrium found by root finding; above it, it must not.
    p = ModelParameters(speed=84.5)
    (eq,) = find_equilibria(p, StateFeedback())
    assert eq.stable(0.7) and not eq.stable(0.85)
    base = p.replace(solver='soe').to_dict()
    base.pop('fractional_order')
    base.pop('speed')
    s = SweepSpec(base=base, alphas=(0.7, 0.85), speeds=(84.5,), transient=0.5, window=0.3,
                  sample_every=2)
    # both points in one batch (one pass of the batch stepper for the two orders)
    stable, unstable = run_chunk(s.to_dict(), [0, 1])
    assert unstable['label'].startswith('periodic') and unstable['amplitude'] > 0.05
    assert stable['kind'] == 'steady'
    # the stable point's end state from the compiled single run (batched = per-point runs:
    # test_batched_points_equal_per_point_runs), also classified steady on its own
    r = simulate(p.replace(solver='soe', fractional_order=0.7), StateFeedback(), 0.8,
                 sample_every=2)
    last = r.t >= 0.5
    cls, _ = classify(r.t[last], r.state[last, 1])
    assert cls.kind == 'steady'
    # algebraic convergence: w is within 1e-4 after 0.8 s, the slow modes within a few 1e-3
    assert abs(r.state[-1, 1] - eq.state[1]) < 1e-4
    assert np.allclose(r.state[-1], eq.state, atol=[1e-3, 1e-4, 1e-3, 2e-2])


def test_alpha_star_is_within_one_grid_step_of_matignons_alpha_c():
    """Fig. 10's alpha*(V), the steady-to-oscillating boundary of the simulated orbits, on the
    sweep's default alpha grid (0.6:1:0.02) at three speeds, against alpha_c(V) from the
    eigenvalues of the Jacobian at the root-found equilibrium (Matignon: an independent
    source). Short runs: 0.3 s transient, 0.2 s window."""
    from fohssv_sim.analysis.diagrams import alpha_star
    from fohssv_sim.analysis.sweep import SweepResult
    from fohssv_sim.cli.sweep import DEFAULT_ALPHAS

    start, stop, step = (float(x) for x in DEFAULT_ALPHAS.split(':'))
    assert (start, stop, step) == (0.6, 1.0, 0.02)
    alphas = tuple(round(start + i * step, 10) for i in range(round((stop - start) / step) + 1))
    speeds = (75.0, 82.5, 90.0)
    base = ModelParameters(solver='soe').to_dict()
    base.pop('fractional_order')
    base.pop('speed')
    s = SweepSpec(base=base, alphas=alphas, speeds=speeds, transient=0.3, window=0.2,
                  sample_every=2)
    rows = run_chunk(s.to_dict(), list(range(len(s.points()))))
    assert {r['kind'] for r in rows} <= {'steady', 'periodic', 'aperiodic'}
    star = dict(alpha_star(SweepResult(rows, {})))
    for v in speeds:
        (eq,) = find_equilibria(ModelParameters(speed=v), StateFeedback())
        assert abs(star[v] - eq.critical_order) <= step, (v, star[v], eq.critical_order)


def read_chunks(out):
    rows = []
    for f in sorted((out / 'chunks').glob('chunk_*.csv')):
        with open(f) as fh:
            rows.extend(csv.DictReader(fh))
    return rows


SWEEP = ['sweep', 'V', '--set', 'model=delay-free', '--speed', '75:90:5', '--transient',
         '0.05', '--window', '0.05', '--chunk-size', '1']


def fohssv(argv, capfd) -> tuple[int, str, str]:
    """``fohssv ARGV`` through the CLI's ``main`` in this process: (exit code, stdout,
    stderr). The installed script is run where it is the subject (a killed client, its own
    local cluster of worker processes)."""
    return run_cli(capfd, *argv)


def test_interrupted_sweep_resumes_without_recomputing_finished_chunks(tmp_path, dask_cluster,
                                                                       capfd):
    out = tmp_path / 'sweep'
    proc = subprocess.Popen([str(FOHSSV), *SWEEP, '--workers', '1', '--out', str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        done = list((out / 'chunks').glob('chunk_*.csv')) if out.exists() else []
        if done or proc.poll() is not None:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)   # the client and its local cluster
    proc.wait()
    finished = {f.name: f.stat().st_mtime_ns for f in (out / 'chunks').glob('chunk_*.csv')}
    assert finished, 'no chunk finished before the kill'
    side = json.loads((out / 'sweep.json').read_text())
    assert side['step'] == 1e-5 and side['solver'] == 'rk4' and len(side['chunks']) == 4
    # the resumed run on the session's cluster of threads, in this process: what it resumes
    # from is the folder, not the killed cluster (no worker processes to start a second time)
    code, stdout, err = fohssv([*SWEEP, '--out', out, '--scheduler',
                                dask_cluster.scheduler_address], capfd)
    assert code == 0, err
    assert f'{len(finished)} reused' in stdout or f'{4 - len(finished)} chunks computed' \
        in stdout
    for name, mtime in finished.items():
        assert (out / 'chunks' / name).stat().st_mtime_ns == mtime   # not recomputed
    assert len(read_chunks(out)) == 4
    assert (out / 'orbit_V.png').stat().st_size > 5000


def test_same_results_with_the_local_default_and_an_explicit_cluster(tmp_path, dask_cluster,
                                                                     capfd):
    """The sweep's own local cluster (``--workers 1``: a worker process) and an explicit one
    (``--scheduler``: the session's cluster of threads) give the same rows; both commands run
    in this process (the installed script, with its own local cluster, is run by the
    interrupted sweep above)."""
    a, b = tmp_path / 'local', tmp_path / 'cluster'
    code, _, err = fohssv([*SWEEP, '--workers', '1', '--out', a], capfd)
    assert code == 0, err
    code, _, err = fohssv([*SWEEP, '--out', b, '--scheduler', dask_cluster.scheduler_address],
                          capfd)
    assert code == 0, err
    assert read_chunks(a) == read_chunks(b)


def test_sweep_rejects_bad_input_in_one_line(tmp_path, capfd):
    """In-process through the CLI's ``main`` (the installed script is run by the other
    tests here and by test_cli_bad_input's sample)."""
    for args, text in [(['--alpha', '0.5:1.2:0.1'],
                        'fractional_order=1.1 is outside the allowed range (0, 1]'),
                       (['--set', 'length=-1'], 'length=-1.0'),
                       (['--window', '0'], '--window')]:
        code, _, err = fohssv(['sweep', 'alpha', *args, '--out', tmp_path], capfd)
        assert code == 2 and text in err and 'Traceback' not in err, err


def test_progress_counts_points_inside_a_chunk_and_writes_lines_to_a_pipe(tmp_path, capfd,
                                                                            dask_cluster):
    # three FOM points batch into one chunk (one Dask task on one worker, so one worker is all
    # it can use): progress still advances point by point, from the worker (its events reach
    # this client through the scheduler, over TCP); stderr is not a terminal, so no carriage
    # returns
    code, stdout, err = fohssv(['sweep', 'alpha', '--set', 'solver=soe', '--alpha',
                                '0.8,0.9,1.0', '--speed', '84.5', '--transient', '0.05',
                                '--window', '0.05', '--scheduler',
                                dask_cluster.scheduler_address, '--check-step', '1', '--out',
                                tmp_path / 's'], capfd)
    assert code == 0, err
    assert '1 chunks computed' in stdout
    assert '\r' not in err
    done = [int(m) for m in re.findall(r'^  points (\d)/3 ', err, re.M)]
    assert done == sorted(set(done)) and done[-1] == 3 and done[0] < 3, err
    checked = [int(m) for m in re.findall(r'^  step check: points at half step (\d)/3 ',
                                          err, re.M)]
    assert checked and checked[-1] == 3, err
