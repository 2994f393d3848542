"""Issue 12, defect 7: a finite state beyond physical bounds (|w| > V, |theta| > pi/2) stops
a run like a non-finite one, naming the time and the state. Pure: no rclpy."""

from __future__ import annotations

import pytest

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.models import StateOutOfBounds, check_state, make_plant
from fohssv_sim.params import ModelParameters
from fohssv_sim.ros.loop import SampledPlant
from fohssv_sim.simulate import simulate

BOUND = r'state beyond physical bounds at t=\S+ s: \[z, w, theta, q\] = \['


def test_the_largest_allowed_step_blows_up_and_the_batch_runner_says_so():
    """step = 0.01 s is allowed by the table but unstable for RK4 on eq. 17: it used to
    finish with w in the millions."""
    p = ModelParameters(model='delay-free', step=0.01)
    with pytest.raises(StateOutOfBounds, match=BOUND) as info:
        simulate(p, StateFeedback(), 2.0, control_period=0.01)
    assert '|w| must stay <= V = 75 m/s' in str(info.value)
    assert isinstance(info.value, FloatingPointError)


def test_sampled_plant_stops_at_the_first_period_beyond_the_bounds():
    sim = SampledPlant(ModelParameters(model='delay-free'), 1e-4, [0.0, 80.0, 0.0, 0.0])
    with pytest.raises(StateOutOfBounds, match=r'at t=0.0001 s'):
        sim.advance()
    assert sim.plant.status == 'failed'


@pytest.mark.parametrize('x, ok', [((0.0, 74.9, 0.0, 0.0), True), ((0.0, -75.1, 0.0, 0.0), False),
                                   ((0.0, 0.0, 1.5, 0.0), True), ((0.0, 0.0, -1.6, 0.0), False)])
def test_check_state(x, ok):
    plant = make_plant(ModelParameters(model='delay-free', speed=75.0), x)
    if ok:
        check_state(plant)
    else:
        with pytest.raises(StateOutOfBounds):
            check_state(plant)


def test_a_normal_run_stays_inside():
    r = simulate(ModelParameters(model='delay-free'), StateFeedback(), 1.0, control_period=1e-4)
    assert abs(r.state[:, 1]).max() < 10.0
