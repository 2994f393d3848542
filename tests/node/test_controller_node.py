"""The controller node in the test process: bad states dropped, non-finite law output
withheld, the hold until ``min_command_subscribers`` match, a refused parameter. A
:class:`inprocess.Probe` on the same executor plays the plant. (The node as a script and as
a plugin, its exit 2, the late command subscription of another participant, and many bad
states, withheld commands and a raising plugin, which bench/bench_faults.py runs as its
cases, are the process tests'.)"""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.node

OVERFLOW = {'depth_gain': 1e308, 'pitch_gain': -1e308}   # eq. 31 overflows at z = 10 m


def _first_answer(graph, probe) -> None:
    """The state t = 0, once the controller and the probe have matched, and its answer."""
    graph.wait(lambda: probe.node.count_subscribers('state') > 0
               and probe.node.count_publishers('command') > 0, 20, 'the controller')
    probe.publish_state([0.0, 0.0, 0.0, 0.0, 0.0])
    graph.wait(lambda: any(c[0] == 0.0 for c in probe.commands), 20, 'the answer at t=0')


def _answered(graph, probe, t: float) -> dict[float, tuple]:
    graph.wait(lambda: any(c[0] == t for c in probe.commands), 20, f'the answer at t={t}')
    return {c[0]: c for c in probe.commands}


def test_controller_drops_bad_state_messages(graph, capfd):
    probe = graph.probe()
    ctl = graph.controller()
    _first_answer(graph, probe)
    for data in ([0.1, 0.0, 0.0, 0.0, 0.0], [0.2, 1.0, 2.0], [0.3, float('nan'), 0, 0, 0],
                 [0.4, 0.01, 0.0, 0.0, 0.0]):
        probe.publish_state(data)
    answered = _answered(graph, probe, 0.4)
    out = capfd.readouterr().err
    assert {0.1, 0.4} <= set(answered) and not set(answered) & {0.2, 0.3}
    assert 'dropped a state message: state: expected 5 values [t,z,w,theta,q], got 3' in out
    assert 'dropped a state message: state: non-finite z=nan' in out
    assert (ctl.answered, ctl.dropped) == (3, 2)


def test_controller_holds_commands_until_min_command_subscribers_match(graph, capfd):
    """``min_command_subscribers:=2`` (a plant and a recorder): with one command subscription
    matched the answers are held, and a log line says why; when a second subscription
    appears every held answer goes out, in order."""
    probe = graph.probe()                           # one command subscription
    graph.controller(min_command_subscribers=2)
    graph.wait(lambda: probe.node.count_subscribers('state') > 0, 20, 'the controller')
    probe.publish_state([0.0, 0.0, 0.0, 0.0, 0.0])
    probe.publish_state([0.1, 0.01, 0.0, 0.0, 0.0])
    # the hold is reported after 2 s; nothing may have been sent by then
    lines = []
    graph.wait(lambda: lines.append(capfd.readouterr().err) or 'holding 2 message(s)'
               in ''.join(lines), 20, 'the hold report')
    assert probe.commands == []
    graph.probe()                                   # the second subscription opens the gate
    graph.wait(lambda: len(probe.commands) >= 2, 20, 'the held answers')
    assert [c[0] for c in probe.commands] == [0.0, 0.1]
    lines.append(capfd.readouterr().err)
    assert 'command has matched 1 of 2 required subscription(s)' in ''.join(lines)


def test_controller_sends_no_command_for_a_non_finite_law_output(graph, capfd):
    """Issue 12, defect 5: with gains of 1e308 the law overflows to NaN for the state at
    t = 0.1; clamped it used to go out as a full +0.5 rad deflection. No command may be sent
    for it; the node says why and answers the next state as usual."""
    probe = graph.probe()
    ctl = graph.controller(**OVERFLOW)
    _first_answer(graph, probe)
    probe.publish_state([0.1, 10.0, 0.0, 10.0, 0.0])
    probe.publish_state([0.2, 0.0, 0.0, 0.0, 0.0])
    answered = _answered(graph, probe, 0.2)
    out = capfd.readouterr().err
    assert 0.1 not in answered and answered[0.2] == (0.2, 0.0, 0.0)
    assert ('state_feedback: non-finite output at t=0.1 s: delta_f=0.0, delta_c=nan rad from '
            '[z, w, theta, q] = [10.0, 0.0, 10.0, 0.0]; no command sent for this state '
            '(1 withheld)') in out, out
    assert ctl.withheld == 1


def test_controller_rejects_min_command_subscribers_below_one(graph):
    """Refused when the node is built; the process's one line and exit 2 for such a refusal
    are test_graph_startup's."""
    with pytest.raises(ValueError) as refused:
        graph.controller(min_command_subscribers=0)
    assert ('min_command_subscribers=0 is outside the allowed range [1, 1000] (matched '
            'subscriptions of command') in str(refused.value)
