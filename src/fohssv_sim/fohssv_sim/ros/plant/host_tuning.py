"""Host tuning of the plant's process: CPU affinity, the CPU wake-up latency request and, in
real time, timer slack, SCHED_FIFO and the kernel's preemption model (what a run on this host
can expect). Each setting is a parameter of the plant (``cpu_affinity``, ``cpu_dma_latency``,
``realtime_priority``); what cannot be set is said in one line and the run goes on.

A function, not a room with state: it is given the node (its logger, its threads) and the
options, and gives back the CPU latency it holds, which the run's summary reports.
"""

from __future__ import annotations

from typing import Any

from ..host import (
    PREEMPTIBLE,
    hold_latency,
    kernel_preemption,
    pin_node,
    set_realtime_priority,
    tighten_timer_slack,
)
from ..options import PlantOptions

__all__ = ['tune_host']


def tune_host(node: Any, o: PlantOptions) -> int | None:
    """Apply the host settings of ``o`` to the process of the plant ``node`` (once, before
    it spins); the ``cpu_dma_latency`` held (us), None when none is."""
    pinned = pin_node(node, o.cpu_affinity)
    latency = hold_latency(node, o.cpu_dma_latency, warn=o.mode == 'realtime')
    if o.mode != 'realtime':
        return latency
    tighten_timer_slack()
    refused = set_realtime_priority(o.realtime_priority)
    model, hz = kernel_preemption()
    if model is not None and model not in PREEMPTIBLE:
        node.get_logger().info(
            f'kernel preemption {model!r}' + (f' ({hz} Hz tick)' if hz else '') + ': the '
            'pacing thread, SCHED_FIFO or not, waits for any kernel path another task runs '
            'on its CPU (milliseconds at worst); for deadlines of a 1e-4 s control period, '
            'a kernel with preempt=full (boot parameter, PREEMPT_DYNAMIC kernels) or '
            'PREEMPT_RT')
    if refused:
        node.get_logger().warning(f'{refused}; running with the normal scheduler')
    elif pinned and o.realtime_priority and len(o.cpu_affinity) == 1:
        node.get_logger().warning(
            'cpu_affinity names one CPU and the pacing thread runs under SCHED_FIFO: '
            "behind schedule it can keep the process's own DDS threads (commands, "
            'acknowledgements) off that CPU; give the plant two CPUs or realtime_priority:=0')
    return latency
