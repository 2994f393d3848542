"""A fork server for the tests' node processes: each test worker's nodes start forked from a
process that imported the nodes and loaded their compiled kernels once.

A node started by ``ros2 run`` spends about 1 CPU s importing numpy, numba, scipy and rclpy
and loading its kernels from numba's cache before its ``main`` runs; the tests start about
two hundred, on two cores. Forked from this server, a node is still a process of its own
with its own pid, session, environment, ROS context and DDS participant, its output in its
log, its exit code and signals its own (:class:`Forked`): what the graph tests check
between processes. It skips the interpreter's start and the imports only, which the
executables' own tests (tests/test_entry_*.py, launch, the demo and the README walkthrough,
any process whose environment changes how Python or its libraries start) still run as
``ros2 run`` does: :func:`rosproc.start` forks only when the environment matches the
server's in every variable read at interpreter or library start (:data:`START_VARS`).

The server (``python zygote.py FD``) reads requests on the socket FD: JSON (the entry point,
argv, cwd, env) with two file descriptors (the process's output and a pipe for its exit
status); it forks, answers the pid, reaps each child and writes its wait status to that
child's pipe. The child leaves the server's loop and runs the entry point at the top of this
module, and ends as multiprocessing's forked children do: its other threads joined, the
atexit functions run, the output flushed, then ``os._exit`` with the exit code (the
interpreter's finalization of a forked plant that had published through the fault sink,
faults.py, crashed with SIGSEGV; an executable never does).
"""

from __future__ import annotations

import atexit
import json
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
from importlib.metadata import entry_points
from pathlib import Path

#: Prefixes of the variables read when Python, the dynamic loader, numba or BLAS start: a
#: process whose values differ from the server's is started as an executable instead.
START_VARS = ('PYTHON', 'LD_', 'NUMBA_', 'OPENBLAS_', 'OMP_', 'MKL_', 'COVERAGE_')

#: The modules the server imports: the nodes and the controllers' laws.
PRELOAD = ('fohssv_sim.ros.plant_node', 'fohssv_sim.ros.recorder_node',
           'fohssv_sim.ros.player_node', 'fohssv_controller.ros.controller_node',
           'fohssv_controller.state_feedback', 'fohssv_controller.lqr',
           'fohssv_controller.fractional_pid', 'fohssv_controller.scheduled')


def start_key(env: dict[str, str]) -> dict[str, str]:
    """The variables of ``env`` that must equal the server's for a fork to be the same start."""
    return {k: v for k, v in env.items() if k.startswith(START_VARS)}


# -- the server ---------------------------------------------------------------------------

def _preload() -> None:
    """Import what the nodes import, as their entry points do, and load the plant's kernels."""
    from fohssv_sim.ros import entry

    entry.skip_coverage()
    entry.cheap_log_callers()
    entry.blas_alone()
    from importlib import import_module
    for name in PRELOAD:
        import_module(name)
    from fohssv_sim import models
    from fohssv_sim.ros.plant.fastpath import sample
    models.warm_up()
    sample.warm_up()


def _serve(sock: socket.socket) -> tuple[dict, int] | None:
    """Fork a child per request until the socket closes; in a child, (request, output fd)."""
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w, warn_on_full_buffer=False)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    exits: dict[int, int] = {}       # pid -> its exit pipe's write end
    while True:
        ready, _, _ = select.select([sock, wake_r], [], [])
        if wake_r in ready:
            os.read(wake_r, 4096)
        while exits:                 # reap: each child's wait status to its pipe
            pid, status = os.waitpid(-1, os.WNOHANG)
            if pid == 0:
                break
            fd = exits.pop(pid, None)
            if fd is not None:
                os.write(fd, struct.pack('i', status))
                os.close(fd)
        if sock not in ready:
            continue
        msg, fds, _, _ = socket.recv_fds(sock, 1 << 20, 2)
        if not msg:                  # the test worker is gone
            return None
        request = json.loads(msg)
        out_fd, exit_fd = fds
        pid = os.fork()
        if pid == 0:
            signal.set_wakeup_fd(-1)
            signal.signal(signal.SIGCHLD, signal.SIG_DFL)
            for fd in (wake_r, wake_w, exit_fd, *exits.values()):
                os.close(fd)
            sock.close()
            return request, out_fd
        os.close(out_fd)
        exits[pid] = exit_fd
        sock.sendall(struct.pack('i', pid))


