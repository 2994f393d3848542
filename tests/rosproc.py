"""Helpers for tests that start real ROS 2 processes over DDS (no mocks).

Every test gets its own ROS_DOMAIN_ID (so concurrent runs on one machine do not see each
other) and localhost-only discovery. Processes are the colcon-installed executables'
entry points, forked from this worker's server (:mod:`zygote`) or, with ``fork=False``,
started exactly as ``ros2 run <pkg> <exe>`` would resolve them.

The domains come from 1-200 unless ``FOHSSV_TEST_DOMAINS=LO-HI`` confines them (inclusive,
within 0-232, Fast DDS's limit), e.g. on a host where other ROS 2 users or another run hold
some domains: ``FOHSSV_TEST_DOMAINS=101-150 make test``. The range needs at least as many
domains as pytest-xdist workers; a wider one lets concurrent runs overlap less.
"""

from __future__ import annotations

import itertools
import os
import re
import signal
import subprocess
import sys
import time
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from ament_index_python.packages import get_package_prefix

import zygote

_counter = itertools.count()
#: The environment variable that confines the tests' ROS_DOMAIN_IDs, and its default.
DOMAINS_VAR, DOMAINS_DEFAULT = 'FOHSSV_TEST_DOMAINS', '1-200'
#: Fast DDS's largest domain id (its port arithmetic allows 232).
_MAX_DOMAIN = 232
#: Every process started by :func:`start`; conftest kills those still running after each test.
STARTED: list[subprocess.Popen] = []


def _worker() -> tuple[int, int]:
    """(index, count) of this pytest-xdist worker; (0, 1) without xdist."""
    name = os.environ.get('PYTEST_XDIST_WORKER', '')
    count = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1') or 1)
    return (int(name[2:]) if name.startswith('gw') else 0), max(count, 1)


def _run_seed() -> int:
    """Differs between concurrent test runs: the xdist run id (shared by a run's workers), or
    the pid of a run without xdist."""
    run_id = os.environ.get('PYTEST_XDIST_TESTRUNUID')
    return zlib.crc32(run_id.encode()) if run_id else os.getpid() * 7


def domain_range(text: str | None = None) -> tuple[int, int]:
    """(lo, hi), inclusive, of ``text`` (default: :data:`DOMAINS_VAR` from the environment,
    else :data:`DOMAINS_DEFAULT`), a range ``LO-HI`` of ROS_DOMAIN_IDs. Raises ValueError
    naming the variable, its value and what is allowed."""
    if text is None:
        text = os.environ.get(DOMAINS_VAR) or DOMAINS_DEFAULT
    found = re.fullmatch(r'\s*(\d+)\s*-\s*(\d+)\s*', text)
    lo, hi = (int(found.group(1)), int(found.group(2))) if found else (-1, -1)
    if not 0 <= lo <= hi <= _MAX_DOMAIN:
        raise ValueError(f'{DOMAINS_VAR}={text!r} is not a range LO-HI of ROS domain ids '
                         f'with 0 <= LO <= HI <= {_MAX_DOMAIN} (e.g. {DOMAINS_DEFAULT})')
    return lo, hi


