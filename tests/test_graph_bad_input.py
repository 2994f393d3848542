"""Bad input to the plant node, with real processes over DDS.

What is between processes or needs the process: bad commands taken in compiled code (the
FOM), lockstep timeouts with a stopped controller or plant, an overrunning plant (exit 3), a
second plant (exit 5) and a second state publisher. The node's own logic (bad commands
rejected and held, stale and future ones, parameters refused at start and at run time, the
start gate's exit 4, the lockstep timeout naming the controller, a stalled publish, a
lowered deflection limit, the watchdog, a state turning non-finite or leaving its bounds) is
tested in the test process: tests/node.
"""

from __future__ import annotations

import math
import os
import re
import signal
import time

import numpy as np
import pytest
from test_graph_support import (
    Probe,
    batch_samples,
    finish,
    late_controller,
    plant_args,
    stop_all,
)

from fohssv_controller.state_feedback import StateFeedback

import rosproc

pytestmark = pytest.mark.graph

TOL = 1e-12
T = 1e-4  # default control period



def _plant(params: dict, env: dict):
    return rosproc.start('fohssv_sim', 'plant', plant_args(**params), env=env)


@pytest.mark.parametrize('model', ['fractional'])   # delay-free: tests/node
def test_bad_commands_are_rejected_and_the_last_good_one_is_held(model):
    """The probe is the controller: good commands delta_c = 0.001 k at sample k, except a NaN,
    an out-of-range and a wrong-length answer at samples 3, 4, 5. The plant must hold the
    command of sample 2 over those periods: the trajectory is the batch run of that law. The
    FOM plant takes its commands in compiled code (compiled_take): the bad ones reach the
    interpreted checks as they came."""
    bad = {3: lambda t: [t, math.nan, 0.0], 4: lambda t: [t, 0.0, 0.9],
           5: lambda t: [t, 0.0]}

    def answer(t, x):
        k = round(t / T)
        return bad[k](t) if k in bad else [t, 0.0, 0.001 * k]

    def applied(t, x):
        k = round(t / T)
        return (0.0, 0.001 * (2 if k in bad else k))

    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain, answer=answer)
    plant = _plant({'model': model, 'duration': 0.02}, env)
    try:
        code, out = finish(plant, 60)
        assert code == 0, out
        probe.wait(lambda: len(probe.states) >= 201, 10, 'all samples')
    finally:
        stop_all(plant)
        probe.close()
    rejected = [ln for ln in out.splitlines() if 'rejected command' in ln]
    assert len(rejected) == 3, out
    assert 'non-finite delta_f=nan' in rejected[0]
    assert 'delta_c=0.9 rad exceeds max_cavitator_deflection=0.5 rad' in rejected[1]
    assert 'expected 3 values' in rejected[2]
    assert all('keeping the last good command delta_f=0.0, delta_c=0.002 rad' in ln
               for ln in rejected)
    assert rosproc.summary(out)['rejected_commands'] == 3
    assert rosproc.summary(out)['compiled_take'] is (model == 'fractional')
    ref, _ = batch_samples(model, applied, 0.02)
    got = probe.state_array()
    assert got.shape == ref.shape
    assert np.max(np.abs(got - ref)) <= TOL


