"""The plant waits for its controller (issue 13 item 1), with real processes over DDS.

* Started alone with its defaults, exactly as ``ros2 run fohssv_sim plant`` starts it, the
  plant publishes nothing (no sample, no ``/clock``) and keeps saying that it waits for a
  controller; a controller started 10 s later runs the whole run: exit 0, every sample, the
  batch runner's trajectory.
* Swapping the controller while the plant waits: the plant follows the live match counts, so a
  controller that came and left does not start the run, and the one started next drives it.
* A positive ``start_timeout`` still ends a lone plant with exit 4, in realtime mode too.

A passive probe (no command publisher) listens to ``state``, ``planing_force`` and ``/clock``
throughout; the plant counts it as a state subscriber, never as a controller.
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
from test_graph_support import Probe, batch_samples, finish, plant_args, stop_all

from fohssv_controller.state_feedback import StateFeedback

import rosproc

pytestmark = pytest.mark.graph

TOL = 1e-12
DURATION = 0.05



def _assert_ran_fully(code: int, out: str, probe: Probe) -> None:
    n = round(DURATION / 1e-4)
    assert code == 0, out
    assert 'peers matched' in out and 'stopping cleanly at t=' in out, out
    assert rosproc.summary(out)['samples'] == n, out
    probe.wait(lambda: len(probe.states) >= n + 1, 20, f'{n + 1} samples at the probe')
    ref, _ = batch_samples('delay-free', StateFeedback(), DURATION)
    got = probe.state_array()
    assert got.shape == ref.shape
    assert np.array_equal(got[:, 0], ref[:, 0])
    assert np.max(np.abs(got - ref)) <= TOL       # eq. 31 drove it, every sample
    assert probe.clocks, 'no /clock once running'


def test_plant_alone_waits_and_a_controller_started_10_s_later_runs_it(tmp_path):
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain, command_publisher=False, clock=True)
    log = tmp_path / 'plant.log'
    # nothing but the model and the run's length: the default start (start_timeout 0)
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(model='delay-free',
                                                            duration=DURATION),
                          env=env, log=log)
    ctl = None
    try:
        rosproc.wait_for(lambda: 'waiting for a controller' in log.read_text(), 60,
                         what='the plant saying it waits')
        time.sleep(10.0)
        text = log.read_text()
        assert plant.poll() is None, text
        waiting = [ln for ln in text.splitlines() if 'waiting for a controller' in ln]
        # at start (and when the probe matched), then every 5 s
        assert len(waiting) >= 2, text
        assert int(re.search(r'waited (\d+) s', waiting[-1]).group(1)) >= 5, text
        assert 'command has 0/1 publisher(s), /state has 1/1 subscriber(s)' in waiting[-1]
        assert 'no start timeout' in waiting[-1]
        assert 'ros2 run fohssv_controller state_feedback' in waiting[-1]
        assert probe.states == [] and probe.clocks == [], 'the plant ran without a controller'
        ctl = rosproc.start('fohssv_controller', 'state_feedback', env=env)
        code = rosproc.wait_exit(plant, 60)
        _assert_ran_fully(code, log.read_text(), probe)
    finally:
        stop_all(plant, ctl)
        probe.close()


def test_swapping_the_controller_while_the_plant_waits(tmp_path):
    """The plant waits for 3 state subscribers: the probe, a controller and a second probe.
    An LQR controller comes and leaves while it waits; eq. 31 then comes with the second probe,
    and the run is eq. 31's."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain, command_publisher=False, clock=True)
    log = tmp_path / 'plant.log'
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model='delay-free', duration=DURATION, min_state_subscribers=3), env=env, log=log)
    lqr = ctl = second = None
    try:
        lqr = rosproc.start('fohssv_controller', 'controller',
                            ['--ros-args', '-p', 'controller:=lqr'], env=env)
        rosproc.wait_for(lambda: 'command has 1/1 publisher(s), /state has 2/3'
                         in log.read_text(), 30, what='the plant seeing the LQR controller')
        rosproc.stop(lqr)
        rosproc.wait_for(lambda: 'command has 0/1 publisher(s), /state has 1/3'
                         in log.read_text().split('/state has 2/3', 1)[1], 30,
                         what='the plant seeing the LQR controller leave')
        assert plant.poll() is None and probe.states == [] and probe.clocks == []
        ctl = rosproc.start('fohssv_controller', 'state_feedback', env=env)
        second = Probe(domain, command_publisher=False)
        code = rosproc.wait_exit(plant, 60)
        _assert_ran_fully(code, log.read_text(), probe)
    finally:
        stop_all(plant, lqr, ctl)
        probe.close()
        if second is not None:
            second.close()


@pytest.mark.parametrize('mode', ['lockstep', 'realtime'])
def test_a_positive_start_timeout_ends_a_lone_plant_with_exit_4(mode):
    env = rosproc.ros_env()
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model='delay-free', mode=mode, start_timeout=1.0), env=env)
    code, out = finish(plant, 30)
    assert code == 4, out
    assert 'waiting for a controller' in out and 'start_timeout 1 s' in out
    assert ('start timeout: state has 0/1 subscriber(s), command has 0/1 publisher(s)'
            in out), out
    assert 'starting at t = 0' not in out
