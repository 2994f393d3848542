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

numba's first compile or cache load in a process checks that BLAS is there by importing
``scipy.linalg.cython_blas``, which imports the whole ``scipy.linalg`` package first and with
it scipy's array-API layer (numpy.f2py, numpy.testing, ...): 0.15 s of CPU at each start of a
plant, which calls no scipy.linalg function. :func:`blas_alone` loads that one extension module
by itself under its own name, so numba finds it imported; a law that needs scipy.linalg (the
LQR) imports the package later as before, and it takes the same module.
"""

from __future__ import annotations

import os
import signal
import sys
from collections.abc import Callable
from importlib import import_module
from importlib.machinery import PathFinder
from importlib.util import module_from_spec
from types import FrameType, SimpleNamespace

__all__ = ['quiet_until_started', 'skip_coverage', 'cheap_log_callers', 'blas_alone', 'run',
           'plant', 'recorder', 'player', 'viewer']


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


def blas_alone() -> None:
    """Import ``scipy.linalg.cython_blas`` without the ``scipy.linalg`` package (see the module
    docstring); where that fails (another scipy), nothing changes."""
    name = 'scipy.linalg.cython_blas'
    if 'scipy.linalg' in sys.modules or name in sys.modules:
        return
    try:
        import scipy

        spec = PathFinder.find_spec(name, [os.path.join(os.path.dirname(scipy.__file__),
                                                        'linalg')])
        if spec is None or spec.loader is None:
            return
        module = module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    except Exception:  # noqa: BLE001 - numba then imports scipy.linalg as before
        sys.modules.pop(name, None)


def run(module: str, function: str = 'main', compiled: bool = False) -> Callable[[], int]:
    """The entry point ``module:function``, imported after :func:`quiet_until_started`,
    :func:`skip_coverage`, :func:`cheap_log_callers` and, for a node that runs numba's
    compiled code (``compiled``), :func:`blas_alone`."""
    def entry() -> int:
        quiet_until_started()
        skip_coverage()
        cheap_log_callers()
        if compiled:
            blas_alone()
        return getattr(import_module(module), function)()
    entry.__name__ = function
    return entry


plant = run('fohssv_sim.ros.plant_node', compiled=True)
recorder = run('fohssv_sim.ros.recorder_node')
player = run('fohssv_sim.ros.player_node')
viewer = run('fohssv_sim.ros.viewer_node')

if __name__ == '__main__':
    sys.exit(plant())
