"""The plant's lockstep command callback in one process (a diagnostic tool).

A :class:`~fohssv_sim.ros.plant_node.PlantNode` (FOM, alpha 0.85, V 75, h 2e-5 s, 'soe',
lockstep, the default control period) is built in this process with real rclpy publishers
and no subscriber, and its lockstep command callback is called with eq. 31's answer to each
sample, serialized as the controller node sends it: the advance, the sample's write, the
publishes of ``state`` and ``planing_force`` (and ``/clock``) and the callback's bookkeeping,
with no DDS round trip and no peer. ``--clock on`` publishes ``/clock`` at every sample as
the plant did before it published it only while someone subscribes; ``off`` is what the
plant does with no ``/clock`` reader. Prints one JSON line: wall and CPU microseconds per
sample over each of ``--repeats`` blocks of ``--samples`` samples, and the median time from
the callback's entry to the call that publishes the state (``to_state_us``: what the round
trip waits for; the rest of the callback runs while the state travels).

    python tools/diag/plant_callback.py --clock off
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import rclpy

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'bench'))
from rclpy.parameter import Parameter
from ros_runs import MODEL_PARAMS  # noqa: E402  (bench/ros_runs.py)

from fohssv_sim.contract import COMMAND
from fohssv_sim.ros.plant_node import PlantNode
from fohssv_sim.ros.wire import ArrayWriter

#: the FOM of bench_ros's cases, lockstep, open-ended
PARAMS = {'mode': 'lockstep', 'model': 'fractional', **MODEL_PARAMS['fractional'],
          'duration': 0.0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--clock', choices=('on', 'off'), required=True)
    ap.add_argument('--samples', type=int, default=20000)
    ap.add_argument('--repeats', type=int, default=5)
    a = ap.parse_args()
    rclpy.init()
    node = PlantNode(parameter_overrides=[Parameter(k, value=v) for k, v in PARAMS.items()])
    try:
        node.running = True
        node._refresh_matched()                 # as the run's start does: no /clock reader
        if a.clock == 'on':
            node._clock_on = node._clock_wanted = True
        callback = node._on_command_lockstep
        sent, k = np.zeros(a.samples, dtype=np.int64), [0]
        send_state = node._send_state

        def timed_send(payload: bytes) -> None:
            if k[0] < a.samples:
                sent[k[0]] = time.perf_counter_ns()
                k[0] += 1
            send_state(payload)

        node._send_state = timed_send
        entered = np.zeros(a.samples, dtype=np.int64)
        command = ArrayWriter(COMMAND)
        out, state = command.values, node._state_data
        node._publish()
        node._await_command()
        blocks = []
        for _ in range(a.repeats):
            k[0] = 0
            wall, cpu = time.perf_counter(), time.process_time()
            for i in range(a.samples):
                out[0] = node._awaiting          # eq. 31, fins at zero, clamped to 0.3 rad
                out[2] = max(-0.3, min(0.3, 15.0 * state[1] - 30.0 * state[3]
                                       - 0.3 * state[4]))
                payload = command.payload()
                entered[i] = time.perf_counter_ns()
                callback(payload)
            blocks.append({'wall_us': (time.perf_counter() - wall) / a.samples * 1e6,
                           'cpu_us': (time.process_time() - cpu) / a.samples * 1e6,
                           'to_state_us': float(np.median(sent - entered)) / 1e3})
        if node._awaiting is None:
            raise RuntimeError('the run ended during the benchmark')
        print(json.dumps({'clock': a.clock, 'samples': node.sim.samples, 'blocks': blocks}),
              flush=True)
    finally:
        node.destroy_node()
        rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
