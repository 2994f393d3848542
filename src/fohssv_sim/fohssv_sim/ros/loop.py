"""The plant as the ROS node drives it, without ROS: sampling, command checks and pacing.

Pure (no rclpy), so the node's callbacks only call into this module. :class:`SampledPlant`
steps a :class:`~fohssv_sim.models.Plant` ``hold`` integration steps per published sample with
the command held (zero-order hold), exactly as :func:`fohssv_sim.simulate.simulate` does with
the same ``control_period``: both take the command computed from the sample at t_n and apply it
over [t_n, t_n + control_period). :func:`check_command` decides whether a command message is
usable. :class:`Pacer` schedules real-time samples against the wall clock and counts deadline
misses. :class:`Profile` accumulates per-sample costs when the node's ``profile`` option is on.
:class:`HostedLaw` runs a controller plugin inside the loop (the plant's ``controller``
parameter) and :class:`CommandLag` measures how late an external controller's commands are.

The node calls these on every sample (10 kHz at the default control period): the good path of
each is a few attribute reads and float comparisons, with no allocation beyond what the model
step itself needs; the slow paths (a rejected command, a log line) build their text only then.
"""

from __future__ import annotations

import gzip
import math
import os
import time
import zlib
from collections.abc import MutableSequence, Sequence
from dataclasses import dataclass
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

__all__ = ['CommandRejected', 'SampledPlant', 'check_command', 'answered_time', 'Pacer',
           'BurstWait',
           'HostedLaw', 'CommandLag', 'cpu_seconds', 'time_text']


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

    def restart(self, now: float) -> None:
        """The schedule starts over at ``now`` (the next sample is due then), as after a
        ``/reset``; the counts go on: they are the whole run's, as the summary's rates."""
        self.start = now - self.produced * self.period

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



@dataclass
class BurstWait:
    """How long a hosted real-time plant lets due samples wait before it wakes and computes
    them in one burst (:meth:`wait`, wall seconds, a whole number of periods).

    On this kind of virtual machine a wake-up costs 20-40 us of CPU, several samples' worth of
    work, so the fewer the better; but the first sample of a burst is published ``wait`` plus
    the wake-up's own overshoot after it was due, and more than ``tolerance`` is a deadline
    miss. The wait starts at its longest, ``longest_share`` of the tolerance less one period
    (4 periods at the defaults: bursts of 5 samples, 0.6 ms of the 1 ms tolerance left for the
    overshoot and the burst's own work; at ``real_time_factor`` 2, 9 periods of 50 us).
    A *near miss* is a wake-up whose first sample was more than ``near_miss`` of
    the tolerance late while a shorter wait would have kept it under (a slow wake-up; not a
    stall longer than the tolerance, which no wait saves). The wait follows them in windows of
    ``window`` seconds of wall time: more than ``allowed`` near misses in a window shorten it
    by one period (down to no wait, one sample per wake-up), none lengthen it by one, back up
    to the longest. Sporadic slow wake-ups cost a sample or two each; only a machine that is
    slow to wake the plant again and again pays for shorter bursts. Pure: the plant calls
    :meth:`observe` at each wake-up.
    """

    period: float
    tolerance: float
    longest_share: float = 0.5
    near_miss: float = 0.85
    window: float = 0.5
    allowed: int = 2
    longest: int = 0
    periods: int = 0
    wake_ups: int = 0
    near_misses: int = 0
    _in_window: int = 0
    _window_end: float = 0.0

    def __post_init__(self) -> None:
        self.longest = max(0, int(self.longest_share * self.tolerance / self.period + 1e-9) - 1)
        self.periods = self.longest

    def wait(self) -> float:
        """Seconds the first due sample waits before the wake-up."""
        return self.periods * self.period

    def observe(self, lateness: float, now: float) -> None:
        """At a wake-up: the first due sample is ``lateness`` s past its due time."""
        self.wake_ups += 1
        limit = self.near_miss * self.tolerance
        if lateness > limit and lateness - self.periods * self.period < limit:
            self.near_misses += 1
            self._in_window += 1
        if now >= self._window_end:
            if self._window_end:        # not the first wake-up: a whole window has passed
                if self._in_window > self.allowed:
                    self.periods = max(0, self.periods - 1)
                elif not self._in_window:
                    self.periods = min(self.longest, self.periods + 1)
            self._in_window = 0
            self._window_end = now + self.window


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


