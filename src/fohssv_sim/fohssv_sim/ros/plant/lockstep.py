"""Lockstep: the awaited command, its timeout and graces, overruns, pacing to slow subscribers, the
short path of the good command.

Rooms of :class:`fohssv_sim.ros.plant_node.PlantNode`: two objects that own their state,
:class:`CommandWait` (the timeout of the awaited command, its graces, the overrun of a period)
and :class:`ReaderPacing` (``pace_to_subscribers``); :class:`Lockstep`, a mixin over the
node's attributes, runs the per-sample path: the awaited command taken, the model advanced,
the sample published (the round trip, where each attribute hop counts).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from time import monotonic
from typing import Any

from rclpy.duration import Duration

from ..loop import time_text
from .codes import EXIT_PUBLISH_FAILED, EXIT_TIMEOUT, PublishFailed
from .fastpath import sample as fastpath

#: Lockstep with pace_to_subscribers: the wait for the acknowledgements (s) after which the
#: loop goes on while that cannot lose a sample ...
_ACK_TIMEOUT = 1.0

#: ... and the longest wait once going on could overrun the writer's queue (a stalled reader).
_STALL_TIMEOUT = 10.0

#: Lockstep: how long past ``command_timeout`` the plant waits for the awaited state to be
#: acknowledged by the subscribers of ``state`` (s). A controller whose reader the plant has
#: matched may not have matched the plant's writer yet (discovery is two one-sided halves;
#: under load the second came seconds later): its timeout counts from the delivery.
_DELIVERY_GRACE = 30.0

#: Lockstep: after the plant itself was not running (a timer check more than half of
#: ``command_timeout`` late: a stopped process, a stalled host), how long past
#: ``command_timeout`` the controller's command may take (s). A command published meanwhile
#: may have been dropped at the stopped process's shared-memory port (Fast DDS gives up on a
#: port whose listener does not answer within 1 s) and comes again only at the writer's next
#: heartbeat, every 3 s in Fast DDS: a CI run under load had a plant stopped for 1.5 s blame
#: its controller about 50 ms after it resumed.
_RESUME_GRACE = 5.0


class CommandWait:
    """Lockstep: the wait for the awaited command (the module docstring): its timeout
    (``command_timeout``, exit 3 naming the side that stalled), the graces for a state not
    yet delivered and for a plant that did not run, and the overrun of a control period.

    Given the node's logger, the ``state`` publisher (whose acknowledgements tell a stalled
    controller from an undelivered state), ``peers()`` (the start gate's: the command
    publishers a timeout's line names) and ``fail(code, message)``. The node sets
    :attr:`published` when the awaited state went out (per sample, inline) and
    :attr:`checked` after a wait of its own (a publish retried, the readers waited for); its
    timer calls :meth:`check`, a period longer than the timeout :meth:`overrun`."""

    def __init__(self, log: Any, state_pub: Any, peers: Callable[[], tuple[int, int]],
                 fail: Callable[[int, str], None]) -> None:
        self._log, self._state_pub, self._peers, self._fail = log, state_pub, peers, fail
        self.published = 0.0                      # when the awaited state went out
        self.checked = 0.0                        # when the timer last checked
        self._undelivered: float | None = None    # t of a state not yet acknowledged
        self._resumed = -math.inf                 # when the plant last came late to a check
        self._slow: tuple[int, float] | None = None   # (samples, CPU s) of a slow period

    def check(self, awaiting: float | None, timeout: float, timer_period_ns: int,
              last_t: float | None, received: int) -> None:
        """The timer's look (every ``timer_period_ns``) at the command awaited for the state
        at ``awaiting`` (None: none awaited) with ``timeout`` s; ``last_t`` and ``received``
        (the last command's t, the commands received) word a stalled controller's line."""
        now = monotonic()
        late, self.checked = now - self.checked, now
        waited = now - self.published
        # (at least two periods of this timer, whose period command_timeout set at the start:
        # lowered during the run, it would otherwise take every check for a stopped plant)
        if late > max(timeout / 2, 2e-9 * timer_period_ns):
            # this check (every command_timeout / 4 at most) came that late: the plant itself
            # was not running (a stalled host, a stopped process); a command that came
            # meanwhile may be waiting behind this timer, or lost on the way and sent again
            # at its writer's next heartbeat: the controller gets _RESUME_GRACE more (also
            # when the wait is not over yet: a 3 s stop with the default 5 s timeout)
            self._resumed = now
            if awaiting is not None and waited > timeout:
                self._log.info(
                    f'lockstep: the plant did not run for {late:.3f} s (a stopped process or '
                    f'a stalled host) while awaiting the command for '
                    f't={time_text(awaiting)} s: '
                    f'its controller gets command_timeout + {_RESUME_GRACE:g} s from now (a '
                    'command lost meanwhile comes again at its writer\'s next heartbeat)')
            return
        if awaiting is None or waited <= timeout:
            return
        if now - self._resumed <= timeout + _RESUME_GRACE:
            return
        if not self._state_pub.wait_for_all_acked(Duration(seconds=0)):
            # not the controller's delay: a subscriber has not got the state yet
            if waited <= timeout + _DELIVERY_GRACE:
                if self._undelivered != awaiting:
                    self._undelivered = awaiting
                    self._log.info(
                        f'the state for t={time_text(awaiting)} s is not acknowledged by all '
                        f'{self._state_pub.get_subscription_count()} subscriber(s) of '
                        f'{self._state_pub.topic_name} after {waited:.1f} s (discovery not '
                        'finished on their side?): command_timeout counts from its delivery')
                return
            self._fail(EXIT_TIMEOUT,
                       f'lockstep timeout: the state for t={time_text(awaiting)} s was not '
                       f'acknowledged by the subscribers of {self._state_pub.topic_name} within '
                       f'{waited:.1f} s (command_timeout={timeout:g} s + '
                       f'{_DELIVERY_GRACE:g} s for delivery; command has {self._peers()[1]} '
                       'publisher(s))')
            return
        if self._undelivered == awaiting:
            # delivered since the last check: the controller has its full timeout from now
            self._undelivered = None
            self.published = now
            return
        if last_t is not None:
            last = f'the last command answered t={time_text(last_t)} s'
        elif received:
            last = (f'{received} command(s) received, none answering a sample: empty or '
                    'without a finite t')
        else:
            last = 'no command received at all'
        self._fail(EXIT_TIMEOUT,
                   f'lockstep timeout: the controller stalled: no command answering '
                   f't={time_text(awaiting)} s within command_timeout='
                   f'{timeout:g} s ({last}; command has '
                   f'{self._peers()[1]} publisher(s))')

    def overrun(self, took: float, timeout: float, samples: int, hold: int, t: float) -> bool:
        """A control period took ``took`` s of wall time, more than ``timeout``:
        the plant's own work, or a wait outside it (a publish that DDS blocked: Fast DDS
        spends up to 1 s checking the shared-memory port of a stopped subscriber's process; a
        host that did not run the plant). The first such period is logged and its end marks
        the process's CPU time; when the very next period is too long as well, the plant is
        overrunning (exit 3) if it used more CPU than ``timeout`` since the mark
        (one period's work and the wait for its command). Nothing is added to a period that
        is not too long."""
        cpu = time.process_time()
        mark, self._slow = self._slow, (samples, cpu)
        if mark is not None and mark[0] == samples - 1 and cpu - mark[1] > timeout:
            self._fail(EXIT_TIMEOUT,
                       f'lockstep timeout: the plant is overrunning: one control period '
                       f'({hold} steps) took {took:.3f} s > command_timeout='
                       f'{timeout:g} s at t={time_text(t)} s, using '
                       f'{cpu - mark[1]:.3f} s of '
                       'CPU with the wait for its command (the one before took too long '
                       'as well)')
            return True
        self._log.warning(
            f'one control period ({hold} steps) took {took:.3f} s > command_timeout='
            f'{timeout:g} s of wall time at t={time_text(t)} s: not an overrun unless the '
            'next one takes as long in CPU time (a publish blocked by DDS, e.g. for a stopped '
            'subscriber, or a stalled host)')
        return False


class ReaderPacing:
    """``pace_to_subscribers`` (lockstep, and a hosted law in lockstep): every so many
    samples the run waits for the subscribers of its samples to acknowledge them.

    Given the publishers whose readers pace the run and the node's logger; offers
    :meth:`keep_up`. Owns, per topic, the sample count when all its readers last
    acknowledged everything (-1: a reader left behind as stalled)."""

    def __init__(self, pubs: tuple[Any, ...], log: Any) -> None:
        self._pubs, self._log = pubs, log
        self._all_acked: dict[str, int] = {}

    def keep_up(self, n: int, every: int, t: float) -> None:
        """At sample ``n`` (time ``t``), pacing every ``every`` samples: wait until every
        subscriber of the samples has acknowledged them, so a subscriber slower than the loop
        (a recorder, whose keep-all readers stop acknowledging when their queue is full) paces
        the run instead of losing what falls out of the writer's queue. After _ACK_TIMEOUT the
        loop goes on only while that cannot lose a sample: the samples since the subscriber
        last acknowledged everything, plus those until the next wait, still fit the writer's
        queue. Otherwise it waits on, up to _STALL_TIMEOUT; a subscriber silent that long
        (stalled) is left behind with a warning, and from then on waited for only
        _ACK_TIMEOUT until it catches up."""
        for pub in self._pubs:
            topic = pub.topic_name
            if pub.wait_for_all_acked(Duration(seconds=_ACK_TIMEOUT)):
                self._all_acked[topic] = n
                continue
            behind = n - self._all_acked.get(topic, 0)
            if behind + every <= pub.qos_profile.depth or self._all_acked.get(topic) == -1:
                continue       # nothing can be lost before the next wait (or stalled before)
            if pub.wait_for_all_acked(Duration(seconds=_STALL_TIMEOUT - _ACK_TIMEOUT)):
                self._all_acked[topic] = n
                continue
            self._all_acked[topic] = -1
            self._log.warning(
                f'{topic}: a subscriber has not acknowledged up to {behind} samples for '
                f'{_STALL_TIMEOUT:g} s at t={time_text(t)} s (the queue holds '
                f'{pub.qos_profile.depth}); continuing (it may lose samples)')


class Lockstep:
    """The plant node in lockstep (the module docstring): a mixin, as the per-sample path
    reads and writes the node's messages, model and counters directly."""

    _awaiting: float | None = None    # t of the state awaiting its command

    def _await_command(self) -> None:
        self._awaiting = t = self.sim.t
        self.command_wait.published = time.monotonic()
        compiled = self._compiled
        if compiled is not None:
            if self.running and self._send_state is self._armable_send:
                # (not armed when the model's kernel call is not bound yet: the first sample
                # and the first after a reset take the interpreted path, which binds it)
                clock = 0
                if self._clock_on and (self.sim.samples + 1) % self._clock_every == 0:
                    clock = ((fastpath.CLOCK_PUBLISH if self._clock_wanted else 0)
                             | (fastpath.CLOCK_PUT if self.record is not None else 0))
                compiled.arm(t, clock)
            else:
                compiled.disarm()

    def _check_lockstep_timeout(self) -> None:
        if not self.running:
            return
        self._refresh_matched()
        self.command_wait.check(self._awaiting, self.options.command_timeout,
                                self._timer.timer_period_ns, self._last_command_t,
                                self.received)

    def _lockstep_command(self, data: Any, t: float | None) -> None:
        if self._awaiting is None or t != self._awaiting:
            self.ignored += 1
            self.get_logger().warning(
                f'ignored a command for t={t!r} s while waiting for t={self._awaiting!r} s '
                f'({self.ignored} ignored so far)', throttle_duration_sec=1.0)
            return
        self._take(data)
        self._awaiting = None
        self._stepped(monotonic())

    def _stepped(self, begin: float) -> None:
        """Lockstep: the awaited command was taken at ``begin`` (monotonic s): advance,
        publish, and await the next one."""
        if self._advance():
            self._next(begin)

    def _next(self, begin: float) -> None:
        """Lockstep: the period whose command was taken at ``begin`` is published: check
        for an overrun, pace to slow subscribers when asked, await the next command."""
        took = monotonic() - begin
        timeout = self.options.command_timeout
        sim = self.sim
        if took > timeout and self.command_wait.overrun(took, timeout, sim.samples, sim.hold,
                                                        sim.t):
            return
        every = self.options.pace_to_subscribers
        if every and sim.samples % every == 0:
            self.reader_pacing.keep_up(sim.samples, every, sim.t)
            # that wait (up to _STALL_TIMEOUT, blocking the timer) was the plant's own: the
            # next lockstep check must not take the plant for stopped and grant the resume
            # grace (which hid a stopped controller's undelivered state for 5 s)
            self.command_wait.checked = monotonic()
        self._await_command()

    def _on_command_lockstep(self, raw: bytes) -> None:
        """Lockstep, external controller (the subscription's callback): the good command,
        the one answering the awaited sample with deflections within their limits, is taken
        with the fewest steps before the next state goes out (the round trip waits for it):
        comparisons inline instead of :meth:`_on_command`'s, :meth:`_lockstep_command`'s and
        :meth:`_take`'s calls (the watchdog's flag, real time only, is not looked at). Any
        other command goes through :meth:`_on_command` (its checks, logs and counts). Armed
        for the awaited sample (by :meth:`_await_command`; it disarms itself when it takes
        the command, :meth:`_took` when the interpreted path does, and is not called once the
        run is over), the compiled sample (fastpath/sample.py) takes the good command first
        and publishes its state before any of this runs."""
        compiled = self._compiled
        if compiled is not None and self.running:
            code = compiled.call(raw, len(raw))
            if code != fastpath.NOT_TAKEN:
                self._compiled_took(raw, code)
                return
        self._lockstep_interpreted(raw)

    def _lockstep_interpreted(self, raw: bytes) -> None:
        """:meth:`_on_command_lockstep` for a command the compiled sample did not take (or
        where there is none): the short path's inline checks, else :meth:`_on_command`."""
        data = self._command_in.read(raw)
        if len(data) == 3 and self.running:
            t, df, dc = data
            o = self.options
            if (t == self._awaiting and abs(df) <= o.max_fin_deflection
                    and abs(dc) <= o.max_cavitator_deflection):
                begin = monotonic()
                self.sim.command = (df, dc)
                quick = self._quick
                if quick is not None:
                    try:
                        if quick.run(df, dc):
                            self._quick_sample(raw, t, begin)
                            return
                    except FloatingPointError as exc:
                        self.sim.failed_period(exc)
                        self._took(raw, t)
                        self._diverged(exc)
                        return
                self._took(raw, t)
                self._stepped(begin)
                return
        self._on_command(raw)

    def _took(self, raw: bytes, t: float, compiled: bool = False) -> None:
        """Lockstep: the awaited command ``raw`` (answering ``t``) was taken (``compiled``: by
        the compiled sample, which disarmed itself and put its record into the in-plant
        ring). (The watchdog's time of the last command is not kept: real time only.)"""
        self.received += 1
        if not compiled:
            if self._compiled is not None:
                self._compiled.disarm()
            if self.record is not None:
                self.record.command(raw)
        self._last_command_t = t
        self._awaiting = None

    def _quick_sample(self, raw: bytes, t: float, begin: float) -> None:
        """Lockstep: :class:`~fohssv_sim.models.HeldPeriod` ran the period of the command
        answering ``t`` and wrote its sample into the state message. The state goes out
        first, the round trip waits for nothing else (work before a publish costs the loop
        at least as long, work after it is free up to about 7 us: docs/ros.md); then the
        model's bookkeeping and what :meth:`_stepped` does after the state (the same
        messages, counts and checks)."""
        payload = self._state_out.payload()
        try:
            self._send_state(payload)
            failed = None
        except Exception as exc:  # noqa: BLE001 - RCLError is not exported by rclpy
            failed = exc
        self._sample_sent(raw, t, begin, failed, payload)

    def _sample_sent(self, raw: bytes, t: float, begin: float, failed: Exception | None,
                     payload: bytes | None, compiled: int | None = None) -> None:
        """Lockstep, the short path: the sample's state went out (or its publish failed with
        ``failed``: ``payload`` is retried); the model's bookkeeping and the rest. With
        ``compiled`` (the compiled sample's code): its planing force and clock went out
        already, its records are in the ring (``FORCE_REFUSED``: the planing force is
        retried here, then the clock)."""
        if compiled is None:
            force = self._force_data
            force[1] = self._quick.settle()
            force[0] = self._state_data[0]
        else:                  # the compiled sample wrote the same [t, Fp] into the message
            self._quick.settle()
        self.sim.took(self.sim.command)
        self._took(raw, t, compiled is not None)
        self.sent += 1
        try:
            if failed is not None:
                self._retry_publish(self._send_state, self.state_pub.topic_name, payload,
                                    failed, state=True)
            if compiled is None:
                self._send_rest(self.sim.samples)
            elif compiled == fastpath.FORCE_REFUSED:
                c = self._compiled
                self._retry_publish(self._send_force, self.force_pub.topic_name,
                                    self._force_out.payload(), RuntimeError(
                                        f'rcl_publish_serialized_message returned '
                                        f'{c.force_ret}: {c.take_error()}'))
                self._send_after_force(self.sim.samples)
            else:
                self._compiled_rest(self.sim.samples)
        except PublishFailed as exc:
            self._fail(EXIT_PUBLISH_FAILED, str(exc))
            return
        if self._published():
            self._next(begin)
