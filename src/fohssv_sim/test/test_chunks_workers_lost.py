"""The chunk machinery (:func:`fohssv_sim.analysis.sweep.run_chunks`, shared by sweeps, gain
maps, tune and fit) ends with :class:`WorkersLost` when its Dask workers die, instead of
waiting for ever: a real scheduler and a real worker, each its own process (``dask scheduler``,
``dask worker --no-nanny``: nothing restarts the worker), SIGKILLed while it runs a chunk.
The finished chunk is kept and a rerun on a new worker resumes from it."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from fohssv_sim.analysis.sweep import WorkersLost, chunk_path, run_chunks

HERE = Path(__file__).resolve().parent


def slow_second_chunk(marker: str, indices, progress=None):
    """Chunk [0] returns at once; chunk [1] sleeps while ``marker`` exists (the test kills
    its worker meanwhile), so a rerun after the marker is removed finishes."""
    if indices[0] == 1:
        Path(marker).with_suffix('.running').write_text(str(os.getpid()))
        while Path(marker).exists():
            time.sleep(0.05)
    return [{'point': i, 'value': 10 * i} for i in indices]


def _start(args, log: Path) -> subprocess.Popen:
    """A Dask process that can import this module (the scheduler unpickles the task too)."""
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join([str(HERE), os.environ.get(
        'PYTHONPATH', '')])}
    return subprocess.Popen([sys.executable, '-m', *args], stdout=open(log, 'w'),
                            stderr=subprocess.STDOUT, env=env, start_new_session=True)


def _wait(pred, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise AssertionError(f'timed out waiting for {what}')
        time.sleep(0.05)


def _stop(*procs: subprocess.Popen) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=10)


def _worker(address: str, log: Path) -> subprocess.Popen:
    return _start(['distributed.cli.dask_worker', address, '--no-nanny', '--nthreads', '2',
                   '--no-dashboard'], log)


def test_run_chunks_ends_with_workers_lost_and_a_rerun_resumes(tmp_path):
    slog = tmp_path / 'scheduler.log'
    sched = _start(['distributed.cli.dask_scheduler', '--port', '0', '--no-dashboard',
                    '--host', '127.0.0.1'], slog)
    procs = [sched]
    try:
        found: list[str] = []

        def address() -> bool:
            found[:] = re.findall(r'Scheduler at:\s+(tcp://\S+)', slog.read_text())
            return bool(found)

        _wait(address, 60, 'the scheduler')
        addr = found[0]
        procs.append(_worker(addr, tmp_path / 'worker1.log'))
        out = tmp_path / 'job'
        marker = tmp_path / 'hold'
        marker.write_text('')
        running = marker.with_suffix('.running')
        killed: list[int] = []

        def kill_when_running() -> None:
            _wait(lambda: running.exists() and chunk_path(out, 0).exists(), 120,
                  'chunk 1 to run and chunk 0 to be written')
            os.kill(int(running.read_text()), signal.SIGKILL)
            killed.append(1)

        from dask.distributed import Client

        side = {'spec': {'job': 'workers-lost'}, 'chunks': [[0], [1]]}
        with Client(addr, timeout='30s') as client:
            t = threading.Thread(target=kill_when_running, daemon=True)
            t.start()
            with pytest.raises(WorkersLost) as e:
                run_chunks(out, 'job.json', side, [[0], [1]], slow_second_chunk,
                           (str(marker),), ('point', 'value'), client=client, lost_after=2.0)
            t.join(5)
            assert killed
            msg = str(e.value)
            assert 'every Dask worker is gone' in msg and '1 of 2 chunks are finished' in msg
            assert 'rerun the same command to resume' in msg and '\n' not in msg
            assert chunk_path(out, 0).exists() and not chunk_path(out, 1).exists()

            marker.unlink()
            procs.append(_worker(addr, tmp_path / 'worker2.log'))
            client.wait_for_workers(1, timeout=60)
            assert run_chunks(out, 'job.json', side, [[0], [1]], slow_second_chunk,
                              (str(marker),), ('point', 'value'), client=client,
                              lost_after=2.0) == (1, 1)
            assert chunk_path(out, 1).read_text().splitlines()[1] == '1,10'
    finally:
        _stop(*procs)
