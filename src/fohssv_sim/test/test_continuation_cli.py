"""`fohssv continue`: the installed console script as a user runs it (the FOM branch, real
files), and the CLI's ``main`` in this process for the other cases (the same code after the
entry point, without an interpreter importing numpy, numba, scipy and matplotlib each)."""

import json
import subprocess
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix
from clirun import fohssv

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.equilibria import find_equilibria
from fohssv_sim.params import ModelParameters

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'


def run(*args):
    return subprocess.run([str(FOHSSV), 'continue', *args], capture_output=True, text=True,
                          timeout=300, env={'OPENBLAS_NUM_THREADS': '1',
                                            **__import__('os').environ})


def in_process(capfd, *args):
    """``fohssv continue ARGS`` through :func:`fohssv_sim.cli.main`: (exit code, stdout,
    stderr)."""
    return fohssv(capfd, 'continue', *args)


def test_fom_branch_writes_branch_json_and_the_diagram(tmp_path, capfd):
    out = run('--vary', 'fractional_order=0.74:0.77', '--set', 'speed=84.5', '--points', '4',
              '--harmonics', '8', '--out', str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert 'point 2:' in out.stdout                      # progress while it runs
    data = json.loads((tmp_path / 'branch.json').read_text())
    assert data['parameter'] == 'fractional_order' and data['complete']
    assert 'harmonic balance' in data['method']
    for p in data['points']:
        assert {'value', 'frequency_hz', 'w_amplitude', 'stable'} <= set(p)
        assert p['stable'] in (True, False)             # by simulation, one per segment
    assert data['settings']['stability_runs']
    (hopf,) = [b for b in data['bifurcations'] if b['kind'] == 'hopf']
    eq = min(find_equilibria(ModelParameters(speed=84.5), StateFeedback()),
             key=lambda e: abs(e.state[1]))
    assert abs(hopf['value'] - eq.critical_order) < 1e-3
    assert (tmp_path / 'branch.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    code, again, _ = in_process(capfd, '--vary', 'fractional_order=0.74:0.77', '--set',
                                'speed=84.5', '--points', '4', '--harmonics', '8', '--out',
                                str(tmp_path))
    assert code == 0 and 'is complete' in again


def test_a_controller_gain_as_the_varied_parameter(tmp_path, capfd):
    """--vary pitch_rate_gain: the delay-free branch over the gain, its last point against a
    long simulation with the controller built at that gain (period to 1e-4)."""
    import numpy as np

    from fohssv_sim.simulate import simulate

    code, _, err = in_process(capfd, '--vary', 'pitch_rate_gain=-0.3:-0.22', '--set',
                              'model=delay-free', '--set', 'speed=75', '--points', '5',
                              '--out', str(tmp_path))
    assert code == 0, err
    data = json.loads((tmp_path / 'branch.json').read_text())
    assert data['parameter'] == 'pitch_rate_gain'
    last = data['points'][-1]
    assert last['value'] == -0.22 and last['stable'] is True
    r = simulate(ModelParameters(model='delay-free', speed=75.0),
                 StateFeedback(pitch_rate_gain=-0.22), 2.5, sample_every=4)
    t, w = r.t[r.t > 1.5], r.state[r.t > 1.5, 1]
    up = np.where((w[:-1] < w.mean()) & (w[1:] >= w.mean()))[0]
    cross = t[up] + (w.mean() - w[up]) / (w[up + 1] - w[up]) * (t[up + 1] - t[up])
    assert last['period_s'] == pytest.approx(np.mean(np.diff(cross)), rel=1e-4)
    code, _, err = in_process(capfd, '--vary', 'pitch_rate_gain=-0.3:-0.2', '--gain',
                              'pitch_rate_gain=-0.1', '--set', 'model=delay-free', '--out',
                              str(tmp_path / 'b'))
    assert code == 2 and 'both given' in err


@pytest.mark.parametrize('args, text', [
    (('--vary', 'model=0:1'), "'model' is not a numeric model parameter"),
    (('--vary', 'speed=abc:90'), 'START:END must be two numbers'),
    (('--vary', 'fractional_order=0.5:1.5'), 'fractional_order=1.5'),
    (('--vary', 'speed'), 'must look like NAME=START:END'),
    (('--vary', 'fractional_order=0.8:0.9', '--set', 'speed=75'), 'no Hopf point'),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capfd, args, text):
    code, _, err = in_process(capfd, *args, '--out', str(tmp_path))
    assert code == 2, err
    assert text in err and 'Traceback' not in err
    assert len(err.strip().splitlines()) == 1
