"""The host's side of a node's timing, in one place: CPU affinity, the CPU wake-up latency
request (PM QoS), SCHED_FIFO, timer slack, and what the kernel's preemption model lets a
real-time thread expect. Each is a plain function that says what it could not do instead of
failing: a node runs on whatever host it gets. The plant applies them from its parameters
(:mod:`.plant.host_tuning`), the controller node from its own, the benchmarks directly.
"""

from __future__ import annotations

import errno
import gzip
import os
import struct
import sys
import zlib
from typing import Any

__all__ = ['tighten_timer_slack', 'set_realtime_priority', 'pin_threads', 'pin_node',
           'hold_cpu_latency', 'hold_latency', 'cpu_latency_limit', 'CPU_LATENCY_DEVICE',
           'NO_LATENCY_LIMIT', 'PREEMPTIBLE', 'kernel_preemption']

_PR_SET_TIMERSLACK = 29


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


def pin_node(node: Any, cpus: tuple[int, ...]) -> bool:
    """Pin every thread of the node's process to ``cpus`` (its validated ``cpu_affinity``;
    ``()`` leaves the scheduler's choice) and say so in one line; when the kernel refuses, say
    why in one line and run unpinned. True when pinned."""
    if not cpus:
        return False
    text = ','.join(map(str, cpus))
    try:
        threads = pin_threads(cpus)
    except OSError as exc:
        node.get_logger().warning(f'cpu_affinity: CPU {text} refused by the kernel '
                                  f'({exc.strerror}); running unpinned')
        return False
    node.get_logger().info(f"cpu_affinity: the process's {threads} threads run on CPU {text}")
    return True


def hold_latency(node: Any, us: int, warn: bool = False) -> int | None:
    """Hold the node's validated ``cpu_dma_latency`` (``us`` microseconds; -1: no request)
    until the process ends (:func:`hold_cpu_latency`) and say so in one line; where
    the kernel's device cannot be written, say why in one line (a warning with ``warn``,
    else information: the run does not depend on it) and run on. Returns the limit held, or
    None."""
    if us < 0:
        return None
    try:
        hold_cpu_latency(us)
    except OSError as exc:
        why = (' (writing it needs root)' if exc.errno in (errno.EACCES, errno.EPERM) else '')
        line = (f'cpu_dma_latency: {us} us not requested: {CPU_LATENCY_DEVICE}: '
                f'{exc.strerror}{why}; idle CPUs may take longer to wake for a message; '
                'cpu_dma_latency:=-1 asks for nothing')
        (node.get_logger().warning if warn else node.get_logger().info)(line)
        return None
    limit = cpu_latency_limit()
    node.get_logger().info(
        f'cpu_dma_latency: CPU wake-up latency at most {us} us while this process runs'
        + ('' if limit is None else f' (system-wide limit now {limit} us)'))
    return us


#: Kernel preemption models (``/sys/kernel/debug/sched/preempt`` names, Linux 6.x) under which
#: a woken SCHED_FIFO thread takes its CPU from a task running in the kernel at once (``lazy``
#: defers the preemption of normal tasks only).
PREEMPTIBLE = ('full', 'lazy', 'rt')


def _config_lines(config: str) -> list[str]:
    """The lines of a kernel config, gzipped (``.gz``, as /proc/config.gz) or plain (as
    /boot/config-RELEASE); none where it cannot be read."""
    try:
        if config.endswith('.gz'):
            with gzip.open(config, 'rt', encoding='ascii', errors='replace') as f:
                return f.read().splitlines()
        with open(config, encoding='ascii', errors='replace') as f:
            return f.read().splitlines()
    except (OSError, EOFError, zlib.error):
        return []


def kernel_preemption(config: str = '/proc/config.gz', cmdline: str = '/proc/cmdline',
                      current: str = '/sys/kernel/debug/sched/preempt',
                      boot_config: str | None = None, version: str | None = None
                      ) -> tuple[str | None, int | None]:
    """(the running kernel's preemption model, its timer tick in Hz), each None where Linux
    does not say: the model from ``current`` (the bracketed one of ``none voluntary (full)
    lazy``, debugfs, root's), else a ``preempt=`` boot parameter in ``cmdline`` (a kernel
    built with PREEMPT_DYNAMIC), else the build's ``CONFIG_PREEMPT_*`` in ``config``
    (gzipped, as /proc/config.gz; ``rt``, ``full``, ``lazy``, ``voluntary`` or ``none``);
    the tick from its ``CONFIG_HZ``; where there is no ``config``, ``boot_config``
    (``/boot/config-RELEASE`` by default, as Debian and Ubuntu ship it); ``version``
    (``uname -v``) says PREEMPT_RT and PREEMPT_DYNAMIC where no config does. Under ``none``
    or ``voluntary`` a SCHED_FIFO thread waits for whatever kernel path another task runs on
    its CPU to reach a preemption point (docs/ros.md, *Modes*)."""
    uname = os.uname()
    lines = _config_lines(config) or _config_lines(
        boot_config if boot_config is not None else f'/boot/config-{uname.release}')
    options: dict[str, str] = {}
    for line in lines:
        if line.startswith('CONFIG_PREEMPT') or line.startswith('CONFIG_HZ='):
            key, _, value = line.strip().partition('=')
            options[key] = value
    words = (uname.version if version is None else version).split()
    if 'PREEMPT_RT' in words:
        options.setdefault('CONFIG_PREEMPT_RT', 'y')
    if 'PREEMPT_DYNAMIC' in words:
        options.setdefault('CONFIG_PREEMPT_DYNAMIC', 'y')
    hz = options.get('CONFIG_HZ')
    tick = int(hz) if hz is not None and hz.isdigit() else None
    try:
        with open(current, encoding='ascii') as f:
            text = f.read()
        if '(' in text:
            return text.split('(', 1)[1].split(')', 1)[0], tick
    except OSError:
        pass
    try:
        with open(cmdline, encoding='ascii', errors='replace') as f:
            for word in f.read().split():
                if word.startswith('preempt=') and options.get('CONFIG_PREEMPT_DYNAMIC') == 'y':
                    return word.split('=', 1)[1], tick
    except OSError:
        pass
    for key, model in (('CONFIG_PREEMPT_RT', 'rt'), ('CONFIG_PREEMPT', 'full'),
                       ('CONFIG_PREEMPT_LAZY', 'lazy'), ('CONFIG_PREEMPT_VOLUNTARY', 'voluntary'),
                       ('CONFIG_PREEMPT_NONE', 'none')):
        if options.get(key) == 'y':
            return model, tick
    return None, tick
