"""An external controller's commands: received, checked, held or rejected.

A room of :class:`fohssv_sim.ros.plant_node.PlantNode`: a mixin whose methods run on the node
(its attributes are set in ``PlantNode.__init__``).
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

#: Realtime: a command lag over ``max_command_lag`` for that many periods that then falls
#: (the controller catching up after a stall of the machine) may take this wall time (s) to
#: fall under the limit before the run stops (exit 6); one that does not fall stops it.
LAG_WALL = 1.0


class CommandIntake:
    """The plant node's intake of an external controller's commands (the module docstring)."""

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
        prev = self._last_command_wall
        self._last_command_wall = wall = monotonic()
        if self._watchdog_warned:
            self._watchdog_warned = False
            self.get_logger().info('watchdog: commands are arriving again')
        if self._lockstep:
            self._lockstep_command(data, t)
            return
        if t is not None:
            now = self.sim.t
            lag = now - t
            if not (0.0 <= lag <= self.options.max_command_age):
                self._stale(t, now)
                return
            lags = self._lag
            over = lags.add(now, t)
            # the longest silence since the lag went over the limit, the one before its first
            # command included (a stall that began it; the backlog answered after a stall
            # comes in quick succession)
            silence = wall - prev if prev is not None else 0.0
            self._lag_gap = 0.0 if lags.over_since is None else max(self._lag_gap, silence)
            if over:                   # over the limit for max_command_lag periods
                if self._lag_wall is None:
                    self._lag_wall, self._lag_from = wall, (now, lags.last)
                elif self._lag_lost(now, wall):
                    self._lag_stop()
                    return
            else:
                self._lag_wall = None
            if self._take(data) and lag > self._max_lag:
                self._max_lag = lag
        else:
            self._take(data)    # rejected: no finite t

    def _lag_lost(self, now: float, wall: float) -> bool:
        """The lag has been over the limit for ``max_command_lag`` periods: True when over
        as many periods again it did not fall (the loop cannot keep up), or it is still over
        after :data:`LAG_WALL` s of wall time; a lag falling after a stall gets that time."""
        lags, (t0, lag0) = self._lag, self._lag_from
        return (wall - self._lag_wall >= LAG_WALL
                or (now - t0 >= lags.limit * lags.period and lags.last >= lag0))

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
