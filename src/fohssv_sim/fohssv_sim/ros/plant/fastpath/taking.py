"""Lockstep, the commands taken in compiled code (rcl's wait and take, then the compiled sample)
and what the node does after the compiled sample.

A room of :class:`fohssv_sim.ros.plant_node.PlantNode`: a mixin whose methods run on the node,
as it finishes each sample on the lockstep per-sample path (the node's messages, model and
counters).
"""

from __future__ import annotations

from time import monotonic
from typing import Any

from ...nodekit import STOP, tighten_timer_slack
from . import sample as fastpath

#: Lockstep, commands taken in compiled code (:meth:`PlantNode.spin_taking`): the longest
#: wait for a command (s) before the executor's turn, and the executor's turn at least this
#: often while commands come (timers, services, parameters; one ``spin_once`` each, about
#: 18 us of CPU here); at most an eighth of ``command_timeout`` (whose check is a timer),
#: at least _TAKE_WAIT_MIN.
_TAKE_WAIT = 0.005
_TAKE_WAIT_MIN = 0.001


class CompiledTaking:
    """The plant node taking its commands in compiled code (the module docstring): a mixin,
    as it finishes each sample on the node's per-sample path."""

    _taking = False    # the commands are taken in compiled code (take_commands)

    def _build_compiled(self) -> fastpath.CompiledSample | None:
        """The compiled sample of the node's held period (:attr:`_quick`), bound to its
        messages, publishers, limits, fault injection and in-plant ring; None (one line says
        why) where it cannot be built."""
        built = fastpath.CompiledSample.build(
            self._quick, self._state_out, self._command_in, self.state_pub.handle.pointer,
            (self._force_out, self.force_pub.handle.pointer),
            (self._clock_out, self.clock_pub.handle.pointer),
            sink=None if self._fault is None else self._fault.sink)
        if isinstance(built, str):
            self.get_logger().info(f'lockstep: the interpreted sample path ({built})')
            return None
        built.limit(self.options.max_fin_deflection, self.options.max_cavitator_deflection)
        rec = self.record
        if rec is not None:     # its records too, as _send_state & co. put them
            built.record_into(rec.ring, rec.index(self.state_pub.topic_name),
                              rec.command_index, rec.index(self.force_pub.topic_name),
                              rec.index(self.clock_pub.topic_name))
        return built

    def take_commands(self) -> bool:
        """Lockstep with the compiled sample: take the commands in compiled code
        (:meth:`.sample.CompiledSample.take_from`) and spin with :meth:`spin_taking`; False
        (one line says why, unless the compiled sample is off or its publish call is
        wrapped: the executor's callback then) when not."""
        compiled = self._compiled
        if compiled is None or self._send_state is not self._armable_send:
            return False
        why = compiled.take_from(self.context.handle.pointer, self.command_sub.handle.pointer,
                                 0.0)
        if why is not None:
            self.get_logger().info(f'lockstep: commands taken by the executor ({why})')
            return False
        self._taking = True
        return True

    def spin_taking(self, executor: Any) -> None:
        """Lockstep, commands taken in compiled code (:meth:`take_commands`): until the run
        has finished, a signal came or the context shut down, wait for the next command and
        take it with rcl, the compiled sample taking the awaited one (its state published
        before any Python runs); the node's Python then finishes the sample
        (:meth:`_compiled_took`) or, for a command the compiled sample left, runs the
        interpreted checks on its bytes (:meth:`_lockstep_interpreted`, as the
        subscription's callback does after the compiled sample). The executor gets its turn (one
        ``spin_once``: timers, services, parameters) at least every :data:`_TAKE_WAIT` s
        (an eighth of ``command_timeout`` if less) and after every wait that long that
        brought nothing; before the run, the executor waits (at most :data:`_TAKE_WAIT` s)
        and the commands are taken after it without waiting. The subscription's
        new-message callback (the event executor's) is unset first and again after each
        turn."""
        compiled = self._compiled
        received, took = compiled.received, self._compiled_took
        left = self._lockstep_interpreted    # the compiled sample looked at it already
        stop, finished, spin_once = STOP, self.finished, executor.spin_once
        not_taken, timed_out = fastpath.NOT_TAKEN, fastpath.TIMED_OUT
        rcl_error, woken = fastpath.RCL_ERROR, fastpath.WOKEN
        tighten_timer_slack()         # a spin_once with no wait: 18 us of CPU, not 75 us
        compiled.detach_listener()
        running_was = None
        next_service = wait = 0.0
        while stop.received is None and not finished.done():
            running = self.running
            if running is not running_was:
                wait = self._take_wait()
                compiled.set_timeout(wait if running else 0.0)
                running_was = running
            if not running:
                compiled.disarm()
                if not self.context.ok():
                    return
                spin_once(timeout_sec=_TAKE_WAIT)
                compiled.detach_listener()
            code = compiled.take()
            if code == not_taken:
                left(received())
            elif code == timed_out:
                next_service = 0.0
            elif code == woken:
                pass
            elif code == rcl_error:
                raise RuntimeError(f'rcl could not wait for or take a command (returned '
                                   f'{compiled.take_ret}: {compiled.take_error()})')
            else:
                took(received(), code)
            if running:
                now = monotonic()
                if now >= next_service:
                    if not self.context.ok():
                        return
                    spin_once(timeout_sec=0.0)
                    compiled.detach_listener()
                    if wait != (wait := self._take_wait()):   # command_timeout changed
                        compiled.set_timeout(wait)
                    next_service = now + wait

    def _take_wait(self) -> float:
        """:meth:`spin_taking`'s longest wait for a command and its executor cadence (s)."""
        return max(_TAKE_WAIT_MIN, min(_TAKE_WAIT, self.options.command_timeout / 8))

    def _compiled_took(self, raw: bytes, code: int) -> None:
        """Lockstep: the compiled sample took the awaited command ``raw`` and returned
        ``code``: the period's steps when its state and planing force went out (and its
        clock, as armed; the rest of the sample follows, as :meth:`_quick_sample` does after
        its publish), a refused state or planing force publish (retried as the interpreted
        path retries it), or a failed period (settled and reported as
        :meth:`_on_command_lockstep` reports it)."""
        begin = monotonic()
        quick = self._quick
        compiled = self._compiled
        if code <= fastpath.FAILED:   # the period failed: finish() raises as run() does
            t, df, dc = self._command_in.read(raw)
            self.sim.command = (df, dc)
            try:
                quick.finish(fastpath.FAILED - code, df, dc)
            except FloatingPointError as exc:
                self.sim.failed_period(exc)
                self._took(raw, t)
                self._diverged(exc)
            return
        # the entry checked the command and wrote the sample (and, but for a refused state,
        # published it): what finish() would keep, without its checks
        t, df, dc = self._command_in.unpack(raw)
        self.sim.command = (df, dc)
        quick.published()
        if code == fastpath.PUBLISH_REFUSED:   # retried through _send_state (recorded)
            failed = RuntimeError(f'rcl_publish_serialized_message returned '
                                  f'{compiled.rcl_ret}: {compiled.take_error()}')
            self._sample_sent(raw, t, begin, failed, self._state_out.payload())
            return
        if self.record is not None and compiled.put < compiled.records:
            self._put_rest(compiled.put, compiled.records, raw)
        self._sample_sent(raw, t, begin, None, None, code)

    def _put_rest(self, put: int, records: int, raw: bytes) -> None:
        """With ``record``: the records of the compiled sample's ``records`` (the state, the
        command, the planing force, the clock, in that order) after the ``put`` it put, which
        did not fit into the ring, put the interpreted way (which waits for room in
        lockstep)."""
        rec = self.record
        for i in range(put, records):
            if i == 0:
                rec.put_sent(self.state_pub.topic_name, self._state_out.payload())
            elif i == 1:
                rec.command(raw)
            elif i == 2:
                rec.put_sent(self.force_pub.topic_name, self._force_out.payload())
            else:
                rec.put_sent(self.clock_pub.topic_name, self._clock_out.last())
