"""Real time: the pacing the spin loop asks for, the watchdog, stale commands, the command lag
stop.

Rooms of :class:`fohssv_sim.ros.plant_node.PlantNode`: two objects that own their state,
:class:`Watchdog` (the silence of an external controller) and :class:`LagStop` (the lag of
its commands and when it ends the run); :class:`RealTime`, a mixin over the node's
attributes, paces the samples and words the warnings and stops (it reads the pacer, the
model's time and the plant's cost, which other rooms own).
"""

from __future__ import annotations

import time
from time import monotonic
from typing import Any

from ..loop import time_text
from ..pacing import CommandLag, cpu_seconds
from .codes import EXIT_COMMAND_LAG, EXIT_NOT_REAL_TIME

#: Realtime mode: wall-clock period of the watchdog check (s).
WATCHDOG_CHECK = 0.01

#: Realtime: a run that missed more than this share of its deadlines does not keep real time:
#: warned during the run (after :data:`SLOW_AFTER` paced samples, then at most every
#: :data:`SLOW_WARN_EVERY` s of wall time) and said in the run's last line.
SLOW_MISS_RATE = 0.01
SLOW_AFTER = 1000
SLOW_WARN_EVERY = 10.0

#: Realtime: a command lag over ``max_command_lag`` for that many periods that then falls
#: (the controller catching up after a stall of the machine) may take this wall time (s) to
#: fall under the limit before the run stops (exit 6); one that does not fall stops it.
LAG_WALL = 1.0


class Watchdog:
    """Real time, an external controller: a warning once per outage when no command came for
    ``watchdog_timeout`` (a limit the node passes at each check: it may change at run time).

    Given the node's logger. The command intake writes :attr:`last` and looks at
    :attr:`warned` for each command (inline: the per-command path), calling :meth:`back`
    when an outage ends; the node's real-time timer calls :meth:`check`; a reset
    :meth:`rearms <rearm>` it."""

    def __init__(self, log: Any) -> None:
        self._log = log
        self.last: float | None = None   # wall time (monotonic s) of the last command, or start
        self.warned = False              # the current outage has been warned of

    def back(self) -> None:
        """Commands come again after a warned outage."""
        self.warned = False
        self._log.info('watchdog: commands are arriving again')

    def rearm(self) -> None:
        self.warned = False

    def check(self, timeout: float, t: float, command: tuple[float, float]) -> None:
        """Warn (once per outage) when no command came for ``timeout`` s (0: off); ``t`` and
        ``command`` are the sample time and the command held, for the line."""
        if timeout > 0.0 and not self.warned and self.last is not None:
            silent = time.monotonic() - self.last
            if silent > timeout:
                self.warned = True
                df, dc = command
                self._log.warning(
                    f'watchdog: no command for {silent:.3f} s (watchdog_timeout={timeout:g} s) '
                    f'at t={t:.6f} s; holding delta_f={df!r} rad, delta_c={dc!r} rad')