def _become(request: dict, out_fd: int) -> int:
    """In the forked child: the node's session, output, directory, environment and argv, then
    its entry point; its exit code."""
    os.setsid()
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    os.dup2(out_fd, 1)
    os.dup2(out_fd, 2)
    os.close(out_fd)
    os.chdir(request['cwd'])
    os.environ.clear()
    os.environ.update(request['env'])
    sys.argv = request['argv']
    (main,) = (ep for ep in entry_points(group='console_scripts', name=request['name'])
               if ep.value.startswith(request['module']))
    return main.load()()


# -- the test side ------------------------------------------------------------------------

class Forked:
    """A node process forked by the server, used as ``subprocess.Popen`` is (pid, poll, wait,
    send_signal, terminate, kill, returncode, stdout, communicate)."""

    def __init__(self, pid: int, args: list[str], exit_fd: int, stdout) -> None:
        self.pid, self.args, self.stdout, self.stderr = pid, args, stdout, None
        self.returncode: int | None = None
        self._exit_fd = exit_fd

    def poll(self) -> int | None:
        return self.wait(0) if self._ended(0) else None

    def _ended(self, timeout: float | None) -> bool:
        if self.returncode is not None:
            return True
        return bool(select.select([self._exit_fd], [], [], timeout)[0])

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            if not self._ended(timeout):
                raise subprocess.TimeoutExpired(self.args, timeout)
            data = os.read(self._exit_fd, 4)
            os.close(self._exit_fd)
            self.returncode = (os.waitstatus_to_exitcode(struct.unpack('i', data)[0])
                               if len(data) == 4 else -signal.SIGKILL)   # the server died
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def communicate(self, timeout: float | None = None) -> tuple[str | None, None]:
        out = self.stdout.read() if self.stdout is not None else None
        self.wait(timeout)
        return out, None


class Server:
    """This test worker's fork server, started on first use with the worker's environment."""

    _lock = threading.Lock()
    _running: Server | None = None

    def __init__(self, env: dict[str, str]) -> None:
        mine, theirs = socket.socketpair()
        self.key = start_key(env)
        self.proc = subprocess.Popen(
            [sys.executable, __file__, str(theirs.fileno())], env=env, pass_fds=[theirs.fileno()],
            stdin=subprocess.DEVNULL, start_new_session=True)
        theirs.close()
        self.sock = mine
        atexit.register(self.close)

    def close(self) -> None:
        """End the server (it exits when its socket closes) and reap it."""
        self.sock.close()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()

    @classmethod
    def get(cls, base: dict[str, str]) -> Server:
        """This worker's server, started with the environment ``base`` if none runs."""
        with cls._lock:
            if cls._running is None or cls._running.proc.poll() is not None:
                cls._running = cls(base)
            return cls._running

    def fits(self, env: dict[str, str]) -> bool:
        """Whether a process with ``env`` starts as this server did (:data:`START_VARS`)."""
        return self.key == start_key(env)

    def start(self, executable: Path, args: list[str], env: dict[str, str],
              out_fd: int | None) -> Forked:
        """``executable`` (an installed console script) with ``args``, forked."""
        module = _script_module(executable)
        reader = None
        if out_fd is None:
            read_end, out_fd = os.pipe()
            reader = open(read_end, encoding='utf-8', errors='replace')  # noqa: SIM115
        exit_r, exit_w = os.pipe()
        request = {'name': executable.name, 'module': module, 'cwd': os.getcwd(),
                   'env': env, 'argv': [str(executable), *args]}
        with self._lock:
            socket.send_fds(self.sock, [json.dumps(request).encode()], [out_fd, exit_w])
            (pid,) = struct.unpack('i', self.sock.recv(4))
        os.close(exit_w)
        if reader is not None:
            os.close(out_fd)
        return Forked(pid, request['argv'], exit_r, reader)


def _script_module(executable: Path) -> str:
    """The package of the console script ``executable`` (its entry point's module's top)."""
    return executable.parent.name


if __name__ == '__main__':
    _preload()
    child = _serve(socket.socket(fileno=int(sys.argv[1])))
    if child is None:
        sys.exit(0)
    try:
        code = _become(*child)
    except SystemExit as exc:
        code = exc.code
    threading._shutdown()
    atexit._run_exitfuncs()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code if isinstance(code, int) else 0 if code is None else 1)
