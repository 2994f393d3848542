"""Benchmark of in-plant recording's two sides without ROS (fohssv_sim.bag.inplant): what the
plant pays per message (a record copied into the shared-memory ring, process CPU time), and
what the writer process pays per message and how many it writes per second (ring to a closed
bag, CPU time from /proc).

The records are a lockstep sample's messages, serialized by rosbags (state, planing_force,
/clock, command: four per sample); the ring is the default 32 MiB, so the producer never
waits. Two cases: the producer as fast as it can (the writer takes large batches; its rate
says how long a 10 kHz run, 40000 messages a second, it keeps up with: the ring holds about
8 s of backlog), and paced at the demo loop's rate (5000 samples a second, in bursts of one
millisecond: the writer wakes between batches as in a run, so its per-batch costs count).
The writer's CPU is its own process time from bag open to close (its closing reply), close
included.

    python bench/bench_inplant.py --out bench/results/inplant.json [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from fohssv_sim import contract
from fohssv_sim.bag.inplant import Ring, TopicSpec, WriterConfig, kind_of, read_reply, send
from fohssv_sim.bag.writer import typestore

TS = typestore()
#: Samples per second of the paced case: the lockstep demo loop through a controller node on
#: a 2-core machine (about 5000 round trips a second, bench/bench_ros.py).
DEMO_RATE = 5000.0
INF = QosTime(9223372036, 854775807)
QOS = Qos(history=QosHistory.KEEP_LAST, depth=2000, reliability=QosReliability.RELIABLE,
          durability=QosDurability.VOLATILE, deadline=INF, lifespan=INF,
          liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=INF,
          avoid_ros_namespace_conventions=False)


def _array(topic: contract.Topic, values) -> bytes:
    dim = TS.types['std_msgs/msg/MultiArrayDimension'](label=topic.label, size=len(values),
                                                         stride=len(values))
    layout = TS.types['std_msgs/msg/MultiArrayLayout'](dim=[dim], data_offset=0)
    msg = TS.types[contract.FLOAT64_ARRAY](layout=layout, data=np.array(values, float))
    return bytes(TS.serialize_cdr(msg, contract.FLOAT64_ARRAY))


def _clock(ns: int) -> bytes:
    t = TS.types['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
    return bytes(TS.serialize_cdr(TS.types[contract.CLOCK.type](clock=t), contract.CLOCK.type))


def _cpu(pid: int) -> float:
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def run(samples: int, rate: float = 0.0, compiled: bool = True) -> dict:
    """The writer fed ``samples`` lockstep samples, at ``rate`` samples per second (0: as fast
    as the producer can), through its compiled path (bag.ringpack) or its interpreted one."""
    topics = (contract.STATE, contract.PLANING_FORCE, contract.CLOCK, contract.COMMAND)
    specs = tuple(TopicSpec('/' + t.name.lstrip('/'), t.type, (QOS,), kind_of(t.type))
                  for t in topics)
    ring = Ring.create()
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.Popen([sys.executable, '-m', 'fohssv_sim.bag.inplant', str(ring.fd),
                                 str(ring.size)], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, pass_fds=(ring.fd,))
        send(proc.stdin, ('open', WriterConfig(f'{tmp}/bag', specs, {}, compiled=compiled)))
        read_reply(proc.stdout)                      # opened
        read_reply(proc.stdout)                      # ready (its compiled path loaded)
        idle_cpu = _cpu(proc.pid)
        messages = []
        for k in range(min(samples, 1000)):
            t = k * 1e-4
            messages.append((_array(contract.STATE, [t, 0.1, 0.2, 0.3, 0.4]),
                             _array(contract.PLANING_FORCE, [t, 5.0]), _clock(round(t * 1e9)),
                             _array(contract.COMMAND, [t, 0.01, -0.02])))
        put = ring.put
        burst = max(1, round(rate * 1e-3)) if rate else samples      # samples per millisecond
        wall0 = time.monotonic()
        cpu0 = time.process_time()
        for k in range(samples):
            if rate and k % burst == 0:
                delay = wall0 + k / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            state, force, clock, command = messages[k % len(messages)]
            put(0, state)
            put(1, force)
            put(2, clock)
            put(3, command)
        producer = (time.process_time() - cpu0) / (4 * samples)
        send(proc.stdin, ('end', contract.run_end_text('plant', 'bench', 0, 0.0, {})))
        reply = read_reply(proc.stdout)
        wall = time.monotonic() - wall0
        writer_cpu = _cpu(proc.pid) - idle_cpu       # 10 ms ticks; the reply's is exact
        proc.wait(timeout=60)
        if reply is not None and 'cpu_time' in reply:
            writer_cpu = reply['cpu_time']
    ring.close()
    n = 4 * samples
    if reply is None or reply.get('messages') != n or reply.get('compiled') != compiled:
        raise RuntimeError(f'the writer wrote {reply}')
    return {'messages': n, 'rate_samples_per_second': rate, 'compiled': compiled,
            'writer_load_cpu_time': reply.get('load_cpu_time', 0.0),
            'producer_cpu_per_message_us': producer * 1e6,
            'writer_cpu_per_message_us': writer_cpu / n * 1e6,
            'writer_messages_per_cpu_second': n / writer_cpu if writer_cpu > 0 else 0.0,
            'writer_messages_per_second': n / wall, 'wall_time': wall}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench/results/inplant.json'))
    ap.add_argument('--quick', action='store_true', help='a smoke check: 200 samples')
    a = ap.parse_args()
    cases = {}
    for compiled in (False, True):           # side by side: the writer's two paths
        key = 'compiled' if compiled else 'interpreted'
        r = cases[key] = run(200 if a.quick else 50000, compiled=compiled)
        print(f"inplant   {key:11s} {r['messages']} messages (4 per lockstep sample): plant "
              f"side {r['producer_cpu_per_message_us']:.2f} us CPU per message (ring copy); "
              f"writer {r['writer_cpu_per_message_us']:.2f} us CPU per message (one core would "
              f"write {r['writer_messages_per_cpu_second']:.0f}/s; a 10 kHz run makes "
              f"40000/s), {r['writer_messages_per_second']:.0f} messages/s to a closed bag on "
              f"this machine now; loading the compiled path {r['writer_load_cpu_time']:.2f} s "
              'CPU once', flush=True)
    paced = {}
    for compiled in (False, True):
        key = 'compiled' if compiled else 'interpreted'
        p = paced[key] = run(100 if a.quick else 10000, rate=DEMO_RATE, compiled=compiled)
        print(f"inplant   {key:11s} paced at {DEMO_RATE:.0f} samples/s (the demo loop's "
              f"rate), {p['messages']} messages: writer {p['writer_cpu_per_message_us']:.2f} "
              'us CPU per message', flush=True)
    ratio = (cases['interpreted']['writer_cpu_per_message_us']
             / cases['compiled']['writer_cpu_per_message_us'])
    paced_ratio = (paced['interpreted']['writer_cpu_per_message_us']
                   / paced['compiled']['writer_cpu_per_message_us'])
    print(f'inplant   writer CPU per message, interpreted / compiled: {ratio:.1f} (paced '
          f'{paced_ratio:.1f})', flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({'benchmark': 'in-plant recording', 'cpus': os.cpu_count(),
                                 'load_average': os.getloadavg(), 'quick': a.quick,
                                 **cases['compiled'], 'interpreted': cases['interpreted'],
                                 'paced': paced['compiled'],
                                 'paced_interpreted': paced['interpreted'],
                                 'interpreted_over_compiled': ratio,
                                 'paced_interpreted_over_compiled': paced_ratio},
                                indent=2) + '\n')
    print(f'wrote {a.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
