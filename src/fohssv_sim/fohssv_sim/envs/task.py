"""What every fohssv environment shares: its keyword arguments, spaces, start draw and reward.

:class:`Task` is built from an environment's keyword arguments: the model parameters (the rows
of :data:`fohssv_sim.params.PARAMETERS`, validated by :class:`~fohssv_sim.params.ModelParameters`,
so a bad ``speed`` is refused in the words the plant node uses), the plant node's
``control_period`` and ``initial_state`` rows, the controllers' deflection-limit rows and the
environment's own rows (:data:`ENV_PARAMETERS`). An unknown name is refused listing the valid
ones. The in-process, vectorised and ROS-backed environments all read the same :class:`Task`,
so they observe, reward and end episodes by one rule.

Pure: numpy and the core; no rclpy, no Gymnasium.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..control import deflection_limit
from ..models import MAX_PITCH
from ..param_kinds import CONTROL_PERIOD, INITIAL_STATE, FlagSpec, StateSpec
from ..params import (
    PARAMETER_BY_NAME,
    ModelParameters,
    ParameterError,
    ParameterSpec,
    steps_per_period,
)
from ..physics import jitable

__all__ = ['ENV_PARAMETERS', 'Task', 'RewardFunction', 'default_reward', 'make_task',
           'DEFAULT_EPISODE_STEPS', 'DEFAULT_SPREAD', 'LOST_PENALTY']

#: Control periods in an episode before it is truncated (0.2 s at the default 1e-4 s period).
DEFAULT_EPISODE_STEPS = 2000
#: Half-widths of the uniform start draw around ``initial_state`` [z m, w m/s, theta rad,
#: q rad/s]: a small offset the default controllers recover from.
DEFAULT_SPREAD = (0.01, 0.1, 0.002, 0.05)
#: Added (negated) to the reward of the step that loses the vehicle.
LOST_PENALTY = 100.0

_P = ParameterSpec


class _Spread(StateSpec):
    def range_text(self) -> str:
        return '4 finite numbers >= 0 [z m, w m/s, theta rad, q rad/s]'

    def validate(self, value: Any) -> Any:
        vals = super().validate(value)
        if min(vals) < 0.0:
            raise self.refuse(value, 'has a negative half-width')
        return vals


class _Range(ParameterSpec):
    """A (low, high) draw range of a model parameter, each end validated by that row."""

    def range_text(self) -> str:
        row = PARAMETER_BY_NAME[self.reference]
        return f'none or (low, high), low <= high, each in {row.range_text()}'

    def validate(self, value: Any) -> Any:
        if value is None:
            return None
        try:
            lo, hi = value
        except (TypeError, ValueError):
            raise self.refuse(value, 'is not a pair (low, high)') from None
        row = PARAMETER_BY_NAME[self.reference]
        lo, hi = row.validate(lo), row.validate(hi)
        if isinstance(lo, str) or isinstance(hi, str) or lo > hi:
            raise self.refuse(value, 'is not an increasing pair of numbers')
        return (lo, hi)


#: The environments' own keyword arguments (besides the model parameters, ``control_period``,
#: ``initial_state`` and the deflection limits).
ENV_PARAMETERS: tuple[ParameterSpec, ...] = (
    _P('episode_steps', '-', DEFAULT_EPISODE_STEPS, 'periods', 'control periods before the '
       'episode is truncated', low=1.0, low_open=False, high=1e9, high_open=False),
    _P('target_depth', 'z_ref', 0.0, 'm', 'depth the default reward tracks', low=-100.0,
       high=100.0, low_open=False, high_open=False),
    _P('depth_scale', '-', 0.1, 'm', 'depth error that costs 1 per step in the default reward',
       low=0.0),
    _P('planing_weight', '-', 1e-4, 's^4/m^4', 'weight of Fp^2 in the default reward',
       low=0.0, low_open=False),
    _P('rate_weight', '-', 1.0, '-', 'weight of the squared change of each deflection, in '
       'units of its limit, in the default reward', low=0.0, low_open=False),
    _P('lost_penalty', '-', LOST_PENALTY, '-', 'subtracted from the reward of the step that '
       'loses the vehicle', low=0.0, low_open=False),
    FlagSpec('fin', '-', False, '-', 'the action holds the fin deflection too '
             '[delta_f, delta_c]; else [delta_c] with delta_f = 0'),
    FlagSpec('observe_planing_force', '-', False, '-', 'append Fp (m^2/s^2) to the observation'),
    FlagSpec('observe_depth_error', '-', False, '-', 'append z - target_depth (m) to the '
             'observation'),
    _Spread('initial_spread', '-', DEFAULT_SPREAD, 'm, m/s, rad, rad/s', 'half-widths of '
            'the uniform draw of the start state around initial_state at each reset',
            numeric=False),
    _Range('speed_range', '-', None, 'm/s', 'draw V uniformly in (low, high) at each reset '
           '(domain randomisation); none = the speed parameter', numeric=False,
           reference='speed'),
    _Range('order_range', '-', None, '-', 'draw alpha uniformly in (low, high) at each reset '
           '(domain randomisation); none = the fractional_order parameter', numeric=False,
           reference='fractional_order'),
)
_ENV = {s.name: s for s in ENV_PARAMETERS}
_LIMITS = {
    'max_cavitator_deflection': deflection_limit('max_cavitator_deflection',
                                                 'largest |delta_c| an action may ask'),
    'max_fin_deflection': deflection_limit('max_fin_deflection',
                                           'largest |delta_f| an action may ask'),
}
_TAKEN = {'control_period': CONTROL_PERIOD, 'initial_state': INITIAL_STATE,
          **_LIMITS, **_ENV}

#: ``reward(state, action, previous_action, planing_force, target_depth) -> float``: state
#: [z, w, theta, q] after the step, action and previous_action the applied (delta_f, delta_c)
#: in rad, planing_force Fp (m^2/s^2) after the step, target_depth in m.
RewardFunction = Callable[[np.ndarray, np.ndarray, np.ndarray, float, float], float]


@jitable
def default_reward(z, planing_force, delta_f, delta_c, previous_f, previous_c, target_depth,
                   depth_scale, planing_weight, rate_weight, max_fin, max_cavitator):
    """The default reward of one step (scalars; the one rule, called interpreted by the
    single env and compiled by the vectorised one):

    -((z - z_ref) / depth_scale)^2 - planing_weight Fp^2
    - rate_weight [((delta_f - delta_f') / max_fin_deflection)^2
                   + ((delta_c - delta_c') / max_cavitator_deflection)^2]

    with the primed deflections those of the previous step (0 at the first step)."""
    e = (z - target_depth) / depth_scale
    a = (delta_f - previous_f) / max_fin
    b = (delta_c - previous_c) / max_cavitator
    return -(e * e) - planing_weight * planing_force * planing_force - rate_weight * (a * a + b * b)


@dataclass(frozen=True)
class Task:
    """The validated keyword arguments of an environment (see the module docstring)."""

    params: ModelParameters
    control_period: float
    hold: int
    initial_state: tuple
    limits: np.ndarray             # [max |delta_f|, max |delta_c|] (rad)
    episode_steps: int
    target_depth: float
    depth_scale: float
    planing_weight: float
    rate_weight: float
    lost_penalty: float
    fin: bool
    observe_planing_force: bool
    observe_depth_error: bool
    initial_spread: tuple
    speed_range: tuple | None
    order_range: tuple | None
    reward: RewardFunction | None

    @property
    def duration(self) -> float:
        """Simulated seconds of a full episode (sizes the FOM's 'soe' history)."""
        return self.episode_steps * self.control_period

    @property
    def action_size(self) -> int:
        return 2 if self.fin else 1

    @property
    def observation_size(self) -> int:
        return 4 + self.observe_planing_force + self.observe_depth_error

    # -- per step ---------------------------------------------------------------------------
    def action(self, action: Any) -> tuple[float, float]:
        """(delta_f, delta_c) in rad from an action.

        Raises:
            ValueError: the wrong shape, a non-finite value, or a value beyond the actuator
                limit (naming it, the value and the range in rad).
        """
        a = np.asarray(action, dtype=float).reshape(-1)
        names = ('delta_f', 'delta_c') if self.fin else ('delta_c',)
        if a.size != len(names):
            raise ValueError(f'action={action!r} must hold {len(names)} number(s) '
                             f"[{', '.join(names)}] in rad")
        limits = self.limits if self.fin else self.limits[1:]
        for name, v, lim in zip(names, a.tolist(), limits.tolist()):
            if not (-lim <= v <= lim):
                what = 'is not finite' if not math.isfinite(v) else 'is outside the actuator range'
                raise ValueError(f'action {name}={v!r} rad {what}; allowed: [{-lim:g}, {lim:g}] '
                                 f'rad (max_{"fin" if name == "delta_f" else "cavitator"}'
                                 '_deflection)')
        return (a[0], a[1]) if self.fin else (0.0, a[0])

    def observe(self, state: Any, planing_force: Any, target_depth: Any = None) -> np.ndarray:
        """The observation [z, w, theta, q] (+ Fp) (+ z - target_depth), vectorised over
        leading axes (``target_depth`` default: this task's)."""
        state = np.asarray(state, dtype=np.float64)
        if not (self.observe_planing_force or self.observe_depth_error):
            return state.copy()
        parts = [state]
        if self.observe_planing_force:
            parts.append(np.asarray(planing_force, dtype=np.float64)[..., None])
        if self.observe_depth_error:
            target = self.target_depth if target_depth is None else target_depth
            parts.append((state[..., 0] - target)[..., None])
        return np.concatenate(parts, axis=-1)

    def score(self, state: np.ndarray, action: np.ndarray, previous: np.ndarray,
              planing_force: float, lost: bool) -> float:
        """The reward of one step: the user's function or :func:`default_reward`, minus
        ``lost_penalty`` when the step lost the vehicle."""
        if self.reward is not None:
            r = float(self.reward(state, action, previous, planing_force, self.target_depth))
        else:
            lf, lc = self.limits.tolist()
            r = default_reward(float(state[0]), planing_force, float(action[0]),
                               float(action[1]), float(previous[0]), float(previous[1]),
                               self.target_depth, self.depth_scale, self.planing_weight,
                               self.rate_weight, lf, lc)
        return r - self.lost_penalty if lost else r

    @staticmethod
    def in_bounds(state: Sequence[float], speed: float) -> bool:
        """The plant's physical bounds |w| <= V, |theta| <= pi/2 (as
        :func:`fohssv_sim.models.check_state`; False for a NaN w or theta, and a plant whose
        state turns non-finite raises before)."""
        return bool(-speed <= state[1] <= speed and -MAX_PITCH <= state[2] <= MAX_PITCH)

    # -- per reset --------------------------------------------------------------------------
    def draw(self, rng: np.random.Generator,
             initial_state: Sequence[float] | None = None) -> tuple[ModelParameters, tuple]:
        """The episode's parameters and start state from ``rng``: V from ``speed_range``,
        then alpha from ``order_range`` (each only when set), then the start state
        ``initial_state + U(-1, 1)^4 * initial_spread``; an explicit ``initial_state`` (a
        reset option) is used as it is and draws nothing for the state.

        Raises:
            ParameterError: a drawn V or alpha the model refuses; a bad ``initial_state``.
        """
        changes = {}
        if self.speed_range is not None:
            changes['speed'] = float(rng.uniform(*self.speed_range))
        if self.order_range is not None:
            changes['fractional_order'] = float(rng.uniform(*self.order_range))
        params = self.params.replace(**changes) if changes else self.params
        if initial_state is not None:
            return params, INITIAL_STATE.validate(initial_state)
        noise = rng.uniform(-1.0, 1.0, 4) * np.array(self.initial_spread)
        return params, tuple((np.array(self.initial_state) + noise).tolist())


def make_task(kwargs: Mapping[str, Any]) -> Task:
    """A :class:`Task` from an environment's keyword arguments.

    Raises:
        ParameterError: an unknown name (listing the valid ones), or an invalid value (naming
            it, the value, the allowed range and unit).
    """
    kwargs = dict(kwargs)
    reward = kwargs.pop('reward', None)
    if reward is not None and not callable(reward):
        raise ParameterError(f'reward={reward!r} is not callable; allowed: none (the default '
                             'reward) or reward(state, action, previous_action, planing_force, '
                             'target_depth) -> float')
    unknown = sorted(set(kwargs) - set(PARAMETER_BY_NAME) - set(_TAKEN))
    if unknown:
        raise ParameterError(f"unknown keyword argument(s) {', '.join(unknown)}; valid names: "
                             f"{', '.join([*PARAMETER_BY_NAME, *_TAKEN, 'reward'])}")
    params = ModelParameters(**{k: v for k, v in kwargs.items() if k in PARAMETER_BY_NAME})
    v = {name: spec.validate(kwargs.get(name, spec.default)) for name, spec in _TAKEN.items()}
    if v['episode_steps'] != int(v['episode_steps']):
        raise _ENV['episode_steps'].refuse(kwargs['episode_steps'], 'is not a whole number')
    try:
        hold = steps_per_period(v['control_period'], params.step)
    except ValueError as exc:
        raise ParameterError(str(exc)) from None
    if v['order_range'] is not None and params.model != 'fractional':
        raise _ENV['order_range'].refuse(v['order_range'], f'needs model=\'fractional\', got '
                                         f'{params.model!r}')
    for name in ('speed_range', 'order_range'):     # both ends must make a valid model
        if v[name] is not None:
            for end in v[name]:
                params.replace(**{_ENV[name].reference: end})
    return Task(params=params, control_period=v['control_period'], hold=hold,
                initial_state=v['initial_state'],
                limits=np.array([v['max_fin_deflection'], v['max_cavitator_deflection']]),
                episode_steps=int(v['episode_steps']), target_depth=v['target_depth'],
                depth_scale=v['depth_scale'], planing_weight=v['planing_weight'],
                rate_weight=v['rate_weight'], lost_penalty=v['lost_penalty'], fin=v['fin'],
                observe_planing_force=v['observe_planing_force'],
                observe_depth_error=v['observe_depth_error'],
                initial_spread=v['initial_spread'], speed_range=v['speed_range'],
                order_range=v['order_range'], reward=reward)
