"""Controller nodes over DDS: the write-your-own-controller example (docs/ros.md) run for real,
both as a package-less node script and as a plugin found by the generic node (each a
process, closing the loop with the plant node built in the test process), with the node's
last line; an unknown name; the first answer held for the state publisher's own command
subscription; many bad states, withheld commands and a raising plugin (the cases
bench/bench_faults.py runs; the node's other handling of bad input: tests/node)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pytest
from inprocess import Graph
from test_graph_support import Probe, batch_samples, finish, stop_all

from fohssv_controller.state_feedback import StateFeedback

import rosproc

pytestmark = pytest.mark.graph

EXAMPLES = Path(__file__).parent / 'examples'
sys.path.insert(0, str(EXAMPLES))
from pitch_damper import PitchDamper  # noqa: E402

TOL = 1e-12
DURATION = 0.05


def _closed_loop(start_controller) -> np.ndarray:
    """The controller process ``start_controller(env)`` starts, closing the loop with the plant
    node built in the test process (what is tested is the controller's process; the plant's
    own is tests/test_graph_lockstep.py's): the states of the run and the node's last line."""
    graph = Graph()
    ctl = None
    try:
        probe = graph.probe()              # a listener: every state and every command
        ctl = start_controller(rosproc.ros_env(graph.domain))
        plant = graph.plant(model='delay-free', duration=DURATION, min_state_subscribers=2)
        assert graph.run(plant, 120) == 0
        # every state, and the node's answer to the last one (t = DURATION)
        graph.wait(lambda: len(probe.states) == 501 and any(
            c[0] == probe.states[-1][0] for c in probe.commands[-3:]), 60,
            'every sample and the answer to the last')
        # the node's last line, on the signal that ends it: its counts (the in-process tests
        # check the counts of drops, withheld and raised answers themselves)
        out = stop_all(ctl)
        assert ('answered 501 state(s), dropped 0, withheld 0 (non-finite law output), '
                '0 raised by the law') in out, out
        return probe.state_array()
    finally:
        if ctl is not None:
            stop_all(ctl)
        graph.close()


def _check_pitch_damper(states: np.ndarray) -> None:
    ref, _ = batch_samples('delay-free', PitchDamper(pitch_damping=0.9), DURATION)
    eq31, _ = batch_samples('delay-free', StateFeedback(), DURATION)
    assert states.shape == ref.shape
    assert np.max(np.abs(states - ref)) <= TOL
    assert np.max(np.abs(states[:, 1:] - eq31[:, 1:])) > 1e-4


def test_example_runs_as_a_node_script():
    """``python pitch_damper.py --ros-args -p pitch_damping:=0.9`` against the real plant."""
    import subprocess

    def start(env):
        return subprocess.Popen(
            [sys.executable, str(EXAMPLES / 'pitch_damper.py'), '--ros-args', '-p',
             'pitch_damping:=0.9'], env=env, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, start_new_session=True)

    _check_pitch_damper(_closed_loop(start))


def test_example_runs_as_a_plugin_of_the_generic_node(tmp_path):
    """Registered the way ``pip install`` of a package with the entry point would: a
    dist-info with entry_points.txt on the path; hosted by name by the generic node."""
    dist = tmp_path / 'pitch_damper_example-0.1.dist-info'
    dist.mkdir()
    (dist / 'METADATA').write_text('Metadata-Version: 2.1\nName: pitch-damper-example\n'
                                   'Version: 0.1\n')
    (dist / 'entry_points.txt').write_text(
        '[fohssv.controllers]\npitch_damper = pitch_damper:PitchDamper\n')

    def start(env):
        env = dict(env, PYTHONPATH=f"{tmp_path}:{EXAMPLES}:{env.get('PYTHONPATH', '')}")
        return rosproc.start('fohssv_controller', 'controller', [
            '--ros-args', '-p', 'controller:=pitch_damper', '-p', 'pitch_damping:=0.9'],
            env=env)

    _check_pitch_damper(_closed_loop(start))


def test_unknown_controller_lists_the_valid_ones():
    proc = rosproc.start('fohssv_controller', 'controller',
                         ['--ros-args', '-p', 'controller:=pid'], env=rosproc.ros_env())
    code, out = finish(proc, 30)
    assert code == 2, out
    assert ("unknown controller 'pid'; valid controllers (fohssv.controllers entry points): "
            'fractional_pid, lqr, scheduled, state_feedback') in out


def test_first_answer_waits_for_the_command_subscription_of_the_state_publisher():
    """Another node subscribed to ``command`` (a recorder, a viewer: here a passive probe)
    meets ``min_command_subscribers`` before the plant's own command subscription has reached
    the controller's process. The answer to the plant's first state must wait for that
    subscription: sent at once it went to the other subscriber only, and a lockstep plant
    waited for it until its command_timeout (test_graph_tune failed so under load). Here the
    'plant' (a test node in its own process context, so its own DDS participant) creates its
    command subscription only 0.3 s after its first state: a reliable, volatile reader that
    joins after the sample was written never gets it."""
    import threading

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64MultiArray

    from fohssv_sim.contract import COMMAND, STATE
    from fohssv_sim.ros.qos import profile

    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    listener = Probe(domain, command_publisher=False)    # a command subscriber from the start
    ctl = rosproc.start('fohssv_controller', 'state_feedback', env=env)
    context = rosproc.init_context(domain)
    node = rclpy.create_node('late_plant', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set() and context.ok():
            executor.spin_once(timeout_sec=0.02)

    spinner = threading.Thread(target=spin, daemon=True)
    got: list[tuple] = []
    try:
        state_pub = node.create_publisher(Float64MultiArray, STATE.name, profile(STATE))
        spinner.start()
        # the controller's command publisher matched the listener, its state reader this node
        listener.wait(lambda: listener.node.count_publishers(COMMAND.name) > 0
                      and state_pub.get_subscription_count() > 0, 30, 'the controller')
        time.sleep(0.5)          # the controller's side of the listener's match, too
        msg = Float64MultiArray()
        msg.data = [0.0, 0.01, 0.0, 0.0, 0.0]
        state_pub.publish(msg)
        listener.wait(lambda: node.count_subscribers(STATE.name) > 0, 5, 'the state reader')
        time.sleep(0.3)
        node.create_subscription(Float64MultiArray, COMMAND.name,
                                 lambda m: got.append(tuple(m.data)), profile(COMMAND))
        listener.wait(lambda: got, 30, "the answer to t=0 at the state publisher's "
                      'command subscription, created after the state')
        listener.wait(lambda: listener.commands, 10, 'the same answer at the listener')
    finally:
        stop.set()
        spinner.join(timeout=5)
        out = stop_all(ctl)
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        listener.close()
    assert got[0][0] == 0.0 and listener.commands[0] == got[0], out


def _first_state_to_controller(probe: Probe) -> None:
    """Wait for the controller node, then publish the state t = 0 once it is matched."""
    probe.wait(lambda: probe.node.count_subscribers('state') > 0
               and probe.node.count_publishers('command') > 0, 20, 'the controller')
    probe.publish_state([0.0, 0.0, 0.0, 0.0, 0.0])
    # matched by the probe's own subscription and by the controller's
    probe.wait(lambda: probe._state_pub.get_subscription_count() >= 2, 20, 'matching')


def test_controller_survives_many_bad_states_and_throttles_their_lines():
    """Issue 21, class 1: the 21st dropped state killed the node (rclpy: "Requested logging
    filters cannot be changed between calls"). 40 bad states: the node stays alive, answers
    a good state after them, and logs the first 20 drops one by one, then at most one line a
    second (docs/ros.md)."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain)
    ctl = rosproc.start('fohssv_controller', 'state_feedback', env=env)
    try:
        _first_state_to_controller(probe)
        for k in range(40):
            probe.publish_state([0.1 + k * 1e-3, float('nan'), 0.0, 0.0, 0.0])
        probe.publish_state([0.5, 0.01, 0.0, 0.0, 0.0])
        probe.wait(lambda: any(c[0] == 0.5 for c in probe.commands), 20, 'the good answer')
        alive = ctl.poll() is None
    finally:
        out = stop_all(ctl)
        probe.close()
    assert alive, out
    assert 'Traceback' not in out and 'cannot be changed' not in out
    lines = [ln for ln in out.splitlines() if 'dropped a state message' in ln]
    # 20 one by one; the other 20 arrive within far less than a second on a quiet machine,
    # and never more than one a second: at most 20 + (seconds taken + 1) lines
    assert 20 <= len(lines) < 40, out
    assert '(20 dropped) [logged one by one up to here' in lines[19]
    assert 'answered 2 state(s), dropped 40' in out


def test_controller_survives_many_withheld_commands_and_throttles_their_lines():
    """Issue 21, class 1, its other half: the 21st withheld (non-finite) command killed the
    node as the 21st dropped state did. Gains of 1e308 overflow for 40 states of z = 10 m:
    no command for any of them, the node stays alive and answers a state after them."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain)
    ctl = rosproc.start('fohssv_controller', 'state_feedback',
                        ['--ros-args', '-p', 'depth_gain:=1e308', '-p', 'pitch_gain:=-1e308'],
                        env=env)
    try:
        _first_state_to_controller(probe)
        for k in range(40):
            probe.publish_state([0.1 + k * 1e-3, 10.0, 0.0, 10.0, 0.0])
        probe.publish_state([0.5, 0.0, 0.0, 0.0, 0.0])
        probe.wait(lambda: any(c[0] == 0.5 for c in probe.commands), 20, 'the good answer')
        alive = ctl.poll() is None
    finally:
        out = stop_all(ctl)
        probe.close()
    assert alive, out
    assert 'Traceback' not in out and 'cannot be changed' not in out
    assert not [c for c in probe.commands if 0.1 <= c[0] < 0.5], probe.commands
    lines = [ln for ln in out.splitlines() if 'no command sent for this state' in ln]
    assert 20 <= len(lines) < 40, out
    assert '(20 withheld) [logged one by one up to here' in lines[19]
    assert 'answered 2 state(s), dropped 0, withheld 40 (non-finite law output)' in out


_RAISING = '''
import sys
sys.path.insert(0, {examples!r})
from pitch_damper import PitchDamper


class Raising(PitchDamper):
    name = 'raising'

    def update(self, t, state):
        if t > 0.0:
            raise RuntimeError('a bug in the plugin')
        return super().update(t, state)


from fohssv_controller.ros.controller_node import main
main(default_controller=Raising)
'''


def test_a_plugin_that_raises_is_logged_rate_limited_and_the_node_lives(tmp_path):
    """Issue 21, class 1: a plugin whose ``update`` raised logged one ERROR per sample (10 000
    a second). 60 states it raises for: counted, 20 lines one by one then at most one a
    second; the state at t = 0 (which it answers) and the node's final line still come."""
    import subprocess

    script = tmp_path / 'raising.py'
    script.write_text(_RAISING.format(examples=str(EXAMPLES)))
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain)
    ctl = subprocess.Popen([sys.executable, str(script)], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True, start_new_session=True)
    rosproc.STARTED.append(ctl)
    try:
        _first_state_to_controller(probe)
        probe.wait(lambda: any(c[0] == 0.0 for c in probe.commands), 20, 'the answer at t=0')
        for k in range(60):
            probe.publish_state([0.1 + k * 1e-3, 0.0, 0.0, 0.0, 0.0])
        probe.wait(lambda: probe.node.count_publishers('command') > 0, 5, 'the node')
        import time
        time.sleep(1.0)
        alive = ctl.poll() is None
    finally:
        out = stop_all(ctl)
        probe.close()
    assert alive, out
    lines = [ln for ln in out.splitlines() if 'raised RuntimeError: a bug in the plugin' in ln]
    assert 20 <= len(lines) < 60, out
    assert 'answered 1 state(s), dropped 0, withheld 0 (non-finite law output), 60 raised' in out
