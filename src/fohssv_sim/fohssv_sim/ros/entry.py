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

rclpy's logger finds the caller of each message (its function, file and line: the key of the
``once``/``throttle`` filters, and what a custom ``RCUTILS_CONSOLE_OUTPUT_FORMAT`` can show)
with ``inspect.getframeinfo``, which reads the caller's source lines and looks up the module
of each frame's file among every imported module: in a plant (a thousand modules) 0.07 s of
CPU for its first message and about 5 ms for each after. It keeps only the file name, which
for a frame of a source file is the frame's own ``f_code.co_filename``: :func:`cheap_log_callers`
hands rclpy that directly (the same caller, function, file and line).
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from importlib import import_module
from types import FrameType, SimpleNamespace

__all__ = ['quiet_until_started', 'skip_coverage', 'cheap_log_callers', 'run', 'plant',
           'recorder', 'player', 'viewer']


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


def _frame_file(frame: FrameType) -> SimpleNamespace:
    """What rclpy's logger reads of ``inspect.getframeinfo(frame)``: the file name."""
    return SimpleNamespace(filename=frame.f_code.co_filename)


def cheap_log_callers() -> None:
    """rclpy's logger takes each message's caller from the frames' code, not from
    ``inspect.getframeinfo`` (see the module docstring); where rclpy does not look it up
    that way (another version), nothing changes."""
    import inspect

    from rclpy.impl import rcutils_logger

    if getattr(rcutils_logger, 'inspect', None) is inspect:
        rcutils_logger.inspect = SimpleNamespace(currentframe=inspect.currentframe,
                                                 getframeinfo=_frame_file)


def run(module: str, function: str = 'main') -> Callable[[], int]:
    """The entry point ``module:function``, imported after :func:`quiet_until_started`,
    :func:`skip_coverage` and :func:`cheap_log_callers`."""
    def entry() -> int:
        quiet_until_started()
        skip_coverage()
        cheap_log_callers()
        return getattr(import_module(module), function)()
    entry.__name__ = function
    return entry


plant = run('fohssv_sim.ros.plant_node')
recorder = run('fohssv_sim.ros.recorder_node')
player = run('fohssv_sim.ros.player_node')
viewer = run('fohssv_sim.ros.viewer_node')

if __name__ == '__main__':
    sys.exit(plant())
