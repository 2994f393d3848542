"""A gain-scheduled state feedback: eq. 31's form with its four gains interpolated over V::

    delta_c = k_z(V) z + k_w(V) w + k_theta(V) theta + k_q(V) q,    delta_f = 0,

where each gain k(V) is piecewise linear between its values at the four breakpoints
``speed_1 < speed_2 < speed_3 < speed_4`` (m/s) and held at the end values outside them. The
table is the law's parameters (``depth_gain_k``, ``vertical_velocity_gain_k``,
``pitch_gain_k``, ``pitch_rate_gain_k`` at ``speed_k``), so ``fohssv tune`` can tune one gain
set per speed band. With every row at eq. 31's gains (the defaults) it is eq. 31 at any V.

The scheduling variable is the parameter ``speed``: the vehicle's V, which the state message
does not carry. Set it to the plant's speed (``-p speed:=90``, or live: it needs no reset);
:attr:`Scheduled.scheduling` tells the simulation and the analysis (``fohssv tune``,
``fohssv gainmap``) to set it from each scenario's ``speed`` model parameter. At a fixed V the
law is affine (:meth:`Scheduled.affine`), so batched runs take it. Stateless.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from fohssv_sim.control import Controller, deflection_limit
from fohssv_sim.params import ParameterSpec, field_specs, spec_field, validate_fields

__all__ = ['Scheduled', 'ScheduledParameters', 'BREAKPOINTS', 'GAINS']

#: Number of rows of the schedule (breakpoints in V).
BREAKPOINTS = 4
#: The gains of each row, with eq. 31's values (the defaults) and units.
GAINS = (('depth_gain', 15.0, 'rad/m', 'delta_c per metre of z'),
         ('vertical_velocity_gain', 0.0, 'rad s/m', 'delta_c per m/s of w'),
         ('pitch_gain', -30.0, 'rad/rad', 'delta_c per radian of theta'),
         ('pitch_rate_gain', -0.3, 'rad s/rad', 'delta_c per rad/s of q'))
_DEFAULT_SPEEDS = (60.0, 80.0, 100.0, 120.0)


def _speed(name: str, default: float, text: str) -> ParameterSpec:
    return ParameterSpec(name, 'V', default, 'm/s', text, low=0.0, high=1000.0,
                         high_open=False, needs_reset=False)


def _gain(name: str, k: int, default: float, unit: str, text: str) -> ParameterSpec:
    return ParameterSpec(f'{name}_{k}', '-', default, unit, f'{text} at speed_{k}',
                         reference='eq. 31, scheduled', needs_reset=False)


def _fields() -> dict[str, object]:
    """The dataclass fields, in table order: speed, then per row its breakpoint and gains."""
    out: dict[str, object] = {'speed': spec_field(_speed(
        'speed', 75.0, "V the gains are read at (the scheduling variable): the plant's speed"))}
    for k in range(1, BREAKPOINTS + 1):
        out[f'speed_{k}'] = spec_field(_speed(f'speed_{k}', _DEFAULT_SPEEDS[k - 1],
                                              f'breakpoint {k} of the schedule (increasing)'))
        for name, default, unit, text in GAINS:
            out[f'{name}_{k}'] = spec_field(_gain(name, k, default, unit, text))
    out['max_cavitator_deflection'] = spec_field(deflection_limit(
        'max_cavitator_deflection', '|delta_c| is clamped to this'))
    out['max_fin_deflection'] = spec_field(deflection_limit(
        'max_fin_deflection', '|delta_f| is clamped to this'))
    return out


def _post_init(self) -> None:
    validate_fields(self)
    speeds = [getattr(self, f'speed_{k}') for k in range(1, BREAKPOINTS + 1)]
    for k in range(1, BREAKPOINTS):
        if not speeds[k] > speeds[k - 1]:
            spec = {s.name: s for s in field_specs(type(self))}[f'speed_{k + 1}']
            raise spec.refuse(speeds[k], f'is not above speed_{k}={speeds[k - 1]!r} (the '
                              'breakpoints must increase)')


# A frozen dataclass built from the table (23 fields written once, not by hand).
ScheduledParameters = dataclass(frozen=True)(type('ScheduledParameters', (), {
    '__annotations__': {name: float for name in _fields()},
    **_fields(),
    '__post_init__': _post_init,
    '__module__': __name__,
    '__doc__': 'Scheduling speed, the schedule (breakpoints and gains per row) and the '
               'deflection limits. Validated on construction.'}))


def interpolate(speeds: Sequence[float], values: Sequence[float], v: float) -> float:
    """Piecewise-linear ``values`` over increasing ``speeds`` at ``v``, held outside."""
    if v <= speeds[0]:
        return float(values[0])
    for k in range(1, len(speeds)):
        if v <= speeds[k]:
            s = (v - speeds[k - 1]) / (speeds[k] - speeds[k - 1])
            return float(values[k - 1] + s * (values[k] - values[k - 1]))
    return float(values[-1])


class Scheduled(Controller):
    """Eq. 31's form with gains interpolated over V (see the module docstring). Stateless."""

    name = 'scheduled'
    Parameters = ScheduledParameters
    scheduling = {'speed': 'speed'}

    def reset(self) -> None:
        self._k = self.gains_at(self.params.speed)

    def gains_at(self, v: float) -> tuple[float, float, float, float]:
        """(k_z, k_w, k_theta, k_q) of the schedule at speed ``v`` (m/s)."""
        p = self.params
        speeds = [getattr(p, f'speed_{k}') for k in range(1, BREAKPOINTS + 1)]
        return tuple(interpolate(speeds, [getattr(p, f'{name}_{k}')
                                          for k in range(1, BREAKPOINTS + 1)], v)
                     for name, *_ in GAINS)

    def update(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        kz, kw, kth, kq = self._k
        return 0.0, kz * state[0] + kw * state[1] + kth * state[2] + kq * state[3]

    def affine(self) -> tuple[list[list[float]], list[float]]:
        return [[0.0, 0.0, 0.0, 0.0], list(self._k)], [0.0, 0.0]
