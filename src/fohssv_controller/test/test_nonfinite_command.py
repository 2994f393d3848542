"""Issue 12, defect 5: a control law whose output is not finite is never clamped into a
command (``clamp(nan)`` is the full limit). Pure: no rclpy."""

from __future__ import annotations

import math

import pytest

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.control import NonFiniteCommand, clamp
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate


def test_clamp_of_nan_is_the_limit_which_is_why_command_must_refuse_it():
    assert clamp(math.nan, 0.5) == 0.5


@pytest.mark.parametrize('state', [[10.0, 0.0, 10.0, 0.0], [1e10, 0.0, 0.0, 0.0]])
def test_overflowing_law_raises_instead_of_a_saturated_deflection(state):
    law = StateFeedback(depth_gain=1e308, pitch_gain=-1e308)
    with pytest.raises(NonFiniteCommand, match=r'state_feedback: non-finite output at '
                       r't=0.25 s: delta_f=0.0, delta_c=(nan|inf) rad from \[z, w, theta, q\]'):
        law.command(0.25, state)
    assert isinstance(NonFiniteCommand('x'), FloatingPointError)


def test_finite_law_is_still_clamped():
    law = StateFeedback(depth_gain=1e3)
    assert law.command(0.0, [1.0, 0.0, 0.0, 0.0]) == (0.0, 0.5)


def test_batch_run_stops_on_a_non_finite_law_output():
    law = StateFeedback(depth_gain=1e308, pitch_gain=-1e308)
    with pytest.raises(NonFiniteCommand, match='non-finite output'):
        simulate(ModelParameters(model='delay-free'), law, 0.05, control_period=1e-4,
                 initial_state=[10.0, 0.0, 10.0, 0.0])