class LagStop:
    """Real time, an external controller: the lag of its commands (:attr:`lag`, a
    :class:`~fohssv_sim.ros.pacing.CommandLag` of ``max_command_lag`` and the control period)
    and whether it has stayed over the limit long enough to end the run (exit 6).

    The command intake calls :meth:`over` for each command in time (after its own checks)
    and raises :attr:`worst` to the lag of each command it holds; the node changes
    :attr:`lag`'s ``limit`` when ``max_command_lag`` changes, and a reset forgets the span
    over it."""

    def __init__(self, limit: float, period: float) -> None:
        self.lag = CommandLag(limit, period)
        self._add = self.lag.add          # (bound once: called per command)
        self.worst = 0.0                  # the largest lag of a command held (simulated s)
        self.gap = 0.0                    # the controller's silence before the lag span (s)
        self._wall: float | None = None   # wall time the span over the limit began
        self._from = (0.0, 0.0)           # (t, lag in control periods) then

    def over(self, now: float, t: float, wall: float, prev: float | None) -> bool:
        """The command answering ``t`` arrived at sample time ``now`` and wall time ``wall``
        (the one before at ``prev``): True when its lag has been over the limit for
        ``max_command_lag`` periods and, given the wall time :data:`LAG_WALL` to fall after
        a stall, has not fallen: the run stops. (The intake keeps :attr:`worst` itself, for
        the commands it holds.)"""
        over = self._add(now, t)
        # the longest silence since the lag went over the limit, the one before its first
        # command included (a stall that began it; the backlog answered after a stall
        # comes in quick succession)
        if self.lag.over_since is None:
            self.gap = 0.0
        elif prev is not None:
            self.gap = max(self.gap, wall - prev)
        if not over:                 # under the limit, or not for max_command_lag periods
            self._wall = None
            return False
        if self._wall is None:
            self._wall, self._from = wall, (now, self.lag.last)
            return False
        return self._lost(now, wall)

    def _lost(self, now: float, wall: float) -> bool:
        """The lag has been over the limit for ``max_command_lag`` periods: True when over
        as many periods again it did not fall (the loop cannot keep up), or it is still over
        after :data:`LAG_WALL` s of wall time; a lag falling after a stall gets that time."""
        lags, (t0, lag0) = self.lag, self._from
        return (wall - self._wall >= LAG_WALL
                or (now - t0 >= lags.limit * lags.period and lags.last >= lag0))

    def rearm(self) -> None:
        """A reset: the span over the limit starts again."""
        self.lag.over_since = None


