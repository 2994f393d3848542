"""The plant hosting the law (``controller:=NAME``), in the test process: the lockstep run is
the batch runner's, for every model and built-in controller, and equal to the external node's;
the controller swapped; a law with no command for any sample counted and its lines
rate-limited; in real time (the hosted loop serving its executor once per chunk of samples,
the probe in its own thread as a process) the law's parameters changed during the run and a
reset's summary. (A second command publisher and a late external controller are the process
tests'.)"""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.parameter import Parameter

from fohssv_controller.fractional_pid import FractionalPID
from fohssv_controller.lqr import LQR
from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

import rosproc

pytestmark = pytest.mark.node

TOL = 1e-12
DURATION = 0.05
N = round(DURATION / 1e-4) + 1                 # the samples at t = 0 .. DURATION
CONTROLLERS = {'state_feedback': StateFeedback, 'lqr': LQR, 'fractional_pid': FractionalPID}
#: (model, controller) whose external-node lockstep run is compared with the batch runner
#: already, by the swap test here (LQR)
EXTERNAL_ELSEWHERE = {('delay-free', 'lqr')}
#: The PI^lambda D^mu law with its fractional integral and derivative terms active (the
#: defaults leave them off); over DDS from its own executable: tests/test_graph_lockstep.py
FRACTIONAL_GAINS = {'integral_order': 0.85, 'derivative_order': 0.7, 'depth_ki': 2.0,
                    'pitch_ki': -1.0, 'pitch_kd': -0.2}


def _batch(model: str, name: str, duration: float, **gains) -> tuple[np.ndarray, np.ndarray]:
    """The batch runner's samples [t, z, w, theta, q] and the inputs it applied from each
    sample on [delta_f, delta_c], every 1e-4 s."""
    p = ModelParameters(model=model)
    r = simulate(p, CONTROLLERS[name](**gains), duration, control_period=1e-4,
                 sample_every=round(1e-4 / p.step))
    return np.column_stack([r.t, r.state]), r.inputs


def _check(states: np.ndarray, commands: np.ndarray, ref: np.ndarray,
           inputs: np.ndarray) -> None:
    assert states.shape == ref.shape
    assert np.array_equal(states[:, 0], ref[:, 0])
    assert np.max(np.abs(states - ref)) <= TOL
    # one command per sample but the last, answering it, equal to what the batch runner held
    assert commands.shape == (len(ref) - 1, 3)
    assert np.array_equal(commands[:, 0], ref[:-1, 0])
    assert np.max(np.abs(commands[:, 1:] - inputs[:-1])) <= TOL


@pytest.mark.parametrize('model', ['delay-free', 'delayed', 'fractional'])
@pytest.mark.parametrize('name', list(CONTROLLERS))
def test_hosted_lockstep_equals_the_batch_runner(graph, capfd, model, name):
    probe = graph.probe()                     # a listener: the plant's one state subscriber
    plant = graph.plant(model=model, duration=DURATION, controller=name)
    assert graph.run(plant) == 0
    graph.wait(lambda: len(probe.states) >= N and len(probe.commands) >= N - 1, 30,
               'every sample and command at the probe')
    out = capfd.readouterr().err
    ref, inputs = _batch(model, name, DURATION)
    _check(probe.state_array(), probe.command_array(), ref, inputs)
    s = rosproc.summary(out)
    assert s['controller'] == name and s['hosted_commands'] == len(ref) - 1, s
    assert f'controller {name}(' in out and 'hosted in the loop' in out


@pytest.mark.parametrize(('model', 'name', 'gains'), [
    *(pytest.param(m, c, {}, id=f'{m}-{c}') for m in ('delay-free', 'delayed', 'fractional')
      for c in CONTROLLERS if (m, c) not in EXTERNAL_ELSEWHERE),
    pytest.param('fractional', 'fractional_pid', FRACTIONAL_GAINS, id='fractional_terms')])
