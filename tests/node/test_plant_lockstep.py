"""The plant node's lockstep timeout and its parameters at start and at run time, in the test
process (stopped processes and stalls are the process tests'; the start gate:
test_plant_start)."""

from __future__ import annotations

import re

import numpy as np
import pytest
from rclpy.parameter import Parameter
from test_graph_support import batch_samples

from fohssv_controller.state_feedback import StateFeedback

pytestmark = pytest.mark.node

TOL = 1e-12
ALONE = {'min_state_subscribers': 0, 'min_command_publishers': 0}


def test_lockstep_timeout_names_the_stalled_controller(graph, capfd):
    plant = graph.plant(model='delay-free', command_timeout=0.5, **ALONE)
    assert graph.run(plant, 30) == 3
    out = capfd.readouterr().err
    assert ('lockstep timeout: the controller stalled: no command answering t=0.0 s within '
            'command_timeout=0.5 s (no command received at all') in out, out


def test_lockstep_timeout_counts_commands_that_answer_no_sample(graph, capfd):
    """Commands with no finite t were received: the timeout line says so, not 'no command
    received at all'."""
    graph.probe(lambda t, x: [float('nan'), 0.0, 0.0])
    plant = graph.plant(model='delay-free', command_timeout=0.5)
    assert graph.run(plant, 30) == 3
    out = capfd.readouterr().err
    assert 'no command received at all' not in out, out
    assert ('lockstep timeout: the controller stalled: no command answering t=0.0 s within '
            'command_timeout=0.5 s (1 command(s) received, none answering a sample: empty or '
            'without a finite t') in out, out


def test_lockstep_timeout_lowered_during_the_run_still_fires(graph, capfd):
    """command_timeout lowered from 5 s to 0.06 s while the run goes (a parameter that needs
    no reset), then the controller stops answering: the run ends with exit 3 naming the
    lockstep timeout. (The process test runs the same with the FOM plant, whose executor
    serves the change between compiled takes.)"""
    law, plant, results = StateFeedback(), None, []

    def answer(t, x):
        k = round(t / 1e-4)
        if k == 50:
            results.extend(plant.set_parameters([Parameter('command_timeout', value=0.06)]))
        return [t, *law.command(t, x)] if k < 100 else None

    graph.probe(answer)
    plant = graph.plant(model='delay-free', duration=60.0)
    assert graph.run(plant, 30) == 3
    out = capfd.readouterr().err
    assert [r.successful for r in results] == [True], [r.reason for r in results]
    assert 'lockstep timeout: ' in out and 'command_timeout=0.06 s' in out, out


def test_invalid_parameter_change_is_refused_and_the_run_is_untouched(graph, capfd):
    """Parameter changes in the middle of a run of eq. 31's controller node: out of the
    descriptor's range, read-only, of the wrong type, inside the descriptor's closed range
    but outside the table's open one are refused with a reason; a valid one is taken. The
    run is still the batch run of eq. 31."""
    plant, results = None, {}
    law = StateFeedback()

    def answer(t, x):
        if round(t / 1e-4) == 50:
            for name, value in (('real_time_factor', -1.0), ('speed', 80.0),
                                ('command_timeout', 'long'), ('real_time_factor', 0.0),
                                ('watchdog_timeout', 0.5)):
                results[(name, value)], = plant.set_parameters([Parameter(name, value=value)])
        return [t, *law.command(t, x)]

    probe = graph.probe(answer)
    plant = graph.plant(model='delay-free', duration=0.05)
    assert graph.run(plant) == 0
    graph.wait(lambda: len(probe.states) >= 501, 30, 'all samples')
    out_of_range = results[('real_time_factor', -1.0)]
    assert not out_of_range.successful
    # rclpy checks the descriptor's FloatingPointRange first
    assert 'real_time_factor out of range Min: 0.0, Max: 1000.0' in out_of_range.reason
    open_bound = results[('real_time_factor', 0.0)]
    assert not open_bound.successful
    assert ('real_time_factor=0.0 is outside the allowed range (0, 1000] (realtime mode: '
            'simulated seconds per wall second)') in open_bound.reason
    read_only = results[('speed', 80.0)]
    assert not read_only.successful and 'read-only' in read_only.reason
    wrong_type = results[('command_timeout', 'long')]
    # the row's own line (issue 51.11: not rclpy's "expected '3' got '4'")
    assert not wrong_type.successful
    assert "command_timeout='long' is a string, not a number" in wrong_type.reason, \
        wrong_type.reason
    assert results[('watchdog_timeout', 0.5)].successful
    assert [plant.get_parameter(n).value for n in
            ('real_time_factor', 'speed', 'watchdog_timeout')] == [1.0, 75.0, 0.5]
    ref, _ = batch_samples('delay-free', StateFeedback(), 0.05)
    got = probe.state_array()
    assert got.shape == ref.shape
    assert np.max(np.abs(got - ref)) <= TOL


