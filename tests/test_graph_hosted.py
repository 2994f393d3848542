"""Hosted controllers and the honest limits of external ones (issue 20), real processes over DDS.

* (A hosted law with no command for any sample, its parameters changed during a real-time
  run, a real-time reset's summary, and the hosted lockstep run equal to the batch runner and
  to the external node, for every model and built-in controller:
  tests/node/test_plant_hosted.py.)
* A second publisher of ``command`` against a hosted plant stops it (exit 7).
* An external controller that answers late (a test plugin taking 5 ms per answer at a 1 ms
  control period) stops the real-time plant with exit 6 and one line naming the lag.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from test_graph_support import Probe, finish, late_controller, plant_args, stop_all

import rosproc

pytestmark = pytest.mark.graph


def _realtime_hosted(env: dict, log: Path, **params) -> object:
    return rosproc.start('fohssv_sim', 'plant', plant_args(
        model='delay-free', mode='realtime', control_period=1e-3, controller='state_feedback',
        min_state_subscribers=1, end_linger=0.0, **params), env=env, log=log)


def test_a_second_command_publisher_stops_a_hosted_plant(tmp_path):
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    log = tmp_path / 'plant.log'
    plant = _realtime_hosted(env, log, duration=60.0)
    probe = None
    try:
        rosproc.wait_for(lambda: 'peers matched' in log.read_text(), 60, what='the start')
        probe = Probe(domain)             # publishes command: a second controller
        code = rosproc.wait_exit(plant, 60)
    finally:
        stop_all(plant)
        if probe is not None:
            probe.close()
    out = log.read_text()
    assert code == 7, out
    lines = [ln for ln in out.splitlines() if 'two controllers must not mix' in ln]
    assert len(lines) == 1, out
    assert ("2 publishers of /command (nodes: /plant, /probe): this plant hosts the "
            "controller 'state_feedback'") in lines[0]


def test_a_late_external_controller_stops_the_realtime_plant_with_exit_6(tmp_path):
    """The plugin late_law answers each state 5 ms after it came, at a 1 ms control period:
    its commands fall behind by about 0.8 periods per period, the lag passes
    max_command_lag (20) and stays there; the plant stops with exit 6 and one line naming
    the lag, the plant's cost per sample and the remedies, long before the vehicle could
    leave its bounds."""
    env = rosproc.ros_env()
    ctl = late_controller(env, tmp_path, 0.005)
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model='delay-free', mode='realtime', control_period=1e-3, duration=5.0,
        end_linger=0.0), env=env)
    try:
        code, out = finish(plant, 90)
    finally:
        stop_all(plant, ctl)
    assert code == 6, out
    lines = [ln for ln in out.splitlines() if 'command lag:' in ln]
    assert len(lines) == 1, out
    line = lines[0]
    for words in ("the external controller's commands lagged by more than "
                  'max_command_lag=20 control periods for as long',
                  'cannot keep up with control_period=0.001 s in real time', 'plant CPU ',
                  ' us per sample = ', 'remedies: mode:=lockstep',
                  'a longer control_period (e.g. control_period:=0.01)', 'controller:=NAME'):
        assert words in line, line
    assert 'state beyond physical bounds' not in out
    s = rosproc.summary(out)
    assert s['command_lag_worst'] > 20 and s['commands_over_lag_limit'] > 0, s
    assert s['t'] < 1.0, s
