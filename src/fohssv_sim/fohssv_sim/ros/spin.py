"""How the fohssv nodes spin: one executor choice and one loop, shared by every node.

``rclpy.experimental.EventsExecutor`` is the default (1 kHz publishing and a lockstep round
trip hold with it on a 2-core machine, where the default executor falls behind). Its blocking
``spin()`` is not used: in rclpy 9.1.2 (Kilted) it keeps a core busy and ignores SIGINT.
:func:`spin_until` instead calls ``spin_once`` with a timeout, which does neither; for the
real-time plant it also publishes each sample at its due time, waiting in ``spin_once`` in
between (see :class:`Paced`).
``FOHSSV_EXECUTOR=single`` selects rclpy's ``SingleThreadedExecutor`` instead.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from time import monotonic as _monotonic
from typing import Protocol

import rclpy
from rclpy.executors import Executor
from rclpy.task import Future

__all__ = ['Paced', 'make_executor', 'spin_until', 'final_log', 'StopSignal', 'STOP',
           'PluginHung']

#: Seconds between two looks at ``rclpy.ok()`` in :func:`spin_until`.
_OK_EVERY = 0.005


class StopSignal:
    """SIGINT and SIGTERM as a request that :func:`spin_until` honours between callbacks.

    rclpy's own handling (``SignalHandlerOptions.ALL``) chains to Python's SIGINT handler, which
    raises KeyboardInterrupt in whatever Python code runs at that moment: often a subscription
    callback in the middle of a lockstep sample. The EventsExecutor then logs ``[FATAL]
    Exception in 'subscriptions' callback`` with the stack before re-raising (issue 12,
    defect 12: about half the interrupted lockstep runs); rclpy also shuts the context down
    from its signal thread, so a callback still running may fail to publish. A node that
    calls ``rclpy.init(..., signal_handler_options=SignalHandlerOptions.NO)`` and
    :meth:`install` instead only records the signal: the loop stops after the callback in
    progress, and the node shuts down in order. Further signals raise nothing (a test
    harness or a terminal often signals twice; raising then would break the orderly end);
    they are counted, and a wait after the loop ends at the next one (the plant's linger).
    Every wait outside the loop is bounded.
    """

    def __init__(self) -> None:
        self.received: int | None = None
        self.count = 0
        #: a hook the plant sets while it hosts a law: the reason when a call of that law is
        #: stuck (has not returned for its timeout), else None. A signal then raises
        #: :class:`PluginHung` in that call, as a stuck call would never reach the loop.
        self.stuck: Callable[[], str | None] | None = None

    def install(self) -> StopSignal:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)
        return self

    def exiting(self) -> None:
        """The node is shut down and the process only exits: further SIGINT/SIGTERM are
        ignored. (Python's finalization resets a Python handler to the default action, so a
        signal sent to a node that has just ended by itself, e.g. a recorder at run_end,
        used to kill it with -SIGINT instead of exit 0. SIGKILL still ends it.)"""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)

    def _handle(self, signum: int, frame: object) -> None:
        self.count += 1
        if self.received is None:
            self.received = signum
        stuck = self.stuck() if self.stuck is not None else None
        if stuck is not None:
            raise PluginHung(stuck)


class PluginHung(BaseException):
    """Raised by a SIGINT/SIGTERM inside a hosted law's call that has not returned for its
    timeout (:attr:`StopSignal.stuck`); a BaseException, so the law's own ``except
    Exception`` does not swallow it. The message names the plugin and the sample's time."""


#: The process's stop request (set by SIGINT/SIGTERM once :meth:`StopSignal.install` ran).
STOP = StopSignal()


def make_executor(context: rclpy.context.Context | None = None) -> Executor:
    """The executor the nodes use (see the module docstring), on ``context`` (default
    rclpy's default context)."""
    if os.environ.get('FOHSSV_EXECUTOR', 'events') != 'single':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # pragma: no cover - rclpy without it
            pass
        else:
            return EventsExecutor(context=context)
    return rclpy.executors.SingleThreadedExecutor(context=context)


class Paced(Protocol):
    """A node with work due at wall-clock times (the real-time plant): :func:`spin_until`
    waits for it by spinning the executor, so callbacks run in the meantime."""

    def pacing_wait(self) -> float | None:
        """Seconds until the next due work (<= 0: due now), or None when nothing is paced."""

    def publish_due(self) -> None:
        """Do the work that is due."""


class _ThrottledOk:
    """``rclpy.ok()`` asked at most every :data:`_OK_EVERY` s (about 1 us a call, with a lock:
    in a lockstep loop one call per sample, after the sample's publish, where every
    microsecond before the next command counts; docs/ros.md). The context is shut down only
    after the loop by these nodes (:class:`StopSignal` ends it first), so a shutdown from
    elsewhere is seen within that time."""

    def __init__(self) -> None:
        self._next = 0.0

    def __call__(self) -> bool:
        now = _monotonic()
        if now < self._next:
            return True
        if not rclpy.ok():
            return False
        self._next = now + _OK_EVERY
        return True


def spin_until(executor: Executor, future: Future | None = None, poll: float = 0.1,
               paced: Paced | None = None) -> None:
    """Process callbacks until ``future`` is done (or forever when ``None``), the context
    shuts down, or :data:`STOP` records a signal (then it returns after the callback in
    progress). Without :data:`STOP` installed, rclpy's signal handling raises
    KeyboardInterrupt / ExternalShutdownException on SIGINT.

    With ``paced``, the loop also runs ``paced.publish_due()`` whenever
    ``paced.pacing_wait()`` says it is due, and otherwise waits in ``spin_once`` for at most
    that long: one sample at its due time, the executor spun between samples (when behind
    schedule, once with a zero timeout after each sample, so commands are never starved).
    """
    spin_once = executor.spin_once
    stop = STOP
    ok = _ThrottledOk()
    if paced is None:
        while stop.received is None and ok() and (future is None or not future.done()):
            spin_once(timeout_sec=poll)
        return
    wait_for = paced.pacing_wait
    publish_due = paced.publish_due
    while stop.received is None and ok() and (future is None or not future.done()):
        wait = wait_for()
        if wait is None:
            spin_once(timeout_sec=poll)
        elif wait > 0.0:
            spin_once(timeout_sec=wait if wait < poll else poll)
        else:
            publish_due()
            wait = wait_for()
            if wait is not None and wait <= 0.0:
                spin_once(timeout_sec=0.0)


class PausedCollector:
    """Context manager: Python's cyclic garbage collector off while a real-time run is paced.

    A full collection pauses the process for milliseconds, a missed deadline at a 100 us
    sample period (measured: disabling it cut the plant's deadline misses at 1e-4 s from
    0.7 % to 0.04 %). Objects alive at entry are frozen out of future collections; reference
    cycles made during the run (the paced path makes none) are collected at exit.
    """

    def __enter__(self) -> PausedCollector:
        import gc

        self._was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()
        return self

    def __exit__(self, *exc: object) -> None:
        import gc

        gc.unfreeze()
        if self._was_enabled:
            gc.enable()


def final_log(name: str, text: str) -> None:
    """Log ``text`` after SIGINT shut the context down (the node's logger would fail to
    publish to /rosout then): to stderr, in the console format."""
    import time

    print(f'[INFO] [{time.time():.9f}] [{name}]: {text}', file=sys.stderr, flush=True)