def test_lockstep_timeout_lowered_during_the_run_still_fires():
    """command_timeout lowered from 5 s to 0.06 s while the run goes (a parameter that needs
    no reset), then the controller (the probe) stops answering: the plant stops with exit 3
    naming the lockstep timeout. Its check timer keeps the period the start gave it (50 ms),
    longer than half the new timeout: that lateness is the timer's, not a stopped plant's
    (which earlier took every check for one, granting grace each time: it never fired). The
    FOM plant, whose executor serves the parameter change between compiled takes."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    answering = [True]
    ctl = StateFeedback()
    probe = Probe(domain, answer=lambda t, x: [t, *ctl.command(t, x)] if answering[0] else None)
    plant = _plant({'model': 'fractional', 'duration': 60.0, 'min_state_subscribers': 1,
                    'min_command_publishers': 1}, env)
    try:
        probe.wait(lambda: len(probe.states) > 50, 60, 'the run to start')
        accepted, = probe.set_plant_parameters(command_timeout=0.06)
        assert accepted.successful, accepted.reason
        answering[0] = False
        code, out = finish(plant, 30)
    finally:
        stop_all(plant)
        probe.close()
    assert code == 3, out
    assert 'lockstep timeout: ' in out and 'command_timeout=0.06 s' in out, out


def test_lockstep_timeout_counts_from_the_delivery_of_the_state(tmp_path):
    """A controller stopped (SIGSTOP) mid-run for 4 s, 8 times command_timeout, then resumed:
    its reader acknowledges nothing while stopped, so the plant says the state is not
    delivered and waits; resumed, the controller answers and the run completes. (A matched
    controller whose half of discovery lags behind under load looks the same to the plant.)
    The controller answers each state 1 ms late (eq. 31, the test plugin late_law): the stop
    comes with most of the run's 500 samples still to go."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain, command_publisher=False)
    log = tmp_path / 'plant.log'
    ctl = late_controller(env, tmp_path, 0.001)
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model='delay-free', duration=0.05, command_timeout=0.5, min_state_subscribers=2,
        end_linger=60.0, pace_to_subscribers=512), env=env, log=log)
    try:
        probe.wait(lambda: len(probe.states) >= 50, 60, 'the run under way')
        os.kill(ctl.pid, signal.SIGSTOP)
        try:
            time.sleep(4.0)
            assert plant.poll() is None, log.read_text()
        finally:
            os.kill(ctl.pid, signal.SIGCONT)
        # paced, the plant cannot run ahead of the probe; it lingers while the probe drains,
        # and a signal then ends the linger
        probe.wait(lambda: len(probe.states) >= 501 or plant.poll() is not None, 120,
                   'all samples')
        stop_all(plant)
        text = log.read_text()
        assert plant.returncode == 0, text
        assert 'stopping cleanly at t=0.05 s: duration 0.05 s reached' in text, text
        found = re.search(r'the state for t=[0-9.e-]+ s is not acknowledged by all 2 '
                          r'subscriber\(s\) of /state after ([0-9.]+) s', text)
        # command_timeout (0.5 s) when the plant's check runs on time. A state publish that
        # Fast DDS blocks (up to 1 s: its check of the stopped reader's shared-memory port)
        # makes that check late, which the plant takes for a plant that did not run: the
        # controller then gets the resume grace (5 s) before the plant looks again, and the
        # plant has said why (the long period, in its log); a grace that outlasts the rest of
        # the 4 s stop sees the controller answer again and says nothing more
        late = re.search(r'one control period \(10 steps\) took [0-9.]+ s > '
                         r'command_timeout=0.5 s', text)
        assert found or late, text
        if found:
            waited = float(found.group(1))
            assert 0.5 <= waited <= 0.5 + 5.0 + 1.0, text
            assert waited <= 0.7 or late, text
        assert len(probe.states) == 501
    finally:
        stop_all(plant, ctl)
        probe.close()


@pytest.mark.parametrize(('stops', 'timeout', 'model'), [
    ((1.5, 3.0), 0.5, 'delay-free'), ((3.0,), 4.0, 'delay-free'),
    ((1.5,), 0.5, 'fractional')])       # the FOM: stopped inside its compiled wait for a command
def test_a_stopped_plant_does_not_blame_its_controller(tmp_path, stops, timeout, model):
    """The plant's process is stopped (SIGSTOP) for 1.5 or 3 s in the middle of a lockstep
    run, longer than command_timeout or (3 s against 4 s) not; the first run is stopped twice
    (1.5 s, then 3 s): resumed, its timer's check of the controller comes late beside the
    command that arrived meanwhile, or that was lost at the stopped process's shared-memory
    port and comes again at the controller's writer's next heartbeat (Fast DDS: up to 3 s;
    with the plant deciding at the next check, 3 s stops against 0.5 s ended with exit 3 one
    time in two); the run goes on to its end. The controller answers each state 1 ms late
    (eq. 31, the test plugin late_law): the 2000 samples last two seconds of wall time, not a
    CPU-bound run of ten times as many."""
    env = rosproc.ros_env()
    ctl = late_controller(env, tmp_path, 0.001)
    log = tmp_path / 'plant.log'
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model=model, duration=0.2, command_timeout=timeout), env=env, log=log)
    try:
        rosproc.wait_for(lambda: 'starting at' in log.read_text(), 90, what='the run')
        for stopped in stops:
            time.sleep(0.3)
            plant.send_signal(signal.SIGSTOP)
            try:
                time.sleep(stopped)
            finally:
                plant.send_signal(signal.SIGCONT)
        code = rosproc.wait_exit(plant, 120)
    finally:
        stop_all(plant, ctl)
    text = log.read_text()
    assert code == 0, text
    assert 'stopping cleanly at t=0.2 s' in text, text
    # every stop fell inside the run (its wall time holds them), the FOM's inside its
    # compiled take
    assert rosproc.summary(text)['wall_time'] > sum(stops), text
    assert f'"compiled_take": {"true" if model == "fractional" else "false"}' in text, text


