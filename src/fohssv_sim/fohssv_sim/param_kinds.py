"""Parameter rows besides numbers and names, and the rows of a run every runner shares.

The kinds of row (each a :class:`~fohssv_sim.params.ParameterSpec` with its own check): a state
(:class:`StateSpec`, a double array in ROS), a switch (:class:`FlagSpec`, a bool), free text
such as a path (:class:`TextSpec`, a string) and a list of names (:class:`NamesSpec`, a string
array). The plant node's table (:mod:`fohssv_sim.ros.options`) and the environments' task
(:mod:`fohssv_sim.envs.task`) take :data:`CONTROL_PERIOD` and :data:`INITIAL_STATE` from here,
so both check them by the same rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .params import ParameterError, ParameterSpec

__all__ = ['StateSpec', 'FlagSpec', 'TextSpec', 'NamesSpec', 'CONTROL_PERIOD', 'INITIAL_STATE']


@dataclass(frozen=True)
class StateSpec(ParameterSpec):
    """A parameter holding a state [z, w, theta, q] (a double array in ROS)."""

    def range_text(self) -> str:
        return '4 finite numbers [z m, w m/s, theta rad, q rad/s]'

    def validate(self, value: Any) -> Any:
        """Return the state as a tuple of 4 floats.

        Raises:
            ParameterError: not 4 finite numbers.
        """
        try:
            vals = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            vals = ()
        if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
            raise ParameterError(f'{self.name}={value!r} is not valid; allowed: '
                                 f'{self.range_text()} ({self.description})')
        return vals


@dataclass(frozen=True)
class FlagSpec(ParameterSpec):
    """A switch: true or false (a bool in ROS)."""

    numeric: bool = False

    def range_text(self) -> str:
        return 'true | false'

    def validate(self, value: Any) -> bool:
        """Return the value.

        Raises:
            ParameterError: not a bool.
        """
        if not isinstance(value, bool):
            raise self.refuse(value, 'is not true or false')
        return value


@dataclass(frozen=True)
class TextSpec(ParameterSpec):
    """Free text, such as a path or a node name (a string in ROS), kept as given; ``allowed``
    says what it names, ``required`` refuses an empty value."""

    numeric: bool = False
    allowed: str = 'any text'
    required: bool = False

    def range_text(self) -> str:
        return self.allowed

    def validate(self, value: Any) -> str:
        """Return the value.

        Raises:
            ParameterError: not a string, or empty when required.
        """
        if not isinstance(value, str):
            raise self.refuse(value, 'is not text')
        if self.required and not value.strip():
            raise self.refuse(value, f'is empty: {self.name} is required')
        return value


@dataclass(frozen=True)
class NamesSpec(ParameterSpec):
    """A list of names, such as topics (a string array in ROS); ``allowed`` says which."""

    numeric: bool = False
    allowed: str = 'names'

    def range_text(self) -> str:
        return self.allowed

    def validate(self, value: Any) -> tuple[str, ...]:
        """Return the names as a tuple.

        Raises:
            ParameterError: not a list of strings.
        """
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise self.refuse(value, 'is not a list of names')
        return tuple(value)


#: The time between a runner's samples, over which the command is held.
CONTROL_PERIOD = ParameterSpec(
    'control_period', 'T', 1e-4, 's', 'simulated time between published samples; the '
    'command is held over it (zero-order hold); a whole multiple of step', low=0.0,
    high=1.0, high_open=False)

#: The state a run starts from.
INITIAL_STATE = StateSpec(
    'initial_state', 'x(0)', (0.0, 0.0, 0.0, 0.0), 'm, m/s, rad, rad/s',
    'state at t = 0 [z, w, theta, q]; a change applies at the next reset',
    numeric=False, needs_reset=False)