@pytest.mark.parametrize(('params', 'message'), [
    ({'speed': -1.0}, 'speed=-1.0 is outside the allowed range (0, inf) m/s'),
    ({'control_period': 1.05e-4, 'model': 'delay-free'},
     'control_period=0.000105 s must be a whole multiple of the integration step 1e-05 s'),
    ({'model': 'quantum'}, "model='quantum' is not valid; choose one of 'fractional'"),
    ({'mode': 'realtime', 'clock_period': 2.5e-4},
     'clock_period=0.00025 s is not 0 or a whole multiple of control_period=0.0001 s '
     '(allowed: 0 or k * control_period'),
    # outside the descriptor's range too: checked against the table before rclpy declares it
    ({'clock_period': 2.0}, 'clock_period=2.0 is outside the allowed '
     'range [0, 1] s (realtime mode: simulated time between /clock messages'),
    ({'profile': 2}, 'profile=2 is outside the allowed range [0, 1]'),
    # a number beyond a double reaches the node as a string: named as such
    ({'speed': '1e400'}, "speed='1e400' is beyond the range of a double (about 1.8e308)"),
    ({'speed': 'abc'}, "speed='abc' is a string, not a number"),
    # legal values whose coefficients overflow: refused, not a traceback
    ({'speed': 1e308}, "the model's coefficients overflow with speed=1e+308:"),
])
def test_invalid_parameters_at_start_are_refused_naming_them(graph, params, message):
    """The node refuses them when it is built; the process's one line and exit 2 for such a
    refusal are test_graph_startup's."""
    with pytest.raises(ValueError) as refused:
        graph.plant(**params)
    assert message in str(refused.value)


#: The reset test's run length: long enough that the reset comes first (0: open-ended). The
#: FOM's is finite because its 'soe' history is sized by the duration as the batch runner's is.
RESET_DURATION = {'delay-free': 0.0, 'fractional': 5.0}


@pytest.mark.parametrize('model', ['delay-free', 'fractional'])
def test_reset_service_returns_to_t0_and_replays_the_run(graph, model):
    """``/reset`` during a lockstep run of eq. 31's node: t goes back to 0 once, and the run
    after it is again the batch run. The summary's rates divide the whole run's samples by
    the whole run's time (issue 21.2 / 22.8). (The FOM's lockstep samples take the plant's
    short path, models.HeldPeriod, which declines after the reset until the general path has
    bound the kernel to the new history.)"""
    from std_srvs.srv import Trigger

    probe = graph.probe()
    graph.controller()
    plant = graph.plant(model=model, duration=RESET_DURATION[model], min_state_subscribers=2)
    client = probe.node.create_client(Trigger, 'reset')
    graph.wait(lambda: len(probe.states) > 100 and client.service_is_ready(), 30,
               'the run to pass t = 0.01 s')
    future = client.call_async(Trigger.Request())
    response = graph.wait(lambda: future.done() and future.result(), 10, 'the reset answer')
    assert response.success, response.message
    assert response.message.startswith('t = 0.0 s')

    def restarted_past_0_1_s():
        t = [s[0] for s in probe.states]
        back = [i for i in range(1, len(t)) if t[i] < t[i - 1]]
        return back and t[-1] >= 0.1 + 1e-9
    graph.wait(restarted_past_0_1_s, 60, 'the restarted run to pass t = 0.1 s')
    s = plant.summary()
    t = probe.state_array()[:, 0]
    back = np.flatnonzero(np.diff(t) < 0)
    assert len(back) == 1 and t[back[0] + 1] == 0.0, (back, t[back], t[back + 1])
    # the probe saw back[0] advances before the reset: t = 0 and back[0] steps; the summary
    # counts the samples made up to now, which the probe may not all have yet
    assert s['resets'] == 1 and s['samples_total'] == s['samples'] + back[0], s
    assert s['samples_per_second'] * s['wall_time'] == pytest.approx(s['samples_total'])
    assert s['cpu_per_sample_us'] * s['samples_total'] == pytest.approx(s['cpu_time'] * 1e6)
    # after the reset the run starts over and is again the batch run
    after = probe.state_array()[back[0] + 1:]
    after = after[after[:, 0] <= 0.1 + 1e-9]
    ref, _ = batch_samples(model, StateFeedback(), RESET_DURATION[model] or 0.1)
    ref = ref[ref[:, 0] <= 0.1 + 1e-9]
    assert after.shape == ref.shape
    assert np.max(np.abs(after - ref)) <= TOL


def test_a_control_period_stalled_outside_the_plant_is_not_an_overrun(graph, capfd,
                                                                      monkeypatch):
    """The publish of sample 100 waits 1.5 s, three times command_timeout, asleep
    (``FOHSSV_FAULT_STALL_STATE``: a write DDS blocked, as Fast DDS does for up to 1 s when a
    subscriber's process is stopped; a CI run under load ended this way with exit 3 and "the
    plant is overrunning"). The plant names the slow period in one warning and runs on."""
    from fohssv_sim.ros.faults import STALL_STATE_VAR

    monkeypatch.setenv(STALL_STATE_VAR, '100:1.5')
    graph.controller()
    plant = graph.plant(model='delay-free', duration=0.05, command_timeout=0.5)
    assert graph.run(plant, 90) == 0
    text = capfd.readouterr().err
    assert re.search(r'one control period \(10 steps\) took 1\.[5-9][0-9]* s > '
                     r'command_timeout=0\.5 s of wall time at t=0\.01', text), text
    assert 'stopping cleanly at t=0.05 s' in text, text
