"""The plant hosting the law (``controller:=NAME``), in the test process: the lockstep run is
the batch runner's, for every model and built-in controller, and equal to the external node's;
the controller swapped; a law with no command for any sample counted and its lines
rate-limited. (A second command publisher, a late external controller and the law's
parameters changed during a real-time run, whose hosted loop serves its executor once per
chunk of samples, are the process tests'.)"""

from __future__ import annotations

import numpy as np
import pytest

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
