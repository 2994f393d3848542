"""The plant node's handling of commands, in the test process: bad ones rejected with the last
good one held, a lowered deflection limit clamping the held one. The controller is an
:class:`inprocess.Probe` on the plant's executor; every run is lockstep and so exactly the
batch run of the law the plant applied."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.parameter import Parameter
from test_graph_support import batch_samples

import rosproc

pytestmark = pytest.mark.node

TOL = 1e-12
T = 1e-4  # default control period


def test_bad_commands_are_rejected_and_the_last_good_one_is_held(graph, capfd):
    """Good commands delta_c = 0.001 k at sample k, except a NaN, an out-of-range and a
    wrong-length answer at samples 3, 4, 5: the plant holds the command of sample 2 over
    those periods, so the trajectory is the batch run of that law. (The FOM plant, which takes
    its commands in compiled code, is the process test's case.)"""
    bad = {3: lambda t: [t, math.nan, 0.0], 4: lambda t: [t, 0.0, 0.9],
           5: lambda t: [t, 0.0]}

    def answer(t, x):
        k = round(t / T)
        return bad[k](t) if k in bad else [t, 0.0, 0.001 * k]

    def applied(t, x):
        k = round(t / T)
        return (0.0, 0.001 * (2 if k in bad else k))

    probe = graph.probe(answer)
    plant = graph.plant(model='delay-free', duration=0.02)
    assert graph.run(plant) == 0
    graph.wait(lambda: len(probe.states) >= 201, 30, 'all samples')
    out = capfd.readouterr().err
    rejected = [ln for ln in out.splitlines() if 'rejected command' in ln]
    assert len(rejected) == 3, out
    assert 'non-finite delta_f=nan' in rejected[0]
    assert 'delta_c=0.9 rad exceeds max_cavitator_deflection=0.5 rad' in rejected[1]
    assert 'expected 3 values' in rejected[2]
    assert all('keeping the last good command delta_f=0.0, delta_c=0.002 rad' in ln
               for ln in rejected)
    summary = rosproc.summary(out)
    assert summary['rejected_commands'] == 3 and summary['compiled_take'] is False
    ref, _ = batch_samples('delay-free', applied, 0.02)
    got = probe.state_array()
    assert got.shape == ref.shape
    assert np.max(np.abs(got - ref)) <= TOL


def test_lowering_a_deflection_limit_clamps_the_held_command(graph, capfd):
    """Issue 12, defect 6: every state is answered with delta_c = -0.11 rad; at sample 20
    max_cavitator_deflection is lowered to 0.001 rad, after which those commands are
    rejected, and the command the plant holds must be the clamped -0.001 rad, not the old
    -0.11 rad. The batch run of that law is the trajectory."""
    plant = None
    results = []

    def answer(t, x):
        if round(t / T) == 20:
            results.extend(plant.set_parameters(
                [Parameter('max_cavitator_deflection', value=0.001)]))
        return [t, 0.0, -0.11]

    probe = graph.probe(answer)
    # open loop at a fixed deflection the vehicle leaves |w| <= V after about 0.24 s
    plant = graph.plant(model='delay-free', duration=0.05)
    assert graph.run(plant) == 0
    graph.wait(lambda: len(probe.states) >= 501, 30, 'all samples')
    out = capfd.readouterr().err
    assert [r.successful for r in results] == [True]
    changed = [ln for ln in out.splitlines() if 'deflection limits now' in ln]
    assert len(changed) == 1, out
    assert ('max_cavitator_deflection=0.001 rad at t=' in changed[0] and
            'the held command delta_f=0.0, delta_c=-0.11 rad is beyond them; holding the '
            'clamped command delta_f=0.0, delta_c=-0.001 rad' in changed[0]), changed
    rejected = [ln for ln in out.splitlines() if 'rejected command' in ln]
    assert rejected and all('delta_c=-0.11 rad exceeds max_cavitator_deflection=0.001 rad'
                            in ln and 'keeping the last good command delta_f=0.0, '
                            'delta_c=-0.001 rad' in ln for ln in rejected), rejected
    ref, _ = batch_samples('delay-free',
                           lambda t, x: (0.0, -0.11 if round(t / T) < 20 else -0.001), 0.05)
    got = probe.state_array()
    assert got.shape == ref.shape
    assert np.max(np.abs(got - ref)) <= TOL
