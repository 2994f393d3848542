"""Hosted controllers and the honest limits of external ones (issue 20), real processes over DDS.

* (A hosted law with no command for any sample, counted and rate-limited, and the hosted
  lockstep run equal to the batch runner and to the external node, for every model and
  built-in controller: tests/node/test_plant_hosted.py.)
* The hosted law's parameters are the plant's ``controller.*`` parameters: they change at run
  time and the commands follow; an out-of-range value is refused with its range.
* A second publisher of ``command`` against a hosted plant stops it (exit 7).
* An external controller that answers late (a test plugin taking 5 ms per answer at a 1 ms
  control period) stops the real-time plant with exit 6 and one line naming the lag.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_graph_support import Probe, finish, plant_args, stop_all

from fohssv_controller.state_feedback import StateFeedback

import rosproc

pytestmark = pytest.mark.graph

EXAMPLES = Path(__file__).parent / 'examples'


def _realtime_hosted(env: dict, log: Path, **params) -> object:
    return rosproc.start('fohssv_sim', 'plant', plant_args(
        model='delay-free', mode='realtime', control_period=1e-3, controller='state_feedback',
        min_state_subscribers=1, end_linger=0.0, **params), env=env, log=log)


def _follow(probe: Probe, before: StateFeedback, after: StateFeedback) -> dict[str, list]:
    """The times of the probe's commands that follow each law (those whose state the probe
    has and for which the two laws differ); raises on a command that follows neither."""
    states = {row[0]: row[1:] for row in list(probe.states)}
    matched: dict[str, list] = {'before': [], 'after': []}
    for t, df, dc in list(probe.commands):
        x = states.get(t)
        if x is None or before.command(t, x) == after.command(t, x):
            continue
        if (df, dc) == before.command(t, x):
            matched['before'].append(t)
        elif (df, dc) == after.command(t, x):
            matched['after'].append(t)
        else:
            raise AssertionError(f'command {(t, df, dc)} follows neither gain')
    return matched


def test_hosted_parameters_change_at_run_time_and_the_commands_follow(tmp_path):
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    log = tmp_path / 'plant.log'
    probe = Probe(domain, command_publisher=False)
    plant = _realtime_hosted(env, log, duration=60.0, initial_state=[0.05, 0.0, 0.0, 0.0])
    before, after = StateFeedback(), StateFeedback(depth_gain=10.0)
    try:
        probe.wait(lambda: len(probe.commands) >= 20, 60, 'hosted commands')
        # a request sent before the services are discovered is never answered: wait first
        rosproc.wait_for(probe.params.services_are_ready, 60, what='the parameter services')
        got = probe.result(probe.params.get_parameters(
            ['controller.depth_gain', 'controller.pitch_gain'])).values
        assert [v.double_value for v in got] == [15.0, -30.0]
        refused = probe.set_plant_parameters(**{'controller.max_cavitator_deflection': 3.0})
        assert not refused[0].successful
        assert 'controller.max_cavitator_deflection' in refused[0].reason
        assert '1.5708' in refused[0].reason, refused[0].reason
        (ok,) = probe.set_plant_parameters(**{'controller.depth_gain': 10.0})
        assert ok.successful, ok.reason
        # the probe may lag the plant under load: what it receives next can still be commands
        # sent before the change, so wait for commands (and their states) after it
        probe.wait(lambda: len(_follow(probe, before, after)['after']) >= 10, 30,
                   'commands after the change, with their states')
    finally:
        out = stop_all(plant) + log.read_text()
        probe.close()
    assert 'controller parameters changed: state_feedback(depth_gain=10' in out, out
    old, new = _follow(probe, before, after).values()
    # the commands before the change follow eq. 31, those after it the new gain, in order
    assert len(old) >= 10 and len(new) >= 10, (len(old), len(new))
    assert max(old) < min(new), (max(old), min(new))


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
    dist = tmp_path / 'late_law_example-0.1.dist-info'
    dist.mkdir()
    (dist / 'METADATA').write_text('Metadata-Version: 2.1\nName: late-law-example\n'
                                   'Version: 0.1\n')
    (dist / 'entry_points.txt').write_text('[fohssv.controllers]\nlate_law = late_law:LateLaw\n')
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    ctl_env = dict(env, PYTHONPATH=f"{tmp_path}:{EXAMPLES}:{env.get('PYTHONPATH', '')}")
    ctl = rosproc.start('fohssv_controller', 'controller', [
        '--ros-args', '-p', 'controller:=late_law', '-p', 'answer_delay:=0.005'], env=ctl_env)
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


def _since_reset(states: np.ndarray) -> int:
    """States received since t went back (0 before that)."""
    back = np.flatnonzero(np.diff(states[:, 0]) < 0) if len(states) > 1 else []
    return len(states) - 1 - back[0] if len(back) else 0


def test_after_a_realtime_reset_the_summary_is_the_whole_runs(tmp_path):
    """Issue 21.2: after ``/reset`` a real-time plant's pacer started its counts over, so the
    summary gave the deadline misses and ``samples_paced`` of the part after the reset only,
    ``samples_per_wake_up`` divided those samples by the whole run's wake-ups, and
    ``cpu_share_of_period`` divided the whole run's CPU time by the samples since the reset.
    Now every count and rate but ``t``, ``samples`` and ``steps`` is the whole run's
    (docs/ros.md): the probe's count of the states published before the reset (t going back
    to 0 once) and the samples since it make ``samples_total``, and the pacer counted each
    state published."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    log = tmp_path / 'plant.log'
    probe = Probe(domain, command_publisher=False)
    plant = _realtime_hosted(env, log, duration=0.0)      # runs until stopped
    try:
        probe.wait(lambda: len(probe.states) >= 300, 60, 'the run to pass t = 0.3 s')
        response = probe.reset_plant()
        assert response.success, response.message
        # 100 states after the one that goes back to t = 0 (a probe that lags the 1 kHz run,
        # idle CPUs halting, has states from before the reset still to take)
        probe.wait(lambda: _since_reset(probe.state_array()) >= 100, 60,
                   'the run after the reset')
        code = rosproc.stop(plant)
    finally:
        out = stop_all(plant) + log.read_text()
        probe.close()
    assert code == 0, out
    s = rosproc.summary(out)
    t = probe.state_array()[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    assert len(back) == 1 and t[back[0] + 1] == 0.0, (back, out[-3000:])
    # samples count the steps of one control period: the t = 0 state is published at the
    # start and again at the reset, not stepped to (test_graph_lockstep.py's reset test). The
    # samples before the reset are read from the last state the probe had before it (t = k
    # control periods): a probe whose half of discovery came late gets only the writer's
    # history of the earliest states (2000 deep), so its count of them can fall short
    before = round(t[back[0]] / 1e-3)
    # ... but once it has the first, it has every later one (reliable delivery, no gap)
    assert np.allclose(np.diff(t[:back[0] + 1]), 1e-3, rtol=0, atol=1e-9), t[:back[0] + 1]
    assert t[back[0]] == pytest.approx(before * 1e-3, abs=1e-12), t[back[0]]
    assert s['resets'] == 1 and s['samples_total'] == before + s['samples'], (before, s)
    assert s['samples_paced'] == s['published_states'] == s['samples_total'] + 2, s
    wall_period = 1e-3                         # control_period / real_time_factor 1
    assert s['cpu_share_of_period'] == pytest.approx(
        s['cpu_time'] / s['samples_total'] / wall_period), s
    assert s['samples_per_wake_up'] * s['wake_ups'] == pytest.approx(s['samples_paced']), s
