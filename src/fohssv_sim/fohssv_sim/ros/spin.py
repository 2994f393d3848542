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
import struct
import sys
from collections.abc import Callable
from time import monotonic as _monotonic
from typing import Protocol

import rclpy
from rclpy.executors import Executor
from rclpy.task import Future

__all__ = ['Paced', 'make_executor', 'spin_until', 'tighten_timer_slack', 'final_log',
           'StopSignal', 'STOP', 'pin_threads', 'hold_cpu_latency', 'cpu_latency_limit',
           'CPU_LATENCY_DEVICE', 'NO_LATENCY_LIMIT', 'PluginHung']

_PR_SET_TIMERSLACK = 29
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


def make_executor() -> Executor:
    """The executor the nodes use (see the module docstring)."""
    if os.environ.get('FOHSSV_EXECUTOR', 'events') != 'single':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # pragma: no cover - rclpy without it
            pass
        else:
            return EventsExecutor()
    return rclpy.executors.SingleThreadedExecutor()


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


def tighten_timer_slack() -> bool:
    """Ask Linux for 1 ns timer slack on the calling thread (``prctl(PR_SET_TIMERSLACK)``).

    The default slack of 50 us makes every timed wait overshoot by 50-75 us (measured: a
    ``spin_once`` timeout or ``time.sleep`` of 100 us returns 75 us late; 20-25 us with 1 ns
    slack), which a real-time plant pacing 100 us samples cannot afford. Returns False where
    unavailable (not Linux); the node then just runs with the default slack.
    """
    if not sys.platform.startswith('linux'):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


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


def set_realtime_priority(priority: int) -> str | None:
    """Run the calling thread under SCHED_FIFO at ``priority`` (1-99); 0 leaves the normal
    scheduler. Returns None on success (or for 0), else why it was not possible (no
    permission: needs CAP_SYS_NICE or an rtprio limit; not Linux)."""
    if priority <= 0:
        return None
    if not hasattr(os, 'sched_setscheduler'):
        return 'SCHED_FIFO is not available on this platform'
    # children (the in-plant writer is started before, but any later one) do not inherit it
    policy = os.SCHED_FIFO | getattr(os, 'SCHED_RESET_ON_FORK', 0)
    try:
        os.sched_setscheduler(0, policy, os.sched_param(priority))
    except OSError as exc:
        return f'SCHED_FIFO priority {priority} not permitted ({exc.strerror})'
    return None


def pin_threads(cpus: tuple[int, ...]) -> int:
    """Pin every thread of this process to ``cpus`` (``sched_setaffinity`` of each thread in
    ``/proc/self/task``: rclpy's and DDS's threads already exist when a node reads its
    parameters; threads started later inherit it from the thread that starts them, and a
    thread started during a pass by one not yet pinned is caught by the next pass). Without
    ``/proc``, only the calling thread. Returns the number of threads pinned; ``()`` pins
    nothing.

    Raises:
        OSError: the kernel refused (e.g. a CPU taken away by a cpuset since the check).
    """
    if not cpus:
        return 0
    pinned: set[int] = set()
    while True:
        try:
            new = {int(t) for t in os.listdir('/proc/self/task')} - pinned
        except OSError:                      # no /proc
            os.sched_setaffinity(0, cpus)
            return 1
        if not new:
            return len(pinned)
        for tid in sorted(new):
            try:
                os.sched_setaffinity(tid, cpus)
            except ProcessLookupError:       # a thread that ended meanwhile
                pass
            pinned.add(tid)


#: Linux's PM QoS device for the system-wide CPU wake-up latency limit (microseconds).
CPU_LATENCY_DEVICE = '/dev/cpu_dma_latency'

#: What the device reads while no process holds a request (Linux's PM QoS default, 2000 s).
NO_LATENCY_LIMIT = 2_000_000_000

#: The open requests of this process: the kernel holds a request while its file is open and
#: drops it when the file closes, which the process's end does however it ends (SIGKILL too).
_LATENCY_REQUESTS: list[int] = []


def hold_cpu_latency(us: int, device: str = CPU_LATENCY_DEVICE) -> None:
    """Ask Linux to keep every CPU's wake-up latency at most ``us`` microseconds until this
    process ends (Linux PM QoS, as ``cyclictest`` and real-time Linux guides do): the cpuidle
    governor then picks no idle state that takes longer to leave; with 0 an idle CPU polls
    (on a VM: the vCPU does not halt, so the host need not wake it for the next message).
    The limit is system-wide, the least of all the requests held.

    Raises:
        OSError: the device is missing (not Linux, a container without it) or not writable
            (it is root's: mode 0600).
    """
    fd = os.open(device, os.O_WRONLY | os.O_CLOEXEC)
    try:
        os.write(fd, struct.pack('=i', us))
    except OSError:
        os.close(fd)
        raise
    _LATENCY_REQUESTS.append(fd)


def cpu_latency_limit(device: str = CPU_LATENCY_DEVICE) -> int | None:
    """The kernel's current system-wide CPU wake-up latency limit in microseconds (the least
    of the requests held; :data:`NO_LATENCY_LIMIT` when none is), or None where it cannot be
    read."""
    try:
        fd = os.open(device, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        raw = os.read(fd, 4)
    except OSError:
        return None
    finally:
        os.close(fd)
    return struct.unpack('=i', raw)[0] if len(raw) == 4 else None


def final_log(name: str, text: str) -> None:
    """Log ``text`` after SIGINT shut the context down (the node's logger would fail to
    publish to /rosout then): to stderr, in the console format."""
    import time

    print(f'[INFO] [{time.time():.9f}] [{name}]: {text}', file=sys.stderr, flush=True)
