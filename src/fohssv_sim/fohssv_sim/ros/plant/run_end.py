"""The run's end: the summary, run_end, the flush and the linger.

Rooms of :class:`fohssv_sim.ros.plant_node.PlantNode`: :class:`RunEnd`, a mixin whose methods
run on the node, as the summary and ``run_end`` read every room's figures (its own state is
declared in its class body); :class:`Departure`, an object given the node's ``run_end`` and
output writers: the flush and the linger after the run.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable
from typing import Any

from rclpy.duration import Duration
from std_msgs.msg import String

from ...contract import run_end_text
from ..loop import time_text
from ..nodekit import STOP, final_log
from ..pacing import cpu_seconds
from .codes import EXIT_LAW_HUNG, EXIT_OK

#: After the run (and ``end_linger``): the longest wait for the readers of ``run_end`` (the
#: recorders, which leave once they took it) to leave (s).
_RUN_END_WAIT = 10.0


class RunEnd:
    """The plant node's end of a run (the module docstring): a mixin, as the summary reads
    every room's figures; its own state is declared here."""

    exit_code = EXIT_OK
    _announced = False                    # run_end published
    _cut: tuple[float, int] | None = None  # (t, steps) where a refused publish ended a burst

    #: the summary line not yet logged: (how it is logged, its lead, the figures); held back
    #: with ``record`` until the bag is closed (:meth:`say_summary`)
    _unsaid: tuple[Callable[[str], None], str, dict[str, Any]] | None = None

    def summary(self) -> dict[str, Any]:
        """Figures of the run so far (also logged as one JSON line at the end)."""
        wall = time.monotonic() - self._run_wall_start if self.running else 0.0
        cpu = cpu_seconds() - self._cpu_start if self.running else 0.0
        # t, samples and steps count from the last /reset; the rates divide the whole run's
        # samples (samples_total) by the whole run's wall and CPU time
        total = self._samples_before + self.sim.samples
        t, n = self._made()
        steps = self._steps_before + n
        s: dict[str, Any] = {
            'mode': self.options.mode, 'model': self.model.model, 'solver': self.model.solver,
            'step': self.model.step, 'control_period': self.options.control_period,
            't': t, 'samples': self.sim.samples,
            'steps': n, 'resets': self.resets, 'samples_total': total,
            'steps_total': steps, 'published_states': self.sent,
            'wall_time': wall, 'cpu_time': cpu,
            'cpu_per_sample_us': cpu / total * 1e6 if total else 0.0,
            'clock_samples': self._clock_every, 'view_samples': self._view_every,
            'views': self.views.published if self.views is not None else 0,
            'rejected_commands': self.rejected, 'ignored_commands': self.ignored,
            'controller': self.options.controller or 'external',
            'publish_retries': self.publish_retries,
            'cpu_affinity': list(self.options.cpu_affinity),
            'cpu_dma_latency': self.cpu_latency,
        }
        if self.hosted is not None:
            s.update(hosted_commands=self.commanded, commands_published=self.commands_sent,
                     law_failures=self.law_failures,
                     law_us_per_sample=self.law_time / total * 1e6 if total else 0.0)
        elif self._lockstep:       # samples the compiled sample took (fastpath/sample.py)
            s['compiled_samples'] = self._compiled.taken if self._compiled is not None else 0
            s['compiled_take'] = self._taking   # commands taken by rcl in compiled code
        if self.profile is not None:
            s['profile'] = self.profile.summary()
        if self.record is not None:
            s.update(self.record.summary())
        if self.pacer is not None:
            p = self.pacer
            s.update(real_time_factor=self.options.real_time_factor,
                     achieved_real_time_factor=(total * self.options.control_period / wall
                                                if wall > 0 else 0.0),
                     deadline_tolerance=p.tolerance,
                     deadline_misses=p.misses, samples_paced=p.produced,
                     deadline_miss_rate=p.misses / p.produced if p.produced else 0.0,
                     late_samples=p.late,
                     mean_lateness=p.lateness_sum / p.produced if p.produced else 0.0,
                     slips=p.slips, worst_lateness=p.worst_lateness,
                     max_command_lag=self.lag_stop.worst, stale_commands=self.stale,
                     cpu_share_of_period=(cpu / total / p.period if total else 0.0))
            if self.hosted is None:
                s.update(self.lag_stop.lag.summary())
            elif self.bursts is not None:   # hosted: wake-ups, and how often they backed off
                s.update(wake_ups=self.bursts.wake_ups, burst_backoffs=self.bursts.near_misses,
                         samples_per_wake_up=(p.produced / self.bursts.wake_ups
                                              if self.bursts.wake_ups else 0.0))
        elif wall > 0:
            s.update(samples_per_second=total / wall, steps_per_second=steps / wall)
        return s

    def _summarise(self, say: Callable[[str], None], lead: str = '') -> dict[str, Any]:
        """The run's figures at its end, logged through ``say`` as one line ``LEAD summary:
        JSON``: at once, or with ``record`` once the bag is closed (:func:`recorded`), as the
        recording's figures are final only then: a writer lagging behind the run (a batch
        job, on a loaded machine) may die after the run's end, a disk that fills while it
        drains the ring (its ``record_lost`` read 0 with exit 8 before)."""
        s = self.summary()
        self._unsaid = (say, lead, s)
        if self.record is None:
            self.say_summary()
        return s

    def say_summary(self) -> None:
        """Log the summary line :meth:`_summarise` held, the recording's figures as they are
        now (once)."""
        if self._unsaid is None:
            return
        say, lead, s = self._unsaid
        self._unsaid = None
        if self.record is not None:
            s.update(self.record.summary())
        say(f'{lead}summary: {json.dumps(s)}')

    def _made(self) -> tuple[float, int]:
        """(t, steps) of the run's last sample: the plant's, unless a refused publish ended
        the run inside a burst whose later samples the kernel had computed already."""
        return self._cut if self._cut is not None else (self.sim.t, self.sim.plant.n)

    def _end(self, code: int) -> None:
        if self.finished.done():
            return
        self.exit_code = code
        if self.hosted is not None:
            self.law_watch.end()
        self.flush_views()      # the summary counts a view's last messages too
        s = self._summarise(self.get_logger().info)
        verdict = self._real_time_verdict(s)
        if verdict is not None:
            self.get_logger().warning(verdict)
        self.running = False
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        self.finished.set_result(code)
        self.announce_end(f'exit code {code}', code)

    def flush_views(self) -> None:
        """Publish a view's last messages, if pending (before the summary and run_end)."""
        if self.views is not None and self.views.pending:
            with contextlib.suppress(Exception):   # the context may be going down (a signal)
                self.views.flush()

    def announce_end(self, reason: str, code: int) -> None:
        """Publish :data:`~fohssv_sim.contract.RUN_END` once: the messages sent on each
        sample and view topic (not ``/clock``: keep-last 1 by design, a slow reader keeps the
        newest) and the commands received while running (a recorder hears the same
        controllers), so that a recorder can wait for them and report any it lost."""
        if self._announced:
            return
        self._announced = True
        published = {self.state_pub.topic_name: self.sent,
                     self.force_pub.topic_name: self.sent - self.forces_lost,
                     self.command_topic: self.received if self.hosted is None
                     else self.commands_sent}
        if self.views is not None:
            self.flush_views()
            n = self.views.published
            for pub in self.views.publishers:
                published[pub.topic_name] = 2 * n if pub is self.views.marker_pub else n
        text = run_end_text('plant', reason, code, self._made()[0], published)
        if self.record is not None:
            self.record.end(text)
        try:
            self.end_pub.publish(String(data=text))
        except Exception as exc:  # noqa: BLE001 - the context is going down (a signal)
            final_log(self.get_name(), f'run_end not published: {exc}')

    def _finish(self, why: str) -> None:
        self.get_logger().info(f'stopping cleanly at t={time_text(self.sim.t)} s: {why}')
        self._end(EXIT_OK)

    def _fail(self, code: int, message: str) -> None:
        self.get_logger().error(message)
        self._end(code)


