"""Gain maps (issue 15): the Matignon boundary of the linearisation against the simulated
classes, batched against per-point runs, resume, and ``fohssv gainmap`` through the CLI."""

import json
import math
import shutil

import numpy as np
import pytest
from clirun import fohssv
from PIL import Image

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.analysis.gainmap import GainMapError, GainMapSpec, run_gain_map, run_points
from fohssv_sim.equilibria import find_equilibria
from fohssv_sim.params import ModelParameters

# pitch_rate_gain moves alpha_c of the eq. 31 loop across 0.85 (about -0.45 at w-gain 0),
# the w gain tilts the boundary
GRID = dict(controller='state_feedback', gain_x='pitch_rate_gain',
            x_values=(-1.0, -0.6, -0.3, -0.1), gain_y='vertical_velocity_gain',
            y_values=(-0.1, 0.0, 0.1, 0.25), alpha=0.85, speed=75.0, duration=0.6,
            transient=0.4)
MARGIN = 0.03


@pytest.fixture(scope='module')
def grid_rows():
    spec = GainMapSpec(**GRID)
    spec.validate()
    return spec, run_points(spec.to_dict(), list(range(spec.n_points)))


def test_matignon_boundary_and_simulated_classes_agree_away_from_the_boundary(grid_rows):
    spec, rows = grid_rows
    assert all(r['path'] == 'batched' for r in rows)
    # alpha_c of each row from an independent call of the root finder on that pair's law
    for r in rows[::5]:
        law = StateFeedback(pitch_rate_gain=r['x'], vertical_velocity_gain=r['y'])
        eqs = find_equilibria(ModelParameters(speed=75.0), law)
        e = min(eqs, key=lambda e: abs(e.state[1]))
        assert abs(e.critical_order - r['alpha_c']) < 1e-9
    # the paper's law (-0.3, 0): alpha_c ~ 0.732 (issue 15: 0.73-0.77), equilibrium of the
    # LQR design point (lqr.py: w* = 1.670 m/s, delta_c* = 0.00986 rad)
    (paper,) = [r for r in rows if r['x'] == -0.3 and r['y'] == 0.0]
    assert abs(paper['alpha_c'] - 0.732) < 2e-3
    assert abs(paper['eq_w'] - 1.670) < 1e-3 and abs(paper['eq_dc'] - 0.00986) < 1e-5
    away = [r for r in rows if abs(r['alpha_c'] - spec.alpha) > MARGIN]
    stable = [r for r in away if r['alpha_c'] > spec.alpha]
    unstable = [r for r in away if r['alpha_c'] < spec.alpha]
    assert len(stable) >= 4 and len(unstable) >= 4
    for r in stable:
        assert r['outcome'] == 'steady', r
        assert math.isfinite(r['settle_time']) and r['settle_time'] < spec.transient
    for r in unstable:
        assert r['outcome'] in ('periodic', 'chaotic', 'diverged'), r
        assert r['settle_time'] == math.inf
        # tail-slap: the planing force peaks well above the resting value of the steady loops
        assert r['peak_fp_window'] > 1.3 * max(s['peak_fp_window'] for s in stable)


def test_batched_rows_equal_per_point_simulate_rows(grid_rows):
    spec, rows = grid_rows
    idx = [1, 6]          # one steady, one tail-slapping pair
    ref = run_points(spec.to_dict(), idx, batched=False)
    assert [r['path'] for r in ref] == ['per-point'] * 2
    assert {rows[i]['outcome'] for i in idx} == {'steady', 'periodic'}
    for i, r in zip(idx, ref):
        for k in ('outcome', 'label', 'period', 'settle_time', 'alpha_c'):
            assert rows[i][k] == r[k], k
        for k in ('peak_fp', 'peak_fp_window', 'effort_rms', 'amplitude'):
            assert abs(rows[i][k] - r[k]) <= 1e-9 * abs(r[k]), k


SMALL = dict(controller='state_feedback', gain_x='pitch_rate_gain', x_values=(-0.6, -0.1),
             gain_y='depth_gain', y_values=(10.0, 20.0), duration=0.1, transient=0.05,
             envelope_speeds=(75.0, 90.0), envelope_alphas=(0.85,), chunk_size=3)


def as_text(rows):
    return [{k: repr(v) for k, v in r.items()} for r in rows]


def test_interrupted_map_resumes_to_the_same_rows(tmp_path, dask_client):
    spec = GainMapSpec(**SMALL)
    seen = []
    full = run_gain_map(spec, tmp_path / 'full', client=dask_client,
                        progress=lambda d, n, t: seen.append((d, n)))
    assert full.computed_chunks == 3 and len(full.rows) == 8
    assert seen[-1] == (8, 8) and len(seen) >= 3        # per point, not only per chunk
    # an interrupted run: chunk 1 never written, chunk 2 cut mid-write (its temp file)
    part = tmp_path / 'part'
    shutil.copytree(tmp_path / 'full', part)
    (part / 'chunks' / 'chunk_00001.csv').unlink()
    (part / 'chunks' / 'chunk_00002.csv').rename(part / 'chunks' / 'chunk_00002.tmp')
    (part / 'chunks' / 'chunk_00002.tmp').write_text('point,pair\n6,3\n')
    again = run_gain_map(spec, part, client=dask_client)
    assert (again.computed_chunks, again.reused_chunks) == (2, 1)
    assert as_text(again.rows) == as_text(full.rows)     # NaN == NaN here
    worst = again.worst()
    assert len(worst) == 4 and all(w['n_scenarios'] == 2 for w in worst)
    for w in worst:
        rs = [r for r in again.rows if r['pair'] == w['pair']]
        assert w['alpha_margin'] == min(r['alpha_c'] - 0.85 for r in rs)
    with pytest.raises(GainMapError, match='different job'):
        run_gain_map(GainMapSpec(**{**SMALL, 'duration': 0.2}), part, client=dask_client)


