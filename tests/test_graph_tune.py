"""``fohssv tune`` (issue 24) as a user runs it, and its winner on a real graph.

One small search (the ``scheduled`` law, one pitch-rate gain per speed band, over the envelope
V {70, 90} m/s x alpha 0.85) is run by the command's own entry point (``fohssv_sim.cli.main``,
what the installed ``fohssv`` calls; in this process, its Dask workers processes of their
own). Its winner must be steady everywhere with the Matignon margin that the equilibria module
gives for eq. 31 with the same gains at each V (the scheduled law at a breakpoint is eq. 31;
the gain map of eq. 31 puts the boundary alpha_c = 0.85 near pitch_rate_gain = -0.45 at
75 m/s). Then the winner's parameters file, loaded by the real generic controller node, runs
against the real plant in lockstep over DDS at both corners of the envelope (separate
processes, both corners at once on their own domains) and gives the class the tuner reported.

Sizes: 0.4 s runs (the class from the last 0.15 s) at a step of 5e-5 s (2 per control
period), the search's and the plant's alike: the claims compare the tuner with an
independent root search and with the plant, at the same step, so the step need not be the
converged one; the winner of these gains settles well inside 0.25 s at both speeds.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from test_graph_support import Probe, plant_args, stop_all

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.analysis.gainmap import outcome
from fohssv_sim.analysis.orbits import classify
from fohssv_sim.equilibria import find_equilibria
from fohssv_sim.params import ModelParameters

import rosproc

SPEEDS = (70.0, 90.0)
ALPHA = 0.85
DURATION, TRANSIENT = 0.4, 0.25
STEP = 5e-5
#: wall-time bound of a graph run's samples reaching the probe (a lockstep run of 4000 control
#: periods takes about 2 s on a quiet machine; generous for a loaded one)
SAMPLES_TIMEOUT = 240.0


@pytest.fixture(scope='module')
def tuned(tmp_path_factory):
    from fohssv_sim.cli import main

    out = tmp_path_factory.mktemp('tune')
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(
            ['tune', '--controller', 'scheduled', '--gain', 'speed_1=70', '--gain', 'speed_2=90',
             '--tune', 'pitch_rate_gain_1=-1:-0.1,pitch_rate_gain_2=-1:-0.1',
             '--envelope-speeds', ','.join(f'{v:g}' for v in SPEEDS), '--envelope-alphas',
             f'{ALPHA:g}', '--duration', str(DURATION), '--transient', str(TRANSIENT),
             '--set', f'step={STEP:g}', '--budget', '10', '--population', '5', '--seed', '3',
             '--workers', '1', '--out', str(out)])
    assert code == 0, stdout.getvalue()
    return out, stdout.getvalue(), json.loads((out / 'tune.json').read_text())


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


def _start_graph(yaml_file: Path, speed: float):
    """The winner hosted by the generic controller node against the plant in lockstep at
    ``speed`` (own domain), with a passive probe recording states and forces."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain, command_publisher=False)
    ctl = rosproc.start('fohssv_controller', 'controller', [
        '--ros-args', '--params-file', str(yaml_file), '-p', f'speed:={speed}'], env=env)
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model='fractional', speed=speed, fractional_order=ALPHA, step=STEP, duration=DURATION,
        min_state_subscribers=2, pace_to_subscribers=512, end_linger=60.0), env=env)
    return probe, ctl, plant


def _finish_graph(probe, ctl, plant) -> tuple[str, float, str]:
    """(class of w after the transient, peak |Fp|, the nodes' output) of a started graph:
    waits until the probe holds every sample of the run (the plant lingers while the probe
    subscribes, so none is lost), bounded by SAMPLES_TIMEOUT; a plant that exits first ends
    the wait and fails below with its output."""
    n = round(DURATION / 1e-4) + 1
    try:
        probe.wait(lambda: (len(probe.states) >= n and len(probe.forces) >= n)
                   or plant.poll() is not None, SAMPLES_TIMEOUT, f'{n} samples at the probe')
        out = stop_all(plant, ctl)
        assert plant.returncode == 0, out
        states = probe.state_array()
        forces = np.array(probe.forces)
    finally:
        stop_all(plant, ctl)
        probe.close()
    assert states.shape == (n, 5), out
    assert forces.shape[0] == n, out
    assert np.allclose(np.diff(states[:, 0]), 1e-4)
    t, w = states[:, 0], states[:, 2]
    win = t >= TRANSIENT - 1e-12
    cls, _ = classify(t[win], w[win], rel_tol=1e-3)
    return outcome(cls.kind), float(np.max(np.abs(forces[:, 1]))), out


def test_winner_yaml_in_the_real_controller_node_gives_the_reported_class(tuned):
    out, _, rec = tuned
    reported = {r['speed']: r for r in rec['winner']['scenarios']}
    graphs = {}
    try:
        for speed in SPEEDS:
            graphs[speed] = _start_graph(out / 'winner.yaml', speed)
        runs = {speed: _finish_graph(*graphs.pop(speed)) for speed in SPEEDS}
    finally:
        for probe, ctl, plant in graphs.values():
            stop_all(plant, ctl)
            probe.close()
    for speed, (cls, peak, log) in runs.items():
        assert f'speed={speed:g}' in log                # the node hosts the winner at V
        assert cls == reported[speed]['outcome'], (speed, cls, reported)
        # the same run: the batched search's peak |Fp| (to its 1e-10 agreement with simulate)
        assert math.isclose(peak, reported[speed]['peak_fp'], rel_tol=1e-8), (peak, speed)