def unique_domain_id() -> int:
    """A ROS_DOMAIN_ID in :func:`domain_range` that differs between tests and between
    concurrent runs.

    The parallel workers of one run (``make test`` uses pytest-xdist) never share a domain:
    worker k of n gets the domains lo + m with m = k (mod n), in turn, so consecutive tests
    of one worker differ too. Another run on the machine starts elsewhere in the cycle.
    """
    lo, hi = domain_range()
    k, n = _worker()
    span = ((hi - lo + 1) // n) * n     # a multiple of n keeps the residue k when it wraps
    if span == 0:
        raise ValueError(f'{DOMAINS_VAR}={lo}-{hi} holds {hi - lo + 1} domain(s), fewer than '
                         f'the {n} pytest-xdist workers: widen it or run fewer workers (-n)')
    base = (_run_seed() % (span // n)) * n
    return lo + (base + k + n * next(_counter)) % span


def ros_env(domain_id: int | None = None, **extra: str) -> dict[str, str]:
    """The current environment with a unique domain and localhost discovery."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain_id if domain_id is not None else unique_domain_id())
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.setdefault('PYTHONUNBUFFERED', '1')
    # a node that hangs prints every thread's Python stack on the SIGABRT wait_exit sends it
    env.setdefault('PYTHONFAULTHANDLER', '1')
    env.update(extra)
    return env


def init_context(domain_id: int, context=None):
    """An initialised ``rclpy.Context`` (``context``, default a new one) on ``domain_id`` with
    the discovery settings every fohssv
    node gives itself (``startup.init``: the package's loopback-only Fast DDS profile, and
    with it the range LOCALHOST handed to rcl as SUBNET), whatever the test process's own
    environment holds. A participant with LOCALHOST and the profile (what env.sh exported
    before it exported SUBNET with the profile) discovers by unicast announcements only: a
    node started after it saw it 0.5 to 2.9 s later, against 0 to 0.7 s for one configured
    like the nodes (measured), so a player that did not wait for it played to nobody."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from fohssv_sim.ros.startup import default_transport

    saved = {k: os.environ.get(k) for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE',
                                            'FASTDDS_DEFAULT_PROFILES_FILE')}
    try:
        default_transport()            # rcl and Fast DDS read these at init
        ctx = rclpy.Context() if context is None else context
        # the test process keeps its own signal handling (pytest's), default context or not
        rclpy.init(context=ctx, domain_id=domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return ctx


def executable(package: str, name: str) -> Path:
    """Path of an installed executable: what ``ros2 run package name`` resolves."""
    path = Path(get_package_prefix(package)) / 'lib' / package / name
    if not path.exists():
        raise FileNotFoundError(f'{path} is missing: is ros2_ws built (make setup)?')
    return path


def start(package: str, name: str, args: Sequence[str] = (), *, env: dict[str, str],
          log: Path | None = None, fork: bool = True):
    """Start ``package``/``name`` with ``args`` (e.g. ``['--ros-args', '-p', 'x:=1']``); a
    ``subprocess.Popen`` or, forked from this worker's server (:mod:`zygote`: the same
    process without the interpreter's start and imports), a :class:`zygote.Forked` used the
    same way. ``fork=False`` (or ``FOHSSV_TEST_FORK=0``, or an environment that starts Python
    differently) runs the executable as ``ros2 run`` does.

    Output goes to ``log`` (a file) if given, else to a pipe.
    """
    path = executable(package, name)
    out = open(log, 'w') if log is not None else subprocess.PIPE  # noqa: SIM115
    server = (zygote.Server.get(ros_env(0)) if fork
              and os.environ.get('FOHSSV_TEST_FORK', '1') != '0' else None)
    if server is not None and server.fits(env):
        proc = server.start(path, list(args), env, None if log is None else out.fileno())
        if log is not None:
            out.close()
    else:
        proc = subprocess.Popen([str(path), *args], env=env, stdout=out,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)
    proc.log = log          # where a failure reads its output (:func:`_abort`)
    STARTED.append(proc)
    return proc


def param_args(*settings: str) -> list[str]:
    """``--ros-args -p s ...`` for ``settings`` such as ``'bag_path:=/tmp/run'``."""
    out = ['--ros-args']
    for setting in settings:
        out += ['-p', setting]
    return out


def start_recorder(env: dict[str, str], log: Path, *settings: str,
                   ready: bool = True) -> subprocess.Popen:
    """The recorder node with the ``-p`` ``settings`` (e.g. ``f'bag_path:={bag}'``), its
    output in ``log``; with ``ready``, returned once it has created its bag (its ``recording
    to`` line), so that what a test starts next is recorded."""
    proc = start('fohssv_sim', 'recorder', param_args(*settings), env=env, log=log)
    if ready:
        wait_for(lambda: 'recording to' in log.read_text(), 90,
                 what=f'the recorder logging to {log}')
    return proc


def kill_leftovers() -> None:
    """Kill every process :func:`start` started that still runs (a failed assertion must not
    leave a plant, controller, recorder or player spinning on the machine)."""
    while STARTED:
        proc = STARTED.pop()
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)


def stop(proc: subprocess.Popen, sig: int = signal.SIGINT, timeout: float = 10.0) -> int:
    """Signal ``proc`` and wait for it; the exit code. A process that has not exited
    ``timeout`` s after the signal is a defect (every node ends within its bounded waits):
    it fails like :func:`wait_exit`, with where its threads were."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            _abort(proc, f'did not exit within {timeout} s of {signal.Signals(sig).name}')
    return proc.returncode


def wait_exit(proc: subprocess.Popen, timeout: float) -> int:
    """Wait for ``proc`` to exit by itself; fail with where its threads were
    (:func:`_abort`) if it does not in time."""
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        _abort(proc, f'did not exit within {timeout} s')


def _abort(proc: subprocess.Popen, what: str) -> NoReturn:
    """Raise AssertionError for a process that ``what`` (did not exit in time), with where
    each of its threads was: gdb's native backtraces (:func:`native_stacks`), then SIGABRT,
    on which a Python process with ``PYTHONFAULTHANDLER`` (:func:`ros_env`) prints its
    threads' Python stacks, then SIGKILL if it still lives. Its output, with that dump,
    goes into the failure: the last 6000 characters of its pipe or its log, and the pipe's
    total, which is 65536 when the process had filled a pipe nobody read and blocked on it."""
    native = native_stacks(proc.pid)
    proc.send_signal(signal.SIGCONT)      # gdb killed mid-attach may leave it stopped
    proc.send_signal(signal.SIGABRT)
    try:
        proc.wait(timeout=3)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=5)
    log = getattr(proc, 'log', None)
    if log is not None:
        text = Path(log).read_text(errors='replace')
        told = f'the end of its log {log}'
    else:
        text = _drain(proc, 5.0)
        told = f'{len(text)} characters of output, the last of them'
    raise AssertionError(f'{proc.args[0]} {what} (stopped with SIGABRT; {told}:\n'
                         f'{text[-6000:]})'
                         + (f'\nits threads in native code (gdb):\n{native}' if native
                            else '')) from None


def native_stacks(pid: int, timeout: float = 20.0, limit: int = 12000) -> str:
    """Where each thread of process ``pid`` is in native code, from ``gdb -batch``'s
    backtraces (the frames only, at most ``limit`` characters), or '' without gdb, when it
    may not attach (ptrace refused: Yama's ``ptrace_scope``, a container without
    CAP_SYS_PTRACE) or takes longer than ``timeout`` s. Python's own dump (SIGABRT,
    faulthandler) stops at the call into a C extension: a node stuck inside rclpy or Fast DDS
    shows only the Python line that called it, this shows the lock or the wait. gdb reads no
    debug info from the network and loads no per-library scripts."""
    import shutil

    gdb = shutil.which('gdb')
    if gdb is None:
        return ''
    try:
        out = subprocess.run([gdb, '-p', str(pid), '-batch', '-nx',
                              '-iex', 'set debuginfod enabled off', '-iex', 'set auto-load off',
                              '-ex', 'thread apply all bt'], capture_output=True, text=True,
                             timeout=timeout, stdin=subprocess.DEVNULL).stdout
    except (OSError, subprocess.TimeoutExpired):
        return ''
    frames = [ln for ln in out.splitlines() if ln.startswith(('Thread ', '#'))]
    text = '\n'.join(ln if len(ln) < 240 else ln[:240] + '...' for ln in frames)
    return text[:limit]


def clean_shared_memory() -> str | None:
    """Remove the Fast DDS shared-memory files (``/dev/shm/fastdds_*``) that no live process
    holds, with Fast DDS's own ``fastdds shm clean`` (``tools/fastdds/shm/clean.py`` of the
    venv's or a ROS install's prefix): a process killed with SIGKILL, as many tests kill
    nodes, leaves its segments and ports behind (1.6 GB in ``/dev/shm`` after a day of
    test runs on this machine: the first clean removed 222 ports and 2849 segments). A file
    a live process holds (another run's) is kept: the tool removes only those whose lock
    file nobody holds. What it printed, or None when the tool is not there."""
    import contextlib
    import importlib.util
    import io

    prefixes = [sys.prefix, *os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)]
    for prefix in filter(None, prefixes):
        tool = Path(prefix) / 'tools' / 'fastdds' / 'shm' / 'clean.py'
        if tool.is_file():
            break
    else:
        return None
    spec = importlib.util.spec_from_file_location('_fastdds_shm_clean', tool)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        module.Clean().run(False)
    return printed.getvalue()


def _drain(proc: subprocess.Popen, timeout: float) -> str:
    """The output of a stopped process started without ``log``, read for at most ``timeout``
    s (a child it left, e.g. the in-plant writer, may hold the pipe open)."""
    if proc.stdout is None:
        return ''
    import select

    fd, chunks = proc.stdout.fileno(), []
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        if not select.select([fd], [], [], left)[0]:
            break
        chunk = os.read(fd, 1 << 16)
        if not chunk:
            break
        chunks.append(chunk)
    return b''.join(chunks).decode(errors='replace')


#: Fast DDS's log line when two participants starting at the same instant race for one
#: shared-memory port: the loser logs it and takes the next port (its participant works; a
#: long-standing upstream line: eProsima/Fast-DDS issues 2003 and 2099, and 6117 on the
#: port mutex). Matched after its colour codes are removed.
FASTDDS_PORT_RACE = re.compile(r'\[RTPS_TRANSPORT_SHM Error\] Failed init_port '
                               r'fastdds_port\d+: open_and_lock_file failed '
                               r'-> Function open_port_internal$')
_COLOUR = re.compile(r'\x1b\[[0-9;]*m')


def without_port_race(text: str) -> str:
    """``text`` without Fast DDS's :data:`FASTDDS_PORT_RACE` lines: a test that starts many
    nodes at once in one domain checks each node's own lines."""
    return ''.join(line for line in text.splitlines(keepends=True)
                   if not FASTDDS_PORT_RACE.search(_COLOUR.sub('', line).rstrip()))


def summary(text: str) -> dict:
    """The plant's summary: the JSON after ``summary: `` on the last line of ``text`` (its log
    or output) that has one; a run logs one, at its end or on the signal that ended it."""
    import json

    lines = [ln for ln in text.splitlines() if 'summary: {' in ln]
    if not lines:
        raise AssertionError(f'no summary line in the log; its end:\n{text[-3000:]}')
    return json.loads(lines[-1].split('summary: ', 1)[1])


def output(proc: subprocess.Popen) -> str:
    """All output of an exited process started without ``log``."""
    if proc.stdout is None:
        return ''
    return proc.stdout.read()


def wait_for(predicate, timeout: float, interval: float = 0.02, what: str = 'condition'):
    """Poll ``predicate`` until it is truthy; raise AssertionError after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f'timed out after {timeout} s waiting for {what}')
