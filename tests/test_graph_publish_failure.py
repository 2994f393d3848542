"""Issue 21.1: a sample DDS refuses to publish ends the run with exit 9, its one line, the
summary and a ``run_end`` that agree with the bag, never with an uncaught ``RCLError``.

Real processes over DDS: a plant, its controller (an external node, or hosted by the plant)
and the recorder. The refusal is injected with the plant's testing aid
``FOHSSV_FAULT_REFUSE_STATE`` (``fohssv_sim/ros/faults.py``: rclpy's own ``RCLError`` from
the plant's ``state`` publish call; no deterministic way to make a keep-last Fast DDS writer
fail for real exists, see that module). The counts asserted come from the test's settings
(the injected ``N``) and the batch runner (the states at those times), not from the nodes.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from test_graph_support import batch_samples, plant_args, stop_all

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.bag import load_run
from fohssv_sim.ros.faults import REFUSE_STATE_VAR, STALL_STATE_VAR
from fohssv_sim.ros.loop import time_text
from fohssv_sim.ros.plant_node import EXIT_PUBLISH_FAILED

import rosproc

pytestmark = pytest.mark.graph

#: Bound of the run if the injection did nothing (the plant would then exit 0).
DURATION = 0.2
#: The state publishes the plant makes before every further one is refused.
N = 600
TOL = 1e-12


def _run(tmp_path, refuse: str, hosted: bool, duration: float = DURATION,
         model: str = 'delay-free', **plant_params) -> SimpleNamespace:
    """A recorded lockstep loop of the ``model`` plant (eq. 31's law, external or hosted)
    with ``FOHSSV_FAULT_REFUSE_STATE=refuse`` in the plant's environment; waits for both the
    plant's and the recorder's exits."""
    env = rosproc.ros_env()
    bag, rlog, plog = tmp_path / 'run', tmp_path / 'recorder.log', tmp_path / 'plant.log'
    rec = rosproc.start_recorder(env, rlog, f'bag_path:={bag}', 'plant_timeout:=30.0',
                                 'command_publishers:=1')
    procs = [rec]
    try:
        extra = {'controller': 'state_feedback'} if hosted else {}
        if not hosted:
            procs.append(rosproc.start('fohssv_controller', 'state_feedback', [
                '--ros-args', '-p', 'min_command_subscribers:=2'], env=env))
        plant = rosproc.start('fohssv_sim', 'plant', plant_args(
            model=model, duration=duration, min_state_subscribers=2,
            pace_to_subscribers=512, **extra, **plant_params),
            env={**env, REFUSE_STATE_VAR: refuse}, log=plog)
        procs.append(plant)
        code = rosproc.wait_exit(plant, 180)
        rcode = rosproc.wait_exit(rec, 60)
    finally:
        stop_all(*procs)
    return SimpleNamespace(code=code, rcode=rcode, bag=bag, plant=plog.read_text(),
                           recorder=rlog.read_text())



@pytest.mark.parametrize(('hosted', 'inplant', 'model'), [
    (True, False, 'delay-free'), (False, True, 'delay-free'), (False, False, 'fractional')],
    ids=['hosted', 'external-recorded-in-plant', 'external-fom'])
def test_a_refused_sample_ends_the_run_with_exit_9_and_the_bag_agrees(tmp_path, hosted,
                                                                         inplant, model):
    """An external controller and a hosted one; the plant's state publish as it is, and
    recorded into the in-plant bag as it is published. (The FOM's lockstep sample takes the
    plant's compiled fast path, which publishes its state before the model's bookkeeping; the
    fault injection refuses there too, and the refusal must not undo the bookkeeping.)"""
    ref, fref = batch_samples(model, StateFeedback(), DURATION)
    steps = round(1e-4 / (2e-5 if model == 'fractional' else 1e-5))
    extra = {'record': str(tmp_path / 'inplant')} if inplant else {}
    run = _run(tmp_path, str(N), hosted, model=model, **extra)
    text = run.plant
    assert run.code == EXIT_PUBLISH_FAILED, text
    assert 'Traceback' not in text and 'Traceback' not in run.recorder, text
    assert f'{REFUSE_STATE_VAR}: state publishes after the first {N} are refused' in text
    # one error line naming the topic, the sample (the batch runner's time of sample N), the
    # retry time and rclpy's error
    errors = [ln for ln in text.splitlines() if '[ERROR]' in ln]
    assert len(errors) == 1, text
    assert (f'/state: the sample at t={time_text(float(ref[N, 0]))} s could not be published '
            'for 1 s (Failed to publish: ' in errors[0]), errors
    assert errors[0].rstrip().endswith('; stopping the run'), errors
    summary = rosproc.summary(text)
    assert summary['published_states'] == N and summary['publish_retries'] == 1, summary
    if model == 'fractional':   # the refusal met the compiled fast path, not a slower one
        assert summary['compiled_samples'] >= N - 1, summary
    # sample N was made (the model's default steps in a control period), never published
    assert summary['t'] == ref[N, 0] and summary['samples'] == N, summary
    assert summary['steps'] == steps * N, summary

    # the recorder heard run_end and found everything it lists in the bag
    assert run.rcode == 0, run.recorder
    assert 'every message of the run is in the bag' in run.recorder, run.recorder
    bag = load_run(run.bag)
    end = bag.metadata['fohssv.run_end']
    assert end['exit_code'] == EXIT_PUBLISH_FAILED and end['source'] == 'plant', end
    assert end['t'] == ref[N, 0], end
    assert end['published']['/state'] == end['published']['/planing_force'] == N, end
    assert bag.topics['/state'] == bag.topics['/planing_force'] == N, bag.topics
    # the states in the bag are the batch runner's first N, in order, at its times
    assert np.array_equal(bag.t, ref[:N, 0])
    assert np.max(np.abs(bag.state - ref[:N, 1:])) <= TOL
    assert np.array_equal(bag.planing_force_t, fref[:N, 0])
    # a command answers each published state (the hosted law's are published by the plant)
    assert end['published']['/command'] == bag.topics['/command'] == N, (end, bag.topics)
    if inplant:     # the plant's own bag: what it published, the refused sample not in it
        assert 'in-plant recording: closed' in text and 'every message of the run is in the ' \
            'bag' in text, text
        own = load_run(tmp_path / 'inplant')
        assert own.topics['/state'] == own.topics['/planing_force'] == N, own.topics
        assert np.array_equal(own.t, bag.t) and np.array_equal(own.state, bag.state)
        assert own.metadata['fohssv.run_end'] == end


def test_a_refusal_shorter_than_the_retry_loses_nothing(tmp_path):
    """50 refusals (about 50 ms of 1 ms retries) of sample 300: the retry gets it out, the
    run completes (exit 0) with every sample in the bag and one retry counted."""
    duration = 0.05
    ref, _ = batch_samples('delay-free', StateFeedback(), duration)
    run = _run(tmp_path, '300:50', False, duration=duration)
    assert run.code == 0, run.plant
    assert 'stopping cleanly at t=' in run.plant and '[ERROR]' not in run.plant, run.plant
    assert f'/state: publishing the sample at t={time_text(float(ref[300, 0]))} failed' in run.plant
    summary = rosproc.summary(run.plant)
    assert summary['publish_retries'] == 1 and summary['published_states'] == len(ref)
    assert run.rcode == 0, run.recorder
    bag = load_run(run.bag)
    assert np.array_equal(bag.t, ref[:, 0])
    assert bag.metadata['fohssv.run_end']['published']['/state'] == len(ref)


@pytest.mark.parametrize(('var', 'value', 'expected'), [
    (REFUSE_STATE_VAR, 'x', 'expected N or N:M'),
    (STALL_STATE_VAR, '100', 'expected N:S, a whole number 0 <= N <= 1e12 and 0 < S <= 3600 s')])
def test_a_bad_fault_injection_value_is_refused_in_one_line(var, value, expected):
    """The plant's process: exit 2 and the line (every bad value of both variables:
    tests/test_ros_pure.py)."""
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(model='delay-free'),
                          env={**rosproc.ros_env(), var: value})
    code = rosproc.wait_exit(plant, 90)
    out = rosproc.output(plant)
    assert code == 2, out
    assert f'{var}={value!r}: {expected}' in out, out
    assert 'Traceback' not in out, out
