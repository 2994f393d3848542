"""The plant's start gate in the test process (issue 13 item 1): alone, it publishes nothing
and keeps saying that it waits for a controller; a controller that comes later runs the whole
run; one that came and left does not start it; a positive ``start_timeout`` ends a lone plant
with exit 4, in realtime mode too. A passive probe (no command publisher) listens to
``state`` and ``/clock``; the plant counts it as a state subscriber, never as a controller."""

from __future__ import annotations

import re

import numpy as np
import pytest
from test_graph_support import batch_samples

from fohssv_controller.state_feedback import StateFeedback

import rosproc

pytestmark = pytest.mark.node

TOL = 1e-12
DURATION = 0.05


def _assert_ran_fully(graph, code: int, out: str, probe) -> None:
    n = round(DURATION / 1e-4)
    assert code == 0, out
    assert 'peers matched' in out and 'stopping cleanly at t=' in out, out
    assert rosproc.summary(out)['samples'] == n, out
    graph.wait(lambda: len(probe.states) >= n + 1, 20, f'{n + 1} samples at the probe')
    ref, _ = batch_samples('delay-free', StateFeedback(), DURATION)
    got = probe.state_array()
    assert got.shape == ref.shape
    assert np.array_equal(got[:, 0], ref[:, 0])
    assert np.max(np.abs(got - ref)) <= TOL       # eq. 31 drove it, every sample
    assert probe.clocks, 'no /clock once running'


def test_plant_alone_waits_and_a_controller_started_later_runs_it(graph, capfd):
    probe = graph.probe(clock=True)
    # nothing but the model and the run's length: the default start (start_timeout 0)
    plant = graph.plant(model='delay-free', duration=DURATION)
    lines: list[str] = []

    def log() -> str:
        lines.append(capfd.readouterr().err)
        return ''.join(lines)

    graph.wait(lambda: 'waiting for a controller' in log(), 60, 'the plant saying it waits')
    graph.spin_for(6.0)                   # past the line it repeats every 5 s
    text = log()
    assert not plant.finished.done(), text
    waiting = [ln for ln in text.splitlines() if 'waiting for a controller' in ln]
    # at start (and when the probe matched), then every 5 s
    assert len(waiting) >= 2, text
    assert int(re.search(r'waited (\d+) s', waiting[-1]).group(1)) >= 5, text
    assert 'command has 0/1 publisher(s), /state has 1/1 subscriber(s)' in waiting[-1]
    assert 'no start timeout' in waiting[-1]
    assert 'ros2 run fohssv_controller state_feedback' in waiting[-1]
    assert probe.states == [] and probe.clocks == [], 'the plant ran without a controller'
    graph.controller()
    code = graph.run(plant)
    _assert_ran_fully(graph, code, log(), probe)


def test_swapping_the_controller_while_the_plant_waits(graph, capfd):
    """The plant waits for 3 state subscribers: the probe, a controller and a second probe.
    An LQR controller comes and leaves while it waits; eq. 31 then comes with the second probe,
    and the run is eq. 31's."""
    probe = graph.probe(clock=True)
    plant = graph.plant(model='delay-free', duration=DURATION, min_state_subscribers=3)
    lines: list[str] = []

    def log() -> str:
        lines.append(capfd.readouterr().err)
        return ''.join(lines)

    lqr = graph.controller('lqr')
    graph.wait(lambda: 'command has 1/1 publisher(s), /state has 2/3' in log(), 30,
               'the plant seeing the LQR controller')
    graph.remove(lqr)
    graph.wait(lambda: 'command has 0/1 publisher(s), /state has 1/3'
               in log().split('/state has 2/3', 1)[1], 30,
               'the plant seeing the LQR controller leave')
    assert not plant.finished.done() and probe.states == [] and probe.clocks == []
    graph.controller()
    graph.probe()
    code = graph.run(plant)
    _assert_ran_fully(graph, code, log(), probe)


@pytest.mark.parametrize('mode', ['lockstep', 'realtime'])
def test_a_positive_start_timeout_ends_a_lone_plant_with_exit_4(graph, capfd, mode):
    plant = graph.plant(model='delay-free', mode=mode, start_timeout=1.0)
    assert graph.run(plant, 30) == 4
    out = capfd.readouterr().err
    assert 'waiting for a controller' in out and 'start_timeout 1 s' in out
    assert ('start timeout: state has 0/1 subscriber(s), command has 0/1 publisher(s)'
            in out), out
    assert 'starting at t = 0' not in out
