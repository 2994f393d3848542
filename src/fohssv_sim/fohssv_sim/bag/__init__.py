"""Recording files: write, load, check and repair rosbag2 bags (MCAP storage). Pure: no rclpy.

* :class:`~.writer.RunWriter` writes a bag that survives SIGKILL up to its last flush;
* :func:`~.loader.load_run` reads a run (complete or truncated) into numpy arrays;
* :func:`~.check.check` verifies a bag's structure (CRCs, indexes, summary, metadata.yaml);
* :func:`~.repair.repair` rebuilds the index, summary and metadata.yaml of a cut bag.

Command line: ``python -m fohssv_sim.bag info|check|repair BAG``.
"""

from .loader import BagError, scan
from .run import Run, load_run
from .writer import RunWriter

__all__ = ['BagError', 'Run', 'RunWriter', 'load_run', 'scan']