def test_the_external_controller_node_equals_the_batch_runner(graph, model, name, gains):
    """The same law in the controller node, answering the plant on the same executor: the
    batch runner's samples and inputs, so hosted = external = batch."""
    probe = graph.probe()
    graph.controller(name, min_command_subscribers=2, **gains)     # the plant and the probe
    plant = graph.plant(model=model, duration=DURATION, min_state_subscribers=2)
    assert graph.run(plant) == 0
    graph.wait(lambda: len(probe.states) >= N and len(probe.commands) >= N - 1, 30,
               'every sample and command at the probe')
    ref, inputs = _batch(model, name, DURATION, **gains)
    # the node answers the last sample too
    _check(probe.state_array(), probe.command_array()[:N - 1], ref, inputs)


def test_swapping_the_controller_changes_only_the_response(graph):
    """The second built-in (LQR) in the generic node, same plant parameters: the response
    differs from eq. 31 and equals the batch run under the LQR."""
    probe = graph.probe()
    graph.controller('lqr')
    plant = graph.plant(model='delay-free', duration=0.1)
    assert graph.run(plant) == 0
    graph.wait(lambda: len(probe.states) >= 1001, 30, 'every sample at the probe')
    states = probe.state_array()
    ref_lqr, _ = _batch('delay-free', 'lqr', 0.1)
    ref_sf, _ = _batch('delay-free', 'state_feedback', 0.1)
    assert states.shape == ref_lqr.shape
    assert np.max(np.abs(states - ref_lqr)) <= TOL
    assert np.max(np.abs(states[:, 1:] - ref_sf[:, 1:])) > 1e-3


def test_a_hosted_law_that_fails_every_sample_is_counted_and_rate_limited(graph, capfd):
    """Issue 21, class 1, hosted: a law with no command for a sample (here a depth gain of
    1e308 overflows at z = 10 m for every sample of the run) is counted and logged as the
    controller node logs it, the first 20 lines one by one and then at most one a second, the
    last good command held (none yet: zero), and the run ends as configured (exit 0)."""
    plant = graph.plant(model='delay-free', controller='state_feedback', duration=DURATION,
                        initial_state=[10.0, 0.0, 0.0, 0.0], min_state_subscribers=0,
                        **{'controller.depth_gain': 1e308})
    assert graph.run(plant) == 0
    out = capfd.readouterr().err
    assert 'Traceback' not in out, out
    s = rosproc.summary(out)
    assert s['law_failures'] == N - 1 and s['hosted_commands'] == 0, s
    lines = [ln for ln in out.splitlines() if 'no command for this sample' in ln]
    # 20 one by one, then at most one a second of a run far shorter than the 20 s allowed
    assert 20 <= len(lines) <= 40, out
    assert 'holding delta_f=0.0, delta_c=0.0 rad (1 without a command)' in lines[0], lines[0]
    assert '[logged one by one up to here' in lines[19], lines[19]


#: A real-time plant hosting eq. 31 (its own parameters on top).
REALTIME_HOSTED = {'model': 'delay-free', 'mode': 'realtime', 'control_period': 1e-3,
                   'controller': 'state_feedback'}


def _follow(probe, before: StateFeedback, after: StateFeedback) -> dict[str, list]:
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


