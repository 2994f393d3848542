"""Entry points of the node executables (``console_scripts`` in setup.py).

A node imports rclpy, numpy and numba before its ``main`` runs, a second or more. A SIGINT or
SIGTERM in that time (a launch shutting down because another node failed at start, Ctrl-C
right after starting) used to end it with a ``KeyboardInterrupt`` traceback from deep in an
import. Until the node installs its own handlers (:func:`.nodekit.run_node`: SIGINT/SIGTERM
then stop it cleanly), a signal ends the process quietly with exit 0, a clean stop before the
node ran. This module imports nothing heavy.

Where coverage.py is installed (a test dependency), numba imports it for its JIT coverage
support, 0.04 s of CPU at each start, which only a process being measured uses: an entry
point not started under coverage (coverage not imported yet, as its process-start hook would
have done) marks it absent (:func:`skip_coverage`).
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from importlib import import_module

__all__ = ['quiet_until_started', 'skip_coverage', 'run', 'plant', 'recorder', 'player', 'viewer']


def _ended(signum: int, frame: object) -> None:
    os._exit(0)


def quiet_until_started() -> None:
    """SIGINT/SIGTERM end the process quietly (exit 0) until the node replaces the handlers."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _ended)


def skip_coverage() -> None:
    """``import coverage`` fails from now on unless coverage is already imported (a process
    being measured): numba then leaves its coverage support out."""
    sys.modules.setdefault('coverage', None)


def run(module: str, function: str = 'main') -> Callable[[], int]:
    """The entry point ``module:function``, imported after :func:`quiet_until_started` and
    :func:`skip_coverage`."""
    def entry() -> int:
        quiet_until_started()
        skip_coverage()
        return getattr(import_module(module), function)()
    entry.__name__ = function
    return entry


plant = run('fohssv_sim.ros.plant_node')
recorder = run('fohssv_sim.ros.recorder_node')
player = run('fohssv_sim.ros.player_node')
viewer = run('fohssv_sim.ros.viewer_node')

if __name__ == '__main__':
    sys.exit(plant())
