"""Real time: the pacing the spin loop asks for, the watchdog, stale commands, the command lag
stop.

A room of :class:`fohssv_sim.ros.plant_node.PlantNode`: a mixin whose methods run on the node
(its attributes are set in ``PlantNode.__init__``).
"""

from __future__ import annotations

import time
from time import monotonic

from ..loop import time_text
from ..pacing import cpu_seconds
from .codes import EXIT_COMMAND_LAG, EXIT_NOT_REAL_TIME
from .commands import LAG_WALL

#: Realtime mode: wall-clock period of the watchdog check (s).
WATCHDOG_CHECK = 0.01

#: Realtime: a run that missed more than this share of its deadlines does not keep real time:
#: warned during the run (after :data:`SLOW_AFTER` paced samples, then at most every
#: :data:`SLOW_WARN_EVERY` s of wall time) and said in the run's last line.
SLOW_MISS_RATE = 0.01
SLOW_AFTER = 1000
SLOW_WARN_EVERY = 10.0


class RealTime:
    """The plant node in real time (the module docstring)."""

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
        wd = self.options.watchdog_timeout
        if wd > 0.0 and not self._watchdog_warned and self._last_command_wall is not None:
            silent = time.monotonic() - self._last_command_wall
            if silent > wd:
                self._watchdog_warned = True
                df, dc = self.sim.command
                self.get_logger().warning(
                    f'watchdog: no command for {silent:.3f} s (watchdog_timeout={wd:g} s) at '
                    f't={self.sim.t:.6f} s; holding delta_f={df!r} rad, delta_c={dc!r} rad')

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
        lag, o = self._lag, self.options
        gap = self._lag_gap
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
        lag = self._lag
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
