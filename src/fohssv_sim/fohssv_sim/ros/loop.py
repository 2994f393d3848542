"""The plant as the ROS node drives it, without ROS: sampling, command checks and pacing.

Pure (no rclpy), so the node's callbacks only call into this module. :class:`SampledPlant`
steps a :class:`~fohssv_sim.models.Plant` ``hold`` integration steps per published sample with
the command held (zero-order hold), exactly as :func:`fohssv_sim.simulate.simulate` does with
the same ``control_period``: both take the command computed from the sample at t_n and apply it
over [t_n, t_n + control_period). :func:`check_command` decides whether a command message is
usable. :class:`Pacer` schedules real-time samples against the wall clock and counts deadline
misses.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from ..contract import COMMAND, ContractError, decode
from ..models import Plant, make_plant
from ..params import ModelParameters
from ..simulate import steps_per_period

__all__ = ['CommandRejected', 'SampledPlant', 'check_command', 'Pacer']


class CommandRejected(ValueError):
    """A command message that must not be applied (the reason is the message)."""


def check_command(data: Sequence[float], max_fin: float, max_cavitator: float
                  ) -> tuple[float, float, float]:
    """``(t, delta_f, delta_c)`` from a ``command`` message's data.

    Raises:
        CommandRejected: wrong length, a non-finite value, or a deflection beyond its limit.
    """
    try:
        t, df, dc = decode(COMMAND, data)
    except ContractError as exc:
        raise CommandRejected(str(exc)) from None
    if abs(df) > max_fin:
        raise CommandRejected(f'command: delta_f={df:g} rad exceeds max_fin_deflection='
                              f'{max_fin:g} rad')
    if abs(dc) > max_cavitator:
        raise CommandRejected(f'command: delta_c={dc:g} rad exceeds max_cavitator_deflection='
                              f'{max_cavitator:g} rad')
    return t, df, dc


def answered_time(data: Sequence[float]) -> float | None:
    """The time a (possibly malformed) command claims to answer: ``data[0]`` if it is a finite
    number, else ``None``."""
    if len(data) == 0:
        return None
    t = float(data[0])
    return t if math.isfinite(t) else None


class SampledPlant:
    """A plant sampled every ``control_period`` with the command held in between.

    ``command`` is the held (last good) input ``(delta_f, delta_c)``; :meth:`advance` runs one
    control period with it. ``failure`` is the error text once the state turned non-finite.
    """

    def __init__(self, params: ModelParameters, control_period: float,
                 initial_state: Sequence[float] | None = None,
                 duration: float | None = None) -> None:
        self.hold = steps_per_period(control_period, params.step)
        self.control_period = control_period
        # duration (s, None or 0 = open-ended) sizes the FOM's 'soe' history as simulate() does
        # for the same run, so lockstep and the batch runner give the same numbers
        self.plant: Plant = make_plant(params, initial_state, duration=duration or None)
        self.compile_seconds = self.plant.compile()   # before the first sample, not during it
        self.command: tuple[float, float] = (0.0, 0.0)
        self.samples = 0

    @property
    def t(self) -> float:
        """Simulation time of the current sample (s), exactly ``n h`` as the plant computes it."""
        return self.plant.t

    def reset(self, initial_state: Sequence[float] | None = None) -> None:
        """Back to t = 0; the held command returns to zero."""
        self.plant.reset(initial_state)
        self.command = (0.0, 0.0)
        self.samples = 0

    def sample(self) -> tuple[tuple[float, ...], tuple[float, float]]:
        """``([t, z, w, theta, q], [t, Fp])`` of the current sample."""
        t = self.plant.t
        return (t, *self.plant.x), (t, self.plant.planing_force)

    def advance(self) -> None:
        """One control period with the held command.

        Raises:
            FloatingPointError: the state turned non-finite (names the time and state).
        """
        self.plant.advance(self.command, self.hold)   # one compiled call (held input)
        self.samples += 1

    def reached(self, duration: float) -> bool:
        """True when ``duration`` > 0 and the current sample is at or past it."""
        return duration > 0.0 and self.plant.t >= duration - 1e-9 * self.control_period


@dataclass
class Pacer:
    """Wall-clock schedule of real-time samples.

    Sample j is due at ``start + j * period`` (``period`` = control_period / real_time_factor,
    wall seconds) and misses its deadline when it is published more than ``tolerance`` (one
    pacing tick) after that. Each tick publishes every due sample, at most ``max_batch``;
    when the backlog exceeds ``max_backlog`` samples the schedule is moved forward (a slip):
    the run then falls behind real time instead of bursting to catch up, and the achieved
    real-time factor shows it.
    """

    period: float
    tolerance: float
    max_batch: int
    max_backlog: int
    start: float = 0.0
    produced: int = 0
    misses: int = 0
    slips: int = 0
    worst_lateness: float = 0.0

    def begin(self, now: float) -> None:
        self.start = now
        self.produced = self.misses = self.slips = 0
        self.worst_lateness = 0.0

    def due(self, now: float) -> int:
        """How many samples to publish now."""
        backlog = int((now - self.start) / self.period) + 1 - self.produced
        if backlog > self.max_backlog:
            self.start += (backlog - self.max_batch) * self.period
            self.slips += 1
            backlog = self.max_batch
        return max(0, min(backlog, self.max_batch))

    def published(self, now: float) -> None:
        """Record that the next sample was published at wall time ``now``."""
        lateness = now - (self.start + self.produced * self.period)
        if lateness > self.tolerance:
            self.misses += 1
        self.worst_lateness = max(self.worst_lateness, lateness)
        self.produced += 1
