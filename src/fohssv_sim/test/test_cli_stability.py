"""`fohssv stability` through :func:`fohssv_sim.cli.main` in the test process (the parser and
command the console script calls; the installed script itself refuses a stability row of
test_cli_bad_input's catalogue as a user runs it), real files."""

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest
from clirun import fohssv
from PIL import Image

from test_equilibria import analytic_jacobian, reduced_equilibrium


@pytest.fixture
def run(capfd):
    """``fohssv ARGS`` in this process: an object with returncode, stdout and stderr."""
    def run(*args):
        code, out, err = fohssv(capfd, *args)
        return SimpleNamespace(returncode=code, stdout=out, stderr=err)
    return run


def test_stability_reports_alpha_c_of_the_eigenvalue_formula_and_draws_the_wedge(tmp_path,
                                                                                  run):
    out = run('stability', '--set', 'speed=84.5', '--set', 'planing_form=exact',
              '--alpha', '0.7', '--speeds', '75,84.5', '--out', str(tmp_path))
    assert out.returncode == 0, out.stderr
    c, x = reduced_equilibrium(84.5)
    lam = np.linalg.eigvals(analytic_jacobian(c, x))
    alpha_c = min(abs(math.atan2(v.imag, v.real)) for v in lam) / (math.pi / 2)
    data = json.loads((tmp_path / 'stability.json').read_text())
    (eq,) = data['equilibria']
    assert np.allclose(eq['state'], x, rtol=1e-8, atol=1e-12)
    assert abs(eq['critical_order'] - alpha_c) < 1e-6
    assert eq['stable'] == (0.7 < alpha_c)
    assert abs(data['critical_order_curve'][1][1] - alpha_c) < 1e-6
    for name in ('wedge_V84.5_alpha0.7_eq0.png', 'wedge_V84.5_alpha0.7_eq0.svg',
                 'critical_order.png'):
        f = tmp_path / name
        assert f.stat().st_size > 5000
    assert (tmp_path / 'wedge_V84.5_alpha0.7_eq0.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert f'alpha_c = {alpha_c:.5f}' in out.stdout
    # the figures say what they show (titles read back from the PNG text chunk)
    with Image.open(tmp_path / 'wedge_V84.5_alpha0.7_eq0.png') as im:
        assert im.text['Title'].startswith('Matignon test at V = 84.5 m/s, α = 0.7: ')
    with Image.open(tmp_path / 'critical_order.png') as im:
        assert im.text['Title'].startswith('Critical order α_c(V)')


def test_bad_input_is_one_line_and_exit_2(tmp_path, run):
    for args, text in [(('--set', 'speed=-1'), 'speed=-1.0 is outside'),
                       (('--controller', 'pid'), 'lqr, scheduled, state_feedback'),
                       (('--gain', 'depth_gain'), 'name=value'),
                       (('--alpha', '1.5'), '(0, 1]'),
                       (('--speeds', '90:75:1'), 'start:stop:step')]:
        out = run('stability', *args, '--out', str(tmp_path))
        assert out.returncode == 2, args
        assert text in out.stderr and 'Traceback' not in out.stderr
        assert len(out.stderr.strip().splitlines()) == 1


def test_out_an_existing_file_is_one_line_and_exit_2(tmp_path, run):
    (tmp_path / 'taken').write_text('mine\n')
    for args, text in [(('--out', str(tmp_path / 'taken')), 'exists and is not a folder'),
                       (('--out', str(tmp_path / 'taken' / 'sub')), 'cannot create the folder')]:
        out = run('stability', *args)
        assert out.returncode == 2, args
        assert text in out.stderr and 'Traceback' not in out.stderr
        assert len(out.stderr.strip().splitlines()) == 1
    assert (tmp_path / 'taken').read_text() == 'mine\n'