class Departure:
    """After the run: the readers get the time to take what was published before the plant's
    writers go away (a reader loses what it has not taken from a writer that leaves).

    Given the node (its context and graph), the ``run_end`` publisher and the writers of the
    run's output (the samples, the views, a hosted law's commands); offers :meth:`flush` and
    :meth:`linger`, which the plant's run calls in that order once the run has ended."""

    def __init__(self, node: Any, end_pub: Any, sample_pubs: tuple[Any, ...]) -> None:
        self._node, self._end_pub, self._sample_pubs = node, end_pub, sample_pubs

    def flush(self, signals: int, timeout: float = 2.0) -> None:
        """Wait until subscribers acknowledged what was published (reliable topics): at most
        ``timeout`` s in all, and not after a signal beyond ``signals``."""
        deadline = time.monotonic() + timeout
        # run_end first: a recorder busy with a backlog must receive it before this writer
        # goes away (seen under load: the bag complete, the run_end never heard, exit 7)
        for pub in (self._end_pub, *self._sample_pubs):
            left = deadline - time.monotonic()
            if left <= 0 or STOP.count != signals:
                return
            if pub.get_subscription_count() > 0:
                pub.wait_for_all_acked(Duration(seconds=left))

    def linger(self, executor: Any, signals: int, seconds: float) -> None:
        """Keep the publishers (and services) up for ``seconds`` (``end_linger``) after the run
        ended, or until nothing subscribes to the samples (or views) any more: a reader drops
        what it has not taken yet from a writer that goes away, so a subscriber lagging behind
        a fast run would lose its tail when the plant exits. Then, up to _RUN_END_WAIT s,
        while a reader of ``run_end`` is still there (a recorder leaves once it took it). A
        signal beyond the ``signals`` that ended the run (:func:`signals_that_ended`) ends
        it."""
        deadline = time.monotonic() + seconds
        samples, ok = self._sample_pubs, self._node.context.ok
        while (ok() and STOP.count == signals and time.monotonic() < deadline
               and any(p.get_subscription_count() > 0 for p in samples)):
            executor.spin_once(timeout_sec=0.05)
        # run_end too, as the player keeps its own: a recorder that has not taken it yet loses
        # it with this writer (seen under load: every sample in the bag, the run_end never
        # heard, exit 7); a recorder leaves once it has it. Bounded by _RUN_END_WAIT.
        end = self._end_pub
        deadline = time.monotonic() + _RUN_END_WAIT
        while (ok() and STOP.count == signals and time.monotonic() < deadline
               and (end.get_subscription_count() > 0
                    or self._node.count_subscribers(end.topic_name) > 0)):
            executor.spin_once(timeout_sec=0.05)


