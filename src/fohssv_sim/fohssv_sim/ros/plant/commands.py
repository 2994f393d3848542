"""An external controller's commands: received, checked, held or rejected.

A room of :class:`fohssv_sim.ros.plant_node.PlantNode`: a mixin whose methods run on the node,
as every command passes here on the per-sample path; its counters are declared in its class
body, the watchdog and lag stop it feeds are :mod:`.realtime`'s objects.
"""

from __future__ import annotations

from time import monotonic
from typing import Any

from ..loop import (
    CommandRejected,
    answered_time,
    check_command,
    time_text,
)

#: Rejected commands logged one by one; later ones are throttled to one line per second.
LOG_EACH = 20


class CommandIntake:
    """The plant node's intake of an external controller's commands (the module docstring):
    a mixin, as each command is checked on the per-sample path; its counters are declared
    here (read by the run's summary and ``run_end``)."""

    received = 0                          # commands received while running
    rejected = 0                          # of those, rejected (the last good one held)
    stale = 0                             # realtime: of the rejected, stale or future
    ignored = 0                           # lockstep: answering another sample than awaited
    _last_command_t: float | None = None  # t of the last command with a finite t

    def _on_command(self, raw: bytes) -> None:
        """A serialized ``command`` (the subscription is raw: see wire.py)."""
        if not self.running:
            return
        self.received += 1
        if self.record is not None:
            self.record.command(raw)
        data = self._command_in.read(raw)
        t = answered_time(data)
        if t is not None:
            self._last_command_t = t
        watchdog = self.watchdog
        prev = watchdog.last
        watchdog.last = wall = monotonic()
        if watchdog.warned:
            watchdog.back()
        if self._lockstep:
            self._lockstep_command(data, t)
            return
        if t is not None:
            now = self.sim.t
            lag = now - t
            if not (0.0 <= lag <= self.options.max_command_age):
                self._stale(t, now)
                return
            stop = self.lag_stop
            if stop.over(now, t, wall, prev):
                self._lag_stop()
                return
            if self._take(data) and lag > stop.worst:
                stop.worst = lag
        else:
            self._take(data)    # rejected: no finite t

    def _take(self, data: Any) -> bool:
        """Hold the command in ``data`` if it is valid; else log and keep the last good one."""
        o = self.options
        try:
            _, df, dc = check_command(data, o.max_fin_deflection, o.max_cavitator_deflection)
        except CommandRejected as exc:
            self._reject(str(exc))
            return False
        self.sim.command = (df, dc)
        return True

    def _reject(self, reason: str) -> None:
        """Count and log a rejected command (the first 20 one by one, then at most one line a
        second); the last good command stays held."""
        self.rejected += 1
        df, dc = self.sim.command
        self._log_rejected(f'rejected command at t={time_text(self.sim.t)} s: {reason}; keeping '
                           'the last '
                           f'good command delta_f={df!r}, delta_c={dc!r} rad ({self.rejected} '
                           'rejected)')