class RealTime:
    """The plant node in real time (the module docstring)."""

    _slow_warn_at = 0.0      # when "not keeping real time" may be warned again (monotonic s)

    def pacing_wait(self) -> float | None:
        """Seconds until the next real-time sample is due (<= 0: due now); None when no
        sample is paced (lockstep, not started, or ended). Called by the spin loop. Lockstep
        with a hosted law: always due while running (the loop runs as fast as it can)."""
        if self.hosted is not None:
            return 0.0 if self.running else None
        pacer = self.pacer
        if pacer is None or not self.running:
            return None
        return pacer.start + pacer.produced * pacer.period - monotonic()

    def publish_due(self) -> None:
        """Advance and publish the next real-time sample if it is due (the spin loop calls
        this when :meth:`pacing_wait` is <= 0). Lockstep with a hosted law: a chunk of
        samples, at most ``_FREE_RUN_CHUNK`` of wall time, then the executor's turn."""
        if not self.running:
            return
        if self.hosted is not None:
            self._run_chunk()
        elif self.pacer.due(monotonic()):
            self._advance()

    def _check_watchdog(self) -> None:
        if not self.running:
            return
        self._check_real_time()
        if not self.running:      # max_deadline_miss_rate ended the run
            return
        self._refresh_matched()
        self.watchdog.check(self.options.watchdog_timeout, self.sim.t, self.sim.command)

    def _check_real_time(self) -> None:
        """Warn while the run misses more than :data:`SLOW_MISS_RATE` of its deadlines (the
        first time after :data:`SLOW_AFTER` paced samples, then at most every
        :data:`SLOW_WARN_EVERY` s), naming the plant's cost per sample; stop it (exit 11)
        beyond ``max_deadline_miss_rate`` when that is set."""
        p = self.pacer
        if p is None or p.produced < SLOW_AFTER:
            return
        rate, limit = p.misses / p.produced, self.options.max_deadline_miss_rate
        if limit and rate > limit:
            self._fail(EXIT_NOT_REAL_TIME, f'not real time: {100 * rate:.2f} % of deadlines '
                       f'missed, over max_deadline_miss_rate={limit:g}, at t={self.sim.t:.6g} '
                       f's ({self._cost_text()}); stopping. ' + self._remedies())
            return
        if rate <= SLOW_MISS_RATE:
            return
        now = monotonic()
        if now < self._slow_warn_at:
            return
        self._slow_warn_at = now + SLOW_WARN_EVERY
        self.get_logger().warning(
            f'not keeping real time: {100 * rate:.2f} % of deadlines missed '
            f'so far, {p.slips} slips, at t={self.sim.t:.6g} s ({self._cost_text()}); '
            + self._remedies())

    def _real_time_verdict(self, s: dict) -> str | None:
        """The run's last word on real time from its summary ``s``: None when it kept it."""
        rate = s.get('deadline_miss_rate', 0.0)
        if rate <= SLOW_MISS_RATE:
            return None
        return (f"not real time: RTF {s['achieved_real_time_factor']:.2f} (real_time_factor="
                f"{s['real_time_factor']:g} asked), {100 * rate:.2f} % of deadlines missed, "
                f"plant CPU {s['cpu_per_sample_us']:.0f} us per sample"
                + (f", the hosted law {s['law_us_per_sample']:.0f} us of it"
                   if s.get('law_us_per_sample') else ''))

    def _cost_text(self) -> str:
        samples = self.sim.samples
        if not samples or not self.running:
            return 'plant CPU per sample unknown'
        cpu = (cpu_seconds() - self._cpu_start) / samples
        period = self.options.control_period / self.options.real_time_factor
        text = (f'plant CPU {cpu * 1e6:.0f} us per sample = {100 * cpu / period:.0f} % of the '
                f'{period * 1e6:.0f} us period')
        if self.law_time:             # a hosted law called per sample: its share
            law = self.law_time / (self._samples_before + samples)
            text += (f', of which the hosted law {law * 1e6:.0f} us ({100 * law / cpu:.0f} % of '
                     'the plant)')
        if self.pacer is not None and self.pacer.produced:
            p = self.pacer
            text += f', deadline misses {p.misses}/{p.produced}'
        return text

    def _remedies(self) -> str:
        longer = min(1.0, 10.0 * self.options.control_period)
        return ('remedies: mode:=lockstep (deterministic, at the speed of the loop), a longer '
                f'control_period (e.g. control_period:={longer:g}), or the law hosted in the '
                'plant, controller:=NAME (e.g. controller:=state_feedback: no DDS in the loop)')

    def _lag_stop(self) -> None:
        lag, o = self.lag_stop.lag, self.options
        gap = self.lag_stop.gap
        stall = (f'it began with a stall: no command for {gap:.3f} s of wall time, and the '
                 'lag has not recovered since; ' if gap > 10 * self.pacer.period else '')
        self._fail(EXIT_COMMAND_LAG,
                   f'command lag: {stall}the external controller\'s commands lagged by more '
                   f'than max_command_lag={o.max_command_lag:g} control periods for as long, not '
                   f'falling back within {LAG_WALL:g} s of wall time (at '
                   f'least {lag.over_least:.0f} periods since t={lag.over_since:.6g} s, now '
                   f'{lag.last:.0f}; mean {lag.mean:.1f}, worst {lag.worst:.0f} over the run) '
                   f'at t={time_text(self.sim.t)} s: the plant and its controller cannot keep '
                   'up with '
                   f'control_period={o.control_period:g} s in real time here '
                   f'({self._cost_text()}); stopping before late commands lose the vehicle. '
                   + self._remedies())

    def _lag_note(self) -> str:
        """For a failure in realtime with an external controller: the command lag, and when
        it was beyond the limit, that the run was probably lost to it."""
        lag = self.lag_stop.lag
        if self.hosted is not None or self.pacer is None or not lag.count:
            return ''
        text = (f'; command lag: now {lag.last:.1f}, mean {lag.mean:.1f}, worst '
                f'{lag.worst:.1f} control periods (worst {lag.worst * lag.period * 1e3:.3g} ms '
                f'of simulated time; max_command_lag={self.options.max_command_lag:g})')
        if lag.lagging():
            text += (': the commands were late, and the loop may have been lost to their lag '
                     f'rather than to the model ({self._cost_text()}); ' + self._remedies())
        return text

    def _stale(self, t: float, now: float) -> None:
        """Reject a real-time command answering a time after the current sample or older
        than ``max_command_age``."""
        self.stale += 1
        if t > now:
            why = (f"it answers t={time_text(t)} s, after the plant's current sample "
                   f"t={time_text(now)} s")
        else:
            why = (f'it answers t={time_text(t)} s, {now - t:g} s of simulated time before the '
                   'current '
                   f'sample: older than max_command_age={self.options.max_command_age:g} s')
        self._reject(f'stale command: {why}')