def run_in_process(capfd, *args) -> tuple[int, str, str]:
    """``fohssv gainmap ARGS`` through the CLI's ``main`` in this process: (exit code, stdout,
    stderr). The parser and commands the console script calls; a new interpreter importing
    numpy, numba, scipy and matplotlib would cost more than the tiny map (the installed
    script and its own local cluster are run by test_sweep and test_cli_bad_input)."""
    return fohssv(capfd, 'gainmap', *args)


@pytest.fixture(scope='module')
def cli_map(tmp_path_factory, dask_cluster):
    """``fohssv gainmap`` run once through the CLI's main in this process, its SVG text kept
    as text (``svg.fonttype`` none) for the figure tests: (exit code, stdout, folder)."""
    import contextlib
    import io

    import matplotlib

    from fohssv_sim.cli import main

    out = tmp_path_factory.mktemp('gainmap') / 'map'
    stdout = io.StringIO()
    with matplotlib.rc_context({'svg.fonttype': 'none'}), contextlib.redirect_stdout(stdout):
        code = main(['gainmap', '--x', 'pitch_rate_gain=-0.6,-0.1', '--y',
                     'vertical_velocity_gain=0:0.2:0.2', '--duration', '0.1', '--transient',
                     '0.05', '--envelope-speeds', '75,90', '--envelope-alphas', '0.85',
                     '--scheduler', dask_cluster.scheduler_address, '--check-step', '3',
                     '--out', str(out)])
    return code, stdout.getvalue(), out


def test_cli_draws_valid_figures_and_rejects_bad_input(tmp_path, capfd, cli_map):
    code, stdout, out = cli_map
    assert code == 0, stdout
    assert 'step check: 3 points re-run at half step' in stdout
    checks = json.loads((out / 'step_check.json').read_text())
    assert sorted(checks) == ['0', '3', '6']           # every 3rd of the 8 points
    assert 'worst case over 2 scenarios' in stdout and 'alpha = 0.85, V = 75 m/s' in stdout
    side = json.loads((out / 'gainmap.json').read_text())
    assert side['step'] == 2e-5 and side['spec']['control_period'] == 1e-4
    for stem in ('gainmap', 'envelope'):
        for metric in ('classes', 'settle_time', 'peak_fp', 'effort_rms'):
            png = out / f'{stem}_{metric}.png'
            assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
            with Image.open(png) as im:
                im.verify()
            assert png.stat().st_size > 5000 and (out / f'{stem}_{metric}.svg').exists()
    with Image.open(out / 'envelope_classes.png') as im:
        assert 'worst case over V ∈ [75, 90]' in im.text['Title']
    for args, text in [
            (('--x', 'pitch_gainz=1,2', '--y', 'depth_gain=1,2'),
             'no parameter \'pitch_gainz\''),
            (('--controller', 'lqr', '--x', 'depth_weight=-1,1', '--y', 'fin_weight=1,2'),
             'depth_weight=-1 is outside its allowed range [0, 1e+12]'),
            (('--x', 'pitch_rate_gain=0:-1:0.1', '--y', 'depth_gain=1,2'), 'start:stop:step'),
            (('--x', 'pitch_rate_gain=-1,0', '--y', 'depth_gain=1,2', '--alpha', '1.2'),
             '(0, 1]'),
            (('--controller', 'pid', '--x', 'a=1', '--y', 'b=1'), 'state_feedback')]:
        code, _, err = run_in_process(capfd, *args, '--out', str(tmp_path / 'bad'))
        assert code == 2, (args, err)
        assert text in err and 'Traceback' not in err, err
        assert len(err.strip().splitlines()) == 1
    code, _, err = run_in_process(capfd, '--x', 'pitch_gainz=1,2', '--y', 'depth_gain=1,2',
                               '--out', str(tmp_path / 'bad'))
    assert 'depth_gain, max_cavitator_deflection' in err      # lists the parameters
    assert np.isfinite(side['n_points'])


def test_map_figures_carry_units_the_unstable_side_and_the_papers_gains(cli_map):
    """The class map as saved (the CLI's, an SVG with text kept as text): axes named with the
    gains' units from the controller's parameter table, the Matignon-unstable cells labelled
    α_c < α (the side where the linearisation is unstable), and the paper's gains (eq. 31:
    pitch-rate gain -0.3, w gain 0) marked where the grid spans them."""
    import csv

    _, stdout, out = cli_map
    svg = (out / 'gainmap_classes.svg').read_text()
    assert str(out / 'gainmap_classes.png') in stdout       # the figures it says it wrote
    assert 'pitch_rate_gain (rad s/rad)' in svg and 'vertical_velocity_gain (rad s/m)' in svg
    assert 'linearisation unstable (α_c &lt; α)' in svg and 'α_c − α)' not in svg
    assert "the paper's gains (eq. 31: -0.3, 0)" in svg.replace('&#39;', "'")
    # every unstable mark is a pair whose alpha_c is below alpha (independent: the rows'
    # alpha_c comes from the Jacobian's eigenvalues)
    rows = [r for f in sorted((out / 'chunks').glob('chunk_*.csv'))
            for r in csv.DictReader(f.read_text().splitlines())]
    assert any(float(r['alpha_c']) < float(r['alpha']) for r in rows if r['speed'] == '75.0')
