"""The paper's state feedback (eq. 31, signs of docs/model.md §9.5)::

    delta_c = 15 z - 30 theta - 0.3 q,    delta_f = 0
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from fohssv_sim.control import Controller, deflection_limit
from fohssv_sim.params import ParameterSpec, spec_field, validate_fields

__all__ = ['StateFeedback', 'StateFeedbackParameters']


def _gain(name: str, default: float, unit: str, text: str) -> ParameterSpec:
    return ParameterSpec(name, '-', default, unit, text, reference='eq. 31', needs_reset=False)


@dataclass(frozen=True)
class StateFeedbackParameters:
    """Gains of eq. 31 and the deflection limits. Validated on construction."""

    depth_gain: float = spec_field(_gain('depth_gain', 15.0, 'rad/m', 'delta_c per metre of z'))
    pitch_gain: float = spec_field(_gain('pitch_gain', -30.0, 'rad/rad',
                                         'delta_c per radian of theta'))
    pitch_rate_gain: float = spec_field(_gain('pitch_rate_gain', -0.3, 'rad s/rad',
                                              'delta_c per rad/s of q'))
    vertical_velocity_gain: float = spec_field(_gain('vertical_velocity_gain', 0.0, 'rad s/m',
                                                     'delta_c per m/s of w (0 in eq. 31)'))
    max_cavitator_deflection: float = spec_field(deflection_limit('max_cavitator_deflection',
                                                        '|delta_c| is clamped to this'))
    max_fin_deflection: float = spec_field(deflection_limit('max_fin_deflection',
                                                  '|delta_f| is clamped to this'))

    def __post_init__(self) -> None:
        validate_fields(self)


class StateFeedback(Controller):
    """Linear state feedback on the cavitator, fins at zero (eq. 31). Stateless."""

    name = 'state_feedback'
    Parameters = StateFeedbackParameters

    def update(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        p = self.params
        z, w, theta, q = state[0], state[1], state[2], state[3]
        dc = (p.depth_gain * z + p.vertical_velocity_gain * w + p.pitch_gain * theta
              + p.pitch_rate_gain * q)
        return 0.0, dc

    def affine(self) -> tuple[list[list[float]], list[float]]:
        p = self.params
        gains = [p.depth_gain, p.vertical_velocity_gain, p.pitch_gain, p.pitch_rate_gain]
        return [[0.0, 0.0, 0.0, 0.0], gains], [0.0, 0.0]