def test_hosted_parameters_change_at_run_time_and_the_commands_follow(graph, capfd):
    """The hosted law's parameters are the plant's ``controller.*`` parameters: they change
    while the real-time run goes (its hosted loop serves the executor once per chunk of
    samples) and the commands follow; an out-of-range value is refused with its range."""
    probe = graph.probe(thread=True)         # a listener, served as a process would be
    plant = graph.plant(**REALTIME_HOSTED, duration=60.0,
                        initial_state=[0.05, 0.0, 0.0, 0.0])
    before, after = StateFeedback(), StateFeedback(depth_gain=10.0)
    graph.run_until(plant, lambda: len(probe.commands) >= 20, 60, 'hosted commands')
    assert [plant.get_parameter(n).value for n in
            ('controller.depth_gain', 'controller.pitch_gain')] == [15.0, -30.0]
    (refused,) = plant.set_parameters([Parameter('controller.max_cavitator_deflection',
                                                 value=3.0)])
    assert not refused.successful
    assert 'controller.max_cavitator_deflection' in refused.reason
    assert '1.5708' in refused.reason, refused.reason
    (ok,) = plant.set_parameters([Parameter('controller.depth_gain', value=10.0)])
    assert ok.successful, ok.reason
    # the probe may lag the plant: what it receives next can still be commands sent before
    # the change, so wait for commands (and their states) after it
    graph.run_until(plant, lambda: len(_follow(probe, before, after)['after']) >= 10, 30,
                    'commands after the change, with their states')
    out = capfd.readouterr().err
    assert 'controller parameters changed: state_feedback(depth_gain=10' in out, out
    old, new = _follow(probe, before, after).values()
    # the commands before the change follow eq. 31, those after it the new gain, in order
    assert len(old) >= 10 and len(new) >= 10, (len(old), len(new))
    assert max(old) < min(new), (max(old), min(new))


def _since_reset(states: np.ndarray) -> int:
    """States received since t went back (0 before that)."""
    back = np.flatnonzero(np.diff(states[:, 0]) < 0) if len(states) > 1 else []
    return len(states) - 1 - back[0] if len(back) else 0


def test_after_a_realtime_reset_the_summary_is_the_whole_runs(graph):
    """Issue 21.2: after ``/reset`` a real-time plant's pacer started its counts over, so the
    summary gave the deadline misses and ``samples_paced`` of the part after the reset only,
    ``samples_per_wake_up`` divided those samples by the whole run's wake-ups, and
    ``cpu_share_of_period`` divided the whole run's CPU time by the samples since the reset.
    Now every count and rate but ``t``, ``samples`` and ``steps`` is the whole run's
    (docs/ros.md): the probe's count of the states published before the reset (t going back
    to 0 once) and the samples since it make ``samples_total``, and the pacer counted each
    state published."""
    from std_srvs.srv import Trigger

    probe = graph.probe(thread=True)         # a listener, served as a process would be
    plant = graph.plant(**REALTIME_HOSTED, duration=0.0)       # runs until stopped
    client = probe.node.create_client(Trigger, 'reset')
    graph.run_until(plant, lambda: len(probe.states) >= 300 and client.service_is_ready(),
                    60, 'the run to pass t = 0.3 s')
    future = client.call_async(Trigger.Request())
    graph.run_until(plant, future.done, 10, 'the reset answer')
    assert future.result().success, future.result().message
    # 100 states after the one that goes back to t = 0
    graph.run_until(plant, lambda: _since_reset(probe.state_array()) >= 100, 60,
                    'the run after the reset')
    s = plant.summary()
    t = probe.state_array()[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    assert len(back) == 1 and t[back[0] + 1] == 0.0, back
    # samples count the steps of one control period: the t = 0 state is published at the
    # start and again at the reset, not stepped to; the samples before the reset are read
    # from the last state the probe had before it (t = k control periods), every one of them
    before = round(t[back[0]] / 1e-3)
    assert np.allclose(np.diff(t[:back[0] + 1]), 1e-3, rtol=0, atol=1e-9), t[:back[0] + 1]
    assert t[back[0]] == pytest.approx(before * 1e-3, abs=1e-12), t[back[0]]
    assert s['resets'] == 1 and s['samples_total'] == before + s['samples'], (before, s)
    assert s['samples_paced'] == s['published_states'] == s['samples_total'] + 2, s
    wall_period = 1e-3                         # control_period / real_time_factor 1
    assert s['cpu_share_of_period'] == pytest.approx(
        s['cpu_time'] / s['samples_total'] / wall_period), s
    assert s['samples_per_wake_up'] * s['wake_ups'] == pytest.approx(s['samples_paced']), s