@dataclass
class CommandLag:
    """How late an external controller's commands are, in control periods (realtime mode).

    A command's lag is ``(now - answered) / period``: how many control periods the sample it
    answers lies before the plant's current sample when it arrives (0: it answered the
    newest sample). :meth:`add` returns True when the lag has *stayed* above ``limit``: every
    command that arrived over the last ``limit`` control periods of simulated time lagged by
    more than ``limit``. One late burst (a stall of the machine followed by catching up) that
    ends within that span does not stop a run. A few float operations per command.
    """

    limit: float
    period: float
    count: int = 0
    total: float = 0.0
    worst: float = 0.0
    last: float = 0.0
    over: int = 0                       # commands that lagged by more than the limit
    over_since: float | None = None     # sim time of the first of the current run above it
    over_least: float = 0.0             # the smallest lag of that run

    def add(self, now: float, answered: float) -> bool:
        lag = (now - answered) / self.period
        self.count += 1
        self.total += lag
        self.last = lag
        if lag > self.worst:
            self.worst = lag
        if lag <= self.limit:
            self.over_since = None
            return False
        self.over += 1
        if self.over_since is None:
            self.over_since = now
            self.over_least = lag
            return False
        if lag < self.over_least:
            self.over_least = lag
        return now - self.over_since >= self.limit * self.period * (1.0 - 1e-9)

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else 0.0

    def lagging(self) -> bool:
        """True when the newest commands lag by more than the limit, or some lagged by more
        than it or by 1 ms of simulated time or more (eq. 31 loses the delay-free vehicle at
        about 3 ms): a loss of the vehicle may then be the lag's doing."""
        return (self.over_since is not None or self.worst > self.limit
                or self.worst * self.period >= 1e-3)

    def summary(self) -> dict[str, float]:
        return {'command_lag_mean': self.mean, 'command_lag_worst': self.worst,
                'command_lag_last': self.last, 'commands_over_lag_limit': self.over,
                'max_command_lag_periods': self.limit}


def time_text(t: float) -> str:
    """Simulated time for a log line: ``0.3``, not ``0.30000000000000004`` (rounded to 1e-12 s,
    far below any step; ``1.0`` stays ``1.0``)."""
    return repr(round(t, 12))


def cpu_seconds() -> float:
    """CPU time of this process (user + system, all threads), for cost per sample figures."""
    return time.process_time()




#: Kernel preemption models (``/sys/kernel/debug/sched/preempt`` names, Linux 6.x) under which
#: a woken SCHED_FIFO thread takes its CPU from a task running in the kernel at once (``lazy``
#: defers the preemption of normal tasks only).
PREEMPTIBLE = ('full', 'lazy', 'rt')


def _config_lines(config: str) -> list[str]:
    """The lines of a kernel config, gzipped (``.gz``, as /proc/config.gz) or plain (as
    /boot/config-RELEASE); none where it cannot be read."""
    try:
        if config.endswith('.gz'):
            with gzip.open(config, 'rt', encoding='ascii', errors='replace') as f:
                return f.read().splitlines()
        with open(config, encoding='ascii', errors='replace') as f:
            return f.read().splitlines()
    except (OSError, EOFError, zlib.error):
        return []


def kernel_preemption(config: str = '/proc/config.gz', cmdline: str = '/proc/cmdline',
                      current: str = '/sys/kernel/debug/sched/preempt',
                      boot_config: str | None = None, version: str | None = None
                      ) -> tuple[str | None, int | None]:
    """(the running kernel's preemption model, its timer tick in Hz), each None where Linux
    does not say: the model from ``current`` (the bracketed one of ``none voluntary (full)
    lazy``, debugfs, root's), else a ``preempt=`` boot parameter in ``cmdline`` (a kernel
    built with PREEMPT_DYNAMIC), else the build's ``CONFIG_PREEMPT_*`` in ``config``
    (gzipped, as /proc/config.gz; ``rt``, ``full``, ``lazy``, ``voluntary`` or ``none``);
    the tick from its ``CONFIG_HZ``; where there is no ``config``, ``boot_config``
    (``/boot/config-RELEASE`` by default, as Debian and Ubuntu ship it); ``version``
    (``uname -v``) says PREEMPT_RT and PREEMPT_DYNAMIC where no config does. Under ``none``
    or ``voluntary`` a SCHED_FIFO thread waits for whatever kernel path another task runs on
    its CPU to reach a preemption point (docs/ros.md, *Modes*)."""
    uname = os.uname()
    lines = _config_lines(config) or _config_lines(
        boot_config if boot_config is not None else f'/boot/config-{uname.release}')
    options: dict[str, str] = {}
    for line in lines:
        if line.startswith('CONFIG_PREEMPT') or line.startswith('CONFIG_HZ='):
            key, _, value = line.strip().partition('=')
            options[key] = value
    words = (uname.version if version is None else version).split()
    if 'PREEMPT_RT' in words:
        options.setdefault('CONFIG_PREEMPT_RT', 'y')
    if 'PREEMPT_DYNAMIC' in words:
        options.setdefault('CONFIG_PREEMPT_DYNAMIC', 'y')
    hz = options.get('CONFIG_HZ')
    tick = int(hz) if hz is not None and hz.isdigit() else None
    try:
        with open(current, encoding='ascii') as f:
            text = f.read()
        if '(' in text:
            return text.split('(', 1)[1].split(')', 1)[0], tick
    except OSError:
        pass
    try:
        with open(cmdline, encoding='ascii', errors='replace') as f:
            for word in f.read().split():
                if word.startswith('preempt=') and options.get('CONFIG_PREEMPT_DYNAMIC') == 'y':
                    return word.split('=', 1)[1], tick
    except OSError:
        pass
    for key, model in (('CONFIG_PREEMPT_RT', 'rt'), ('CONFIG_PREEMPT', 'full'),
                       ('CONFIG_PREEMPT_LAZY', 'lazy'), ('CONFIG_PREEMPT_VOLUNTARY', 'voluntary'),
                       ('CONFIG_PREEMPT_NONE', 'none')):
        if options.get(key) == 'y':
            return model, tick
    return None, tick
