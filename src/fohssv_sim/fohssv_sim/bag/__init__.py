"""Recording files: write, load, check and repair rosbag2 bags (MCAP storage). Pure: no rclpy.

* :class:`~.writer.RunWriter` writes a bag that survives SIGKILL up to its last flush;
* :func:`~.loader.load_run` reads a run (complete or truncated) into numpy arrays;
* :func:`~.check.check` verifies a bag's structure (CRCs, indexes, summary, metadata.yaml);
* :func:`~.repair.repair` rebuilds the index, summary and metadata.yaml of a cut bag.

Command line: ``python -m fohssv_sim.bag info|check|repair BAG``.

The names below are imported when first used: a process that needs one module of the package
(the plant's in-plant recording imports the writer) does not import the others' (the loader's
YAML and the run's readers, 0.05 s of CPU).
"""

from importlib import import_module
from typing import Any

__all__ = ['BagError', 'Run', 'RunWriter', 'load_run', 'scan']

_MODULES = {'BagError': '.loader', 'scan': '.loader', 'Run': '.run', 'load_run': '.run',
            'RunWriter': '.writer'}


def __getattr__(name: str) -> Any:
    if name not in _MODULES:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(import_module(_MODULES[name], __name__), name)
