"""``fohssv tune`` (issue 24) as a user runs it, and its winner on a real graph.

One small search (the ``scheduled`` law, one pitch-rate gain per speed band, over the envelope
V {70, 90} m/s x alpha 0.85) is run by the installed ``fohssv`` command. Its winner must be
steady everywhere with the Matignon margin that the equilibria module gives for eq. 31 with
the same gains at each V (the scheduled law at a breakpoint is eq. 31; the gain map of
eq. 31 puts the boundary alpha_c = 0.85 near pitch_rate_gain = -0.45 at 75 m/s). Then the
winner's parameters file, loaded by the real generic controller node, runs against the real
plant in lockstep over DDS at both corners of the envelope and gives the class the tuner
reported there.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from ament_index_python.packages import get_package_prefix
from PIL import Image
from test_graph_support import Probe, plant_args, stop_all

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.analysis.gainmap import outcome
from fohssv_sim.analysis.orbits import classify
from fohssv_sim.equilibria import find_equilibria
from fohssv_sim.params import ModelParameters

import rosproc

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'
SPEEDS = (70.0, 90.0)
ALPHA = 0.85
DURATION, TRANSIENT = 0.6, 0.4


@pytest.fixture(scope='module')
def tuned(tmp_path_factory):
    out = tmp_path_factory.mktemp('tune')
    r = subprocess.run(
        [str(FOHSSV), 'tune', '--controller', 'scheduled', '--gain', 'speed_1=70',
         '--gain', 'speed_2=90', '--tune', 'pitch_rate_gain_1=-1:-0.1,pitch_rate_gain_2=-1:-0.1',
         '--envelope-speeds', ','.join(f'{v:g}' for v in SPEEDS), '--envelope-alphas',
         f'{ALPHA:g}', '--duration', str(DURATION), '--transient', str(TRANSIENT),
         '--budget', '10', '--population', '5', '--seed', '3', '--workers', '1',
         '--out', str(out)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return out, r.stdout, json.loads((out / 'tune.json').read_text())


def test_winner_is_steady_with_the_margin_of_the_equilibria_module(tuned):
    out, stdout, rec = tuned
    assert rec['status'] == 'done' and len(rec['generations']) == 2
    assert all(len(g['candidates']) == 5 for g in rec['generations'])   # every generation
    w = rec['winner']
    assert [r['outcome'] for r in w['scenarios']] == ['steady', 'steady']
    # alpha_c of eq. 31 with the winner's gain of each band, by an independent root search
    margins = []
    for k, v in enumerate(SPEEDS, start=1):
        law = StateFeedback(pitch_rate_gain=w['values'][f'pitch_rate_gain_{k}'])
        eqs = find_equilibria(ModelParameters(speed=v), law)
        e = min(eqs, key=lambda e: abs(e.state[1]))
        margins.append(e.critical_order - ALPHA)
    assert abs(w['score']['margin'] - min(margins)) < 1e-9
    assert min(margins) >= rec['spec']['min_margin']     # the Matignon-stable side
    assert 'worst steady, 0/2 scenario(s) not steady' in stdout
    # progress: a line per generation with the best score so far, elapsed time and ETA
    assert 'generation 1/2: best so far score ' in stdout and ' s left' in stdout
    assert 'generation 2/2: best so far score ' in stdout
    for stem in ('envelope', 'history'):
        png = out / f'{stem}.png'
        with Image.open(png) as im:
            im.verify()
        assert png.stat().st_size > 5000 and (out / f'{stem}.svg').exists()
    text = (out / 'winner.yaml').read_text()
    params = yaml.safe_load(text)['/**']['ros__parameters']
    assert params['controller'] == 'scheduled'
    assert params['pitch_rate_gain_1'] == w['values']['pitch_rate_gain_1']
    assert params['speed_1'] == 70.0 and params['speed_2'] == 90.0


def _graph_run(yaml_file: Path, speed: float) -> tuple[str, float, str]:
    """(class of w after the transient, peak |Fp|, the nodes' output) of the winner hosted
    by the generic controller node against the plant in lockstep at ``speed``."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain, command_publisher=False)
    ctl = rosproc.start('fohssv_controller', 'controller', [
        '--ros-args', '--params-file', str(yaml_file), '-p', f'speed:={speed}'], env=env)
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model='fractional', speed=speed, fractional_order=ALPHA, duration=DURATION,
        min_state_subscribers=2, pace_to_subscribers=512, end_linger=60.0), env=env)
    n = round(DURATION / 1e-4) + 1
    try:
        probe.wait(lambda: (len(probe.states) >= n and len(probe.forces) >= n)
                   or plant.poll() is not None, 180, f'{n} samples at the probe')
        out = stop_all(plant, ctl)
        assert plant.returncode == 0, out
        states = probe.state_array()
        forces = np.array(probe.forces)
    finally:
        stop_all(plant, ctl)
        probe.close()
    assert states.shape == (n, 5), out
    assert np.allclose(np.diff(states[:, 0]), 1e-4)
    t, w = states[:, 0], states[:, 2]
    win = t >= TRANSIENT - 1e-12
    cls, _ = classify(t[win], w[win], rel_tol=1e-3)
    return outcome(cls.kind), float(np.max(np.abs(forces[:, 1]))), out


def test_winner_yaml_in_the_real_controller_node_gives_the_reported_class(tuned):
    out, _, rec = tuned
    reported = {r['speed']: r for r in rec['winner']['scenarios']}
    for speed in SPEEDS:
        cls, peak, log = _graph_run(out / 'winner.yaml', speed)
        assert f'speed={speed:g}' in log                # the node hosts the winner at V
        assert cls == reported[speed]['outcome'], (speed, cls, reported)
        # the same run: the batched search's peak |Fp| (to its 1e-10 agreement with simulate)
        assert math.isclose(peak, reported[speed]['peak_fp'], rel_tol=1e-8), (peak, speed)
