"""The plant's run end in the test process: the plant's own ``_run`` (spin, flush, linger), and
which signals end its linger. (A signal from outside, and what a recorder drains meanwhile,
are the process tests': tests/test_graph_run_end.py, tests/test_graph_bad_input.py.)"""

from __future__ import annotations

import signal
import time

import pytest
from inprocess import overrides

from fohssv_sim.ros.plant_node import PlantNode, _run
from fohssv_sim.ros.spin import STOP

pytestmark = pytest.mark.node


def test_a_signal_while_the_run_ends_by_itself_ends_the_linger(graph):
    """A SIGINT that comes while the run ends by itself (raised here as the plant says its
    duration is reached, after the last sample went out) did not interrupt the run: it ends
    the linger (end_linger 60 s, a reader of the samples still there) at once. The plant
    looks at signals between callbacks, and took the count after its loop for the signals
    that interrupted the run, which the linger passes over (so that a recorder still
    drains): it lingered on, and a graph test's stop (SIGINT, 10 s) found it alive under load
    and killed it (-9)."""
    graph.probe()              # a reader of the samples: the linger waits while it is there
    plant = PlantNode(context=graph.context, parameter_overrides=overrides({
        'model': 'delay-free', 'duration': 0.01, 'controller': 'state_feedback',
        'min_state_subscribers': 2, 'end_linger': 60.0}))
    finish = plant._finish

    def finish_signalled(why: str) -> None:
        signal.raise_signal(signal.SIGINT)        # the process's handler (STOP) counts it
        finish(why)

    plant._finish = finish_signalled
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    STOP.install()
    try:
        begin = time.monotonic()
        code = _run(plant)
        took = time.monotonic() - begin
        lingered = plant.state_pub.get_subscription_count()
        counted = STOP.count
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
        STOP.received, STOP.count = None, 0
        plant.destroy_node()
    assert counted == 1 and code == 0
    assert lingered == 1                 # the reader was there all along
    assert took < 10.0, f'_run took {took:.1f} s: the linger went on after the signal'