def signals_that_ended(node: Any) -> int:
    """After the plant's spin loop: the signals that ended the run (:data:`STOP`'s count),
    which the linger passes over so that a recorder still drains; any later one ends it. A
    signal the loop found with the run still going interrupted it (logged as
    such here); a hosted law's hung call ends the run on a signal (exit 10). A run that ended
    by itself (its duration, a failure) counts none, even a signal that came while its last
    sample went out (the loop looks between callbacks): counted, that signal, meant to end the
    linger, left the plant lingering for ``end_linger`` (a test's stop found it alive 10 s
    later)."""
    if STOP.received is not None and not node.finished.done():
        interrupted(node)
        return STOP.count
    return STOP.count if node.exit_code == EXIT_LAW_HUNG else 0


def interrupted(node: Any) -> None:
    node.flush_views()
    node._summarise(lambda text: final_log(node.get_name(), text),
                    'interrupted; stopping cleanly. ')
    # the announced end is the end: nothing is stepped or published after it (the linger
    # spins the executor, and a lockstep command arriving then would advance the run)
    node.running = False
    node.pacer = None
    node.announce_end('interrupted', node.exit_code)


def recorded(node: Any, code: int) -> int:
    """With ``record``: wait until the writer closed the bag, then log the summary; exit 8
    when it misses messages."""
    if node.record is None:
        return code
    if node._compiled is not None:    # the ring closes: the compiled sample puts no more
        node._compiled.disarm()
        node._compiled.record_into(None)
    code = node.record.finish(code)
    node.say_summary()
    return code


def on_interrupt(node: Any) -> int:
    if not node.finished.done():
        interrupted(node)
    code = recorded(node, node.exit_code)
    if node.record is not None:
        node.record.reap()
    return code
