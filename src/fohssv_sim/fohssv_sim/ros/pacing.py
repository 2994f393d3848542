"""Real time without ROS: the wall-clock schedule of the plant's samples (:class:`Pacer`:
deadlines, misses, slips), the wait of a hosted law's bursts (:class:`BurstWait`) and how
late an external controller's commands are (:class:`CommandLag`). Pure (no rclpy): the
plant's real-time room (:mod:`.plant.realtime`) calls these on every sample.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

__all__ = ['Pacer', 'BurstWait', 'CommandLag', 'cpu_seconds']


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


def cpu_seconds() -> float:
    """CPU time of this process (user + system, all threads), for cost per sample figures."""
    return time.process_time()
