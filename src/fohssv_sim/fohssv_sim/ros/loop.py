"""The plant as the ROS node drives it, without ROS: sampling and command checks.

Pure (no rclpy), so the node's callbacks only call into this module. :class:`SampledPlant`
steps a :class:`~fohssv_sim.models.Plant` ``hold`` integration steps per published sample with
the command held (zero-order hold), exactly as :func:`fohssv_sim.simulate.simulate` does with
the same ``control_period``: both take the command computed from the sample at t_n and apply it
over [t_n, t_n + control_period). :func:`check_command` decides whether a command message is
usable. :class:`HostedLaw` runs a controller plugin inside the loop (the plant's ``controller``
parameter). The real-time schedule is :mod:`.pacing`; the host's settings :mod:`.host`.

The node calls these on every sample (10 kHz at the default control period): the good path of
each is a few attribute reads and float comparisons, with no allocation beyond what the model
step itself needs; the slow paths (a rejected command, a log line) build their text only then.
"""

from __future__ import annotations

import math
from collections.abc import MutableSequence, Sequence
from typing import Any

from ..contract import COMMAND, ContractError, decode
from ..control import Controller, per_sample_command
from ..models import (
    MAX_PITCH,
    AffineLaw,
    FractionalModel,
    HeldPeriod,
    Plant,
    StateOutOfBounds,
    check_state,
    make_plant,
)
from ..params import ModelParameters
from ..simulate import steps_per_period

__all__ = ['CommandRejected', 'SampledPlant', 'check_command', 'answered_time', 'HostedLaw',
           'time_text']


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

    def advance_burst(self, law: AffineLaw, periods: int, limits: Any, out: Any
                      ) -> tuple[int, int]:
        """Up to ``periods`` control periods in one compiled call with the affine ``law``
        sampled at each new sample and held over the next period, starting with
        :attr:`command` (:meth:`fohssv_sim.models.Plant.advance_sampled`: rows of ``out``,
        the ``(samples, status)`` it returns, ``(0, -1)`` without a compiled kernel). The
        same numbers as :meth:`advance` per period with the law's command taken after each
        sample. :attr:`samples` and :attr:`command` are left to the caller, who takes the
        rows one by one (:meth:`took`)."""
        return self.plant.advance_sampled(law, self.command, self.hold, periods, limits, out)

    def took(self, command: tuple[float, float]) -> None:
        """One sample of a burst taken by the caller: count it; ``command`` is now held."""
        self.samples += 1
        self.command = command

    def held_period(self, state: MutableSequence[float]) -> HeldPeriod | None:
        """A :class:`~fohssv_sim.models.HeldPeriod` of this plant's control period writing
        its samples into ``state`` ([t, z, w, theta, q]), or None for a plant without one
        (the integer models, an interpreted FOM). Its sample, once settled, is counted with
        :meth:`took` (the command held over it set as :attr:`command` before); a period it
        raised for is passed to :meth:`failed_period`."""
        plant = self.plant
        if isinstance(plant, FractionalModel) and plant.engine == 'compiled':
            return HeldPeriod(plant, self.hold, state)
        return None

    def failed_period(self, exc: FloatingPointError) -> None:
        """Count a period that :class:`~fohssv_sim.models.HeldPeriod` ended with ``exc``
        as :meth:`advance` counts it: a state beyond the bounds is a sample, a non-finite
        one is not."""
        if isinstance(exc, StateOutOfBounds):
            self.samples += 1

    def samples_until(self, duration: float) -> int:
        """Samples from now until :meth:`reached` ``duration`` (at least 1; a large number
        when ``duration`` is 0, open-ended)."""
        if duration <= 0.0:
            return 1 << 30
        plant = self.plant
        n0, hold, h = plant.n, self.hold, plant.h
        end = duration - 1e-9 * self.control_period
        m = max(1, int((end / h - n0) / hold))
        while m > 1 and (n0 + (m - 1) * hold) * h >= end:
            m -= 1
        while (n0 + m * hold) * h < end:
            m += 1
        return m

    def reached(self, duration: float) -> bool:
        """True when ``duration`` > 0 and the current sample is at or past it."""
        return duration > 0.0 and self.plant.t >= duration - 1e-9 * self.control_period


class HostedLaw:
    """A controller plugin run inside the plant's loop (the ``controller`` parameter): what
    ros2_control's controller manager does, read, update, write in one process.

    ``command(t, x)`` gives ``(delta_f, delta_c)`` for the sample at ``t``, clamped as
    :meth:`fohssv_sim.control.Controller.command` clamps; it raises
    :class:`~fohssv_sim.control.NonFiniteCommand` for a non-finite output. A law that says
    it is affine (``Controller.affine()``, e.g. eq. 31) is evaluated as a scalar expression
    of its gains, a fraction of a microsecond, and :attr:`law` is then the
    :class:`~fohssv_sim.models.AffineLaw` the plant runs inside the compiled kernel for a
    burst of samples (:meth:`SampledPlant.advance_burst`); any other plugin (fractional PID,
    your own) through its ``command`` per sample, exactly as the controller node would call
    it. ``affine`` tells which.
    """

    def __init__(self, controller: Controller) -> None:
        self.controller = controller
        self.name = controller.name or type(controller).__name__
        law = AffineLaw.from_controller(controller)
        self.affine = law is not None
        #: the law as the compiled kernels run it (None unless affine)
        self.law: AffineLaw | None = law
        self.command = per_sample_command(controller)

    def reset(self) -> None:
        """Clear the controller's memory (the plant was reset)."""
        self.controller.reset()

    def describe(self) -> str:
        how = ('affine, inside the compiled kernel' if self.affine
               else 'its command() per sample')
        return f'{self.controller.describe()} hosted in the loop ({how})'


def time_text(t: float) -> str:
    """Simulated time for a log line: ``0.3``, not ``0.30000000000000004`` (rounded to 1e-12 s,
    far below any step; ``1.0`` stays ``1.0``)."""
    return repr(round(t, 12))


