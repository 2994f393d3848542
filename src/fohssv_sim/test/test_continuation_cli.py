"""`fohssv continue` as a user runs it: the installed console script, real files."""

import json
import subprocess
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.equilibria import find_equilibria
from fohssv_sim.params import ModelParameters

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'


def run(*args):
    return subprocess.run([str(FOHSSV), 'continue', *args], capture_output=True, text=True,
                          timeout=300, env={'OPENBLAS_NUM_THREADS': '1',
                                            **__import__('os').environ})


def test_fom_branch_writes_branch_json_and_the_diagram(tmp_path):
    out = run('--vary', 'fractional_order=0.74:0.77', '--set', 'speed=84.5', '--points', '4',
              '--harmonics', '8', '--out', str(tmp_path))
    assert out.returncode == 0, out.stderr
    assert 'point 2:' in out.stdout                      # progress while it runs
    data = json.loads((tmp_path / 'branch.json').read_text())
    assert data['parameter'] == 'fractional_order' and data['complete']
    assert 'harmonic balance' in data['method']
    for p in data['points']:
        assert {'value', 'frequency_hz', 'w_amplitude', 'stable'} <= set(p)
        assert p['stable'] is None
    (hopf,) = [b for b in data['bifurcations'] if b['kind'] == 'hopf']
    eq = min(find_equilibria(ModelParameters(speed=84.5), StateFeedback()),
             key=lambda e: abs(e.state[1]))
    assert abs(hopf['value'] - eq.critical_order) < 1e-3
    assert (tmp_path / 'branch.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    again = run('--vary', 'fractional_order=0.74:0.77', '--set', 'speed=84.5', '--points',
                '4', '--harmonics', '8', '--out', str(tmp_path))
    assert again.returncode == 0 and 'is complete' in again.stdout


@pytest.mark.parametrize('args, text', [
    (('--vary', 'model=0:1'), "'model' is not a numeric model parameter"),
    (('--vary', 'speed=abc:90'), 'START:END must be two numbers'),
    (('--vary', 'fractional_order=0.5:1.5'), 'fractional_order=1.5'),
    (('--vary', 'speed'), 'must look like NAME=START:END'),
    (('--vary', 'fractional_order=0.8:0.9', '--set', 'speed=75'), 'no Hopf point'),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, text):
    out = run(*args, '--out', str(tmp_path))
    assert out.returncode == 2, out.stderr
    assert text in out.stderr and 'Traceback' not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
