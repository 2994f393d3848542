"""A fractional PI^lambda D^mu controller (Podlubny's form) on the depth and pitch channels::

    delta_c = sum over c in (depth, pitch) of  Kp_c e_c + Ki_c I^lambda e_c + Kd_c D^mu e_c,
    e_depth = z - depth_reference,  e_pitch = theta - pitch_reference,  delta_f = 0,

clamped to the deflection limits like every controller. I^lambda is the Riemann-Liouville
integral and D^mu the Caputo derivative, both from t = 0 (the first sample) and computed online
with O(1) cost per call by :mod:`fohssv_sim.fractional.operators` (product trapezoidal rule and
L1 scheme over the sum-of-exponentials history of the FOM solver, kernel tolerance 1e-10).
With lambda = mu = 1 it is the integer PID with a trapezoidal integral and a backward-difference
derivative; with the default gains (Ki = 0, mu = 1) it is eq. 31 with q replaced by the
backward difference of theta.

The operators need the samples on a uniform grid: the step is taken from the first two calls
(the control period) and every later call must keep it (to 1e-6 relative), which the zero-order
hold of the plant node and of ``simulate(..., control_period=...)`` does. It keeps memory, so
continuous feedback (evaluated at solver stages) is refused, as for any stateful controller.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from fohssv_sim.control import Controller, deflection_limit
from fohssv_sim.fractional import OnlineCaputoDerivative, OnlineIntegral
from fohssv_sim.params import ParameterSpec, spec_field, validate_fields

__all__ = ['FractionalPID', 'FractionalPIDParameters']


def _gain(name: str, default: float, unit: str, text: str) -> ParameterSpec:
    return ParameterSpec(name, '-', default, unit, text, reference='Podlubny PI^lambda D^mu',
                         needs_reset=False)


def _order(name: str, text: str) -> ParameterSpec:
    return ParameterSpec(name, '-', 1.0, '-', text, low=0.0, high=1.0, high_open=False,
                         reference='Podlubny PI^lambda D^mu')


@dataclass(frozen=True)
class FractionalPIDParameters:
    """Gains, orders, references and deflection limits. Validated on construction."""

    depth_kp: float = spec_field(_gain('depth_kp', 15.0, 'rad/m', 'delta_c per metre of depth '
                                       'error'))
    depth_ki: float = spec_field(_gain('depth_ki', 0.0, 'rad/(m s^lambda)', 'delta_c per unit '
                                       'of I^lambda of the depth error'))
    depth_kd: float = spec_field(_gain('depth_kd', 0.0, 'rad s^mu/m', 'delta_c per unit of '
                                       'D^mu of the depth error'))
    pitch_kp: float = spec_field(_gain('pitch_kp', -30.0, 'rad/rad', 'delta_c per radian of '
                                       'pitch error'))
    pitch_ki: float = spec_field(_gain('pitch_ki', 0.0, 'rad/(rad s^lambda)', 'delta_c per '
                                       'unit of I^lambda of the pitch error'))
    pitch_kd: float = spec_field(_gain('pitch_kd', -0.3, 'rad s^mu/rad', 'delta_c per unit of '
                                       'D^mu of the pitch error'))
    integral_order: float = spec_field(_order('integral_order', 'lambda, order of the '
                                              'fractional integral (1 = ordinary integral)'))
    derivative_order: float = spec_field(_order('derivative_order', 'mu, order of the Caputo '
                                                'derivative (1 = ordinary derivative)'))
    depth_reference: float = spec_field(ParameterSpec(
        'depth_reference', '-', 0.0, 'm', 'depth the depth channel regulates to',
        needs_reset=False))
    pitch_reference: float = spec_field(ParameterSpec(
        'pitch_reference', '-', 0.0, 'rad', 'pitch the pitch channel regulates to',
        needs_reset=False))
    max_cavitator_deflection: float = spec_field(deflection_limit(
        'max_cavitator_deflection', '|delta_c| is clamped to this'))
    max_fin_deflection: float = spec_field(deflection_limit(
        'max_fin_deflection', '|delta_f| is clamped to this'))

    def __post_init__(self) -> None:
        validate_fields(self)


class FractionalPID(Controller):
    """Podlubny's PI^lambda D^mu on depth and pitch, delta_c out (see the module docstring)."""

    name = 'fractional_pid'
    Parameters = FractionalPIDParameters
    stateless = False

    def reset(self) -> None:
        self._t0: float | None = None
        self._step: float | None = None
        self._first: list[float] | None = None
        self._integral: OnlineIntegral | None = None
        self._derivative: OnlineCaputoDerivative | None = None

    def _operators(self, step: float) -> None:
        p = self.params
        self._integral = OnlineIntegral(p.integral_order, step, 2)
        self._derivative = OnlineCaputoDerivative(p.derivative_order, step, 2)

    def update(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        p = self.params
        e = [state[0] - p.depth_reference, state[2] - p.pitch_reference]
        if self._t0 is None:                       # t_0: no history yet, I = D = 0
            self._t0, self._first = t, e
            return 0.0, p.depth_kp * e[0] + p.pitch_kp * e[1]
        if self._step is None:
            self._step = t - self._t0
            self._operators(self._step)
            self._integral.update(self._first)
            self._derivative.update(self._first)
        n = self._integral.n
        expected = self._t0 + n * self._step
        if abs(t - expected) > 1e-6 * self._step:
            raise ValueError(f'fractional_pid needs uniform samples: got t={t!r} s, expected '
                             f'{expected!r} s (step {self._step!r} s from the first two calls)')
        i = self._integral.update(e)
        d = self._derivative.update(e)
        dc = (p.depth_kp * e[0] + p.depth_ki * i[0] + p.depth_kd * d[0]
              + p.pitch_kp * e[1] + p.pitch_ki * i[1] + p.pitch_kd * d[1])
        return 0.0, float(dc)
