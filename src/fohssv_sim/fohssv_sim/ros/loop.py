"""The plant as the ROS node drives it, without ROS: sampling, command checks and pacing.

Pure (no rclpy), so the node's callbacks only call into this module. :class:`SampledPlant`
steps a :class:`~fohssv_sim.models.Plant` ``hold`` integration steps per published sample with
the command held (zero-order hold), exactly as :func:`fohssv_sim.simulate.simulate` does with
the same ``control_period``: both take the command computed from the sample at t_n and apply it
over [t_n, t_n + control_period). :func:`check_command` decides whether a command message is
usable. :class:`Pacer` schedules real-time samples against the wall clock and counts deadline
misses. :class:`Profile` accumulates per-sample costs when the node's ``profile`` option is on.

The node calls these on every sample (10 kHz at the default control period): the good path of
each is a few attribute reads and float comparisons, with no allocation beyond what the model
step itself needs; the slow paths (a rejected command, a log line) build their text only then.
"""

from __future__ import annotations

import math
import time
from collections.abc import MutableSequence, Sequence
from dataclasses import dataclass, field

from ..contract import COMMAND, ContractError, decode
from ..models import MAX_PITCH, Plant, check_state, make_plant
from ..params import ModelParameters
from ..simulate import steps_per_period

__all__ = ['CommandRejected', 'SampledPlant', 'check_command', 'answered_time', 'Pacer',
           'Profile']


class CommandRejected(ValueError):
    """A command message that must not be applied (the reason is the message)."""


def check_command(data: Sequence[float], max_fin: float, max_cavitator: float
                  ) -> tuple[float, float, float]:
    """``(t, delta_f, delta_c)`` from a ``command`` message's data.

    Raises:
        CommandRejected: wrong length, a non-finite value, or a deflection beyond its limit.
    """
    if len(data) == 3:
        # good path (every sample): comparisons are False for NaN; t - t is NaN for +-inf
        t, df, dc = data
        if abs(df) <= max_fin and abs(dc) <= max_cavitator and t - t == 0.0:
            return float(t), float(df), float(dc)
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
        self._w_max = params.speed      # physical bounds of the state (models.check_state)
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

    def write_sample(self, state: MutableSequence[float], force: MutableSequence[float]) -> None:
        """Write the current sample into preallocated buffers, in place: ``state[0:5] = [t, z,
        w, theta, q]``, ``force[0:2] = [t, Fp]`` (the node's message arrays; no allocation)."""
        plant = self.plant
        t = plant.t
        x = plant.x
        state[0] = t
        state[1] = x[0]
        state[2] = x[1]
        state[3] = x[2]
        state[4] = x[3]
        force[0] = t
        force[1] = plant.planing_force

    def sample(self) -> tuple[tuple[float, ...], tuple[float, float]]:
        """``([t, z, w, theta, q], [t, Fp])`` of the current sample."""
        t = self.plant.t
        return (t, *self.plant.x), (t, self.plant.planing_force)

    def advance(self) -> None:
        """One control period with the held command.

        Raises:
            FloatingPointError: the state turned non-finite, or
                :class:`~fohssv_sim.models.StateOutOfBounds` (a FloatingPointError): it left
                |w| <= V, |theta| <= pi/2 (both name the time and state).
        """
        plant = self.plant
        plant.advance(self.command, self.hold)   # one compiled call (held input)
        self.samples += 1
        x = plant.x
        w_max = self._w_max
        if not (-w_max <= x[1] <= w_max and -MAX_PITCH <= x[2] <= MAX_PITCH):
            check_state(plant)                  # raises StateOutOfBounds

    def reached(self, duration: float) -> bool:
        """True when ``duration`` > 0 and the current sample is at or past it."""
        return duration > 0.0 and self.plant.t >= duration - 1e-9 * self.control_period


@dataclass
class Pacer:
    """Wall-clock schedule of real-time samples, one sample at a time.

    Sample j is due at ``start + j * period`` (``period`` = control_period / real_time_factor,
    wall seconds). The node's loop waits (spinning the executor, so commands are taken
    meanwhile) until :meth:`next_due`, then advances and publishes that one sample. A sample
    misses its deadline when it is published more than ``tolerance`` (the ``pacing_period``)
    after it was due; ``late`` counts those published more than one ``period`` after it, and
    ``lateness_sum`` / ``worst_lateness`` give the mean and worst. When the backlog exceeds
    ``max_backlog`` samples the schedule is moved forward to a backlog of ``max_batch`` (a
    slip): the run then falls behind real time instead of bursting to catch up, and the
    achieved real-time factor shows it.
    """

    period: float
    tolerance: float
    max_batch: int
    max_backlog: int
    start: float = 0.0
    produced: int = 0
    misses: int = 0
    late: int = 0
    slips: int = 0
    worst_lateness: float = 0.0
    lateness_sum: float = 0.0

    def begin(self, now: float) -> None:
        self.start = now
        self.produced = self.misses = self.late = self.slips = 0
        self.worst_lateness = self.lateness_sum = 0.0

    def next_due(self) -> float:
        """Wall time at which the next sample is due."""
        return self.start + self.produced * self.period

    def due(self, now: float) -> int:
        """How many samples are due by ``now`` (after a slip if the backlog is too long)."""
        backlog = int((now - self.start) / self.period) + 1 - self.produced
        if backlog > self.max_backlog:
            self.start += (backlog - self.max_batch) * self.period
            self.slips += 1
            backlog = self.max_batch
        return max(0, min(backlog, self.max_batch))

    def published(self, now: float) -> None:
        """Record that the next sample was published at wall time ``now``."""
        lateness = now - (self.start + self.produced * self.period)
        if lateness > self.period:
            self.late += 1
        if lateness > self.tolerance:
            self.misses += 1
        if lateness > self.worst_lateness:
            self.worst_lateness = lateness
        self.lateness_sum += lateness
        self.produced += 1


#: The per-sample costs :class:`Profile` measures, in the order of its ``ns`` accumulators.
PROFILE_PARTS = ('advance', 'write_sample', 'publish_state', 'publish_planing_force',
                 'publish_clock', 'command_callback', 'publish_views')


@dataclass
class Profile:
    """Accumulated wall time (``time.perf_counter_ns``) of each part of the per-sample path.

    The node uses its profiled code path only when the ``profile`` option is on; then each part
    costs two ``perf_counter_ns`` calls (about 0.1 us) on top of itself. ``ns[i]`` and
    ``calls[i]`` belong to ``PROFILE_PARTS[i]``.
    """

    ns: list[int] = field(default_factory=lambda: [0] * len(PROFILE_PARTS))
    calls: list[int] = field(default_factory=lambda: [0] * len(PROFILE_PARTS))
    worst: list[int] = field(default_factory=lambda: [0] * len(PROFILE_PARTS))

    def add(self, part: int, ns: int) -> None:
        self.ns[part] += ns
        self.calls[part] += 1
        if ns > self.worst[part]:
            self.worst[part] = ns

    def summary(self) -> dict[str, dict[str, float]]:
        """Per part: mean and worst cost in microseconds and the number of calls."""
        return {name: {'mean_us': self.ns[i] / self.calls[i] / 1e3 if self.calls[i] else 0.0,
                       'worst_us': self.worst[i] / 1e3, 'calls': self.calls[i]}
                for i, name in enumerate(PROFILE_PARTS)}


def cpu_seconds() -> float:
    """CPU time of this process (user + system, all threads), for cost per sample figures."""
    return time.process_time()