def test_lockstep_timeout_names_an_overrunning_plant():
    """Control periods of 2500 steps of the exact, interpreted ABM solver (O(n) per step)
    take longer than command_timeout, in the plant's own CPU time: the first is logged, the
    second ends the run."""
    env = rosproc.ros_env()
    ctl = rosproc.start('fohssv_controller', 'state_feedback', env=env)
    plant = _plant({'model': 'fractional', 'solver': 'abm', 'control_period': 0.05,
                    'command_timeout': 0.02}, env)
    try:
        code, out = finish(plant, 60)
    finally:
        stop_all(ctl)
    assert code == 3, out
    assert 'one control period (2500 steps) took' in out and 'not an overrun unless' in out
    assert 'lockstep timeout: the plant is overrunning: one control period (2500 steps)' in out
    # more CPU than the timeout (0.02 s) over the second period
    assert re.search(r'at t=0\.1 s, using (0\.0[2-9]|0\.[1-9]|[1-9])[0-9.]* s of CPU', out), out


def test_a_second_plant_on_the_same_domain_is_refused():
    """Issue 12, defect 1: two plants on one domain took each other's commands silently. The
    first plant to see the other's ``state`` publisher stops with exit 5 naming them (both may);
    a survivor is then alone on the domain."""
    import time

    env = rosproc.ros_env()
    plants = [_plant({'model': 'delay-free'}, env) for _ in range(2)]   # wait for controllers
    try:
        rosproc.wait_for(lambda: any(p.poll() is not None for p in plants), 30,
                         what='a plant to refuse')
        time.sleep(1.0)                          # the other plant's next look at the graph
        stopped = [p for p in plants if p.poll() is not None]
        outs = [rosproc.output(p) for p in stopped]
    finally:
        stop_all(*plants)
    assert [p.returncode for p in stopped] == [5] * len(stopped), outs
    for out in outs:
        assert '2 publishers of /state (nodes: /plant, /plant): another plant' in out, out
        assert 'Traceback' not in out


def test_controllers_and_the_recorder_warn_about_two_publishers_of_state(tmp_path):
    """Defect 1, the other side: two publishers of ``state`` (here two nodes in the test
    process, which stay up; two plants would stop each other) make a controller and a recorder
    say so once, naming the nodes, and keep running."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray

    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    ctx = rosproc.init_context(domain)          # the nodes' discovery settings
    nodes = [rclpy.create_node(name, context=ctx) for name in ('plant_a', 'plant_b')]
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pubs = [n.create_publisher(Float64MultiArray, 'state', qos) for n in nodes]
    logs = {k: tmp_path / f'{k}.log' for k in ('controller', 'recorder')}
    procs = [rosproc.start('fohssv_controller', 'state_feedback', [], env=env,
                           log=logs['controller']),
             rosproc.start('fohssv_sim', 'recorder', [
                 '--ros-args', '-p', f'bag_path:={tmp_path / "bag"}', '-p', 'plant_node:=none'],
                 env=env, log=logs['recorder'])]
    try:
        for log in logs.values():
            rosproc.wait_for(lambda log=log: 'publishers of /state' in log.read_text(), 60,
                             what=f'the warning in {log.name}')
        assert all(p.poll() is None for p in procs)          # a warning, not a stop
        assert all(p.get_subscription_count() >= 1 for p in pubs)
    finally:
        codes = [rosproc.stop(p) for p in procs]
        for n in nodes:
            n.destroy_node()
        rclpy.shutdown(context=ctx)
    for log in logs.values():
        text = log.read_text()
        assert text.count('2 publishers of /state (nodes: /plant_a, /plant_b)') == 1, text
        assert 'Traceback' not in text
    assert codes == [0, 0]
