"""``bench/bench_ros.py``'s machine floor (:func:`case_wake`): a loop on the hosted plant's
schedule that does no work, in a process of its own, under the normal scheduler and
SCHED_FIFO: the deadline misses no code of the plant can remove, a figure of the machine
like the bare echo."""

from __future__ import annotations

import json
import subprocess
import sys

from benchutil import host_cpu_ticks, steal_share
from ros_runs import NODE_LATENCY, _rt_priority_permitted, _steal_text

from fohssv_sim.ros.pacing import BurstWait

_WAKE_LOOP = r"""
import json, math, os, sys, time, ctypes
ctypes.CDLL(None).prctl(29, 1, 0, 0, 0)            # 1 ns timer slack, as the plant asks
if sys.argv[1] == 'fifo':
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
from fohssv_sim.ros.host import hold_cpu_latency
try:       # the CPU wake-up latency limit the plant holds by default (NODE_LATENCY)
    if int(sys.argv[6]) >= 0:
        hold_cpu_latency(int(sys.argv[6]))
except OSError:
    pass
period, burst, tol, n = float(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5])
late, misses, worst, j = [], 0, 0.0, 0
c0 = time.process_time()
start = time.monotonic()
while j < n:
    # asleep until the burst's last sample is due, then every due sample "published" at once
    due = start + (j + burst - 1) * period
    time.sleep(max(0.0, due - time.monotonic()))
    now = time.monotonic()
    late.append(now - due)
    k = min(n, int((now - start) / period) + 1)
    if k <= j:
        continue
    # samples j..k-1 go out now: those due more than tol before now miss their deadline
    misses += min(k, max(j, math.ceil((now - start - tol) / period))) - j
    worst = max(worst, now - (start + j * period))
    j = k
cpu = time.process_time() - c0
late.sort()
w = len(late)
print(json.dumps({'cpu_per_wake_up_us': cpu / w * 1e6, 'late_p50_us': late[w // 2] * 1e6,
                  'late_p99_us': late[int(w * 0.99)] * 1e6,
                  'late_p999_us': late[int(w * 0.999)] * 1e6, 'wake_ups': w,
                  'samples': n, 'misses': misses, 'miss_rate': misses / n,
                  'worst_lateness': worst}))
"""


#: The schedule of the machine-floor loop: the hosted plant's at the defaults (1e-4 s samples,
#: woken once per burst of the plant's longest (5), a deadline missed when published more
#: than 1 ms after due).
FLOOR_PERIOD, FLOOR_TOLERANCE = 1e-4, 1e-3


FLOOR_BURST = BurstWait(period=FLOOR_PERIOD, tolerance=FLOOR_TOLERANCE).longest + 1


def case_wake(sim_time: float, when: str) -> dict:
    """The machine's floor: a loop with the hosted plant's schedule that computes and publishes
    nothing (woken every 0.5 ms, when a burst of 5 samples of 1e-4 s is due, its samples counted
    as published at the wake-up), for ``sim_time`` of wall time, under the normal scheduler and
    SCHED_FIFO 50, holding the CPU wake-up latency limit the plant holds
    (:data:`NODE_LATENCY`): the CPU time per wake-up, how late the wake-ups come, and the
    deadline misses a plant doing no work would have had. A hosted plant's misses are these
    plus what its own work adds. Run at the start and at the end of the benchmark (the machine
    drifts), with the hypervisor's steal over each loop."""
    out = {}
    n = round(sim_time / FLOOR_PERIOD)
    for sched in ('normal', 'fifo'):
        if sched == 'fifo' and not _rt_priority_permitted():
            continue
        before = host_cpu_ticks()
        res = subprocess.run([sys.executable, '-c', _WAKE_LOOP, sched, str(FLOOR_PERIOD),
                              str(FLOOR_BURST), str(FLOOR_TOLERANCE), str(n),
                              str(NODE_LATENCY)],
                             capture_output=True, text=True, timeout=60 + 3 * sim_time)
        if res.returncode != 0:
            print(f'floor     {sched}: failed: {res.stderr.strip()[-300:]}', flush=True)
            continue
        w = json.loads(res.stdout)
        w['host_steal_share'] = steal_share(before, host_cpu_ticks())
        out[sched] = w
        print(f"floor     {when:5s} {sched:6s} no-work loop, hosted schedule ({sim_time:g} s): "
              f"misses {w['misses']}/{w['samples']} ({100 * w['miss_rate']:.2f} %), worst "
              f"lateness {1e3 * w['worst_lateness']:.1f} ms; {w['cpu_per_wake_up_us']:.1f} us "
              f"CPU per wake-up, late by {w['late_p50_us']:.0f} / {w['late_p99_us']:.0f} / "
              f"{w['late_p999_us']:.0f} us (median / 99 % / 99.9 %)"
              + _steal_text(w['host_steal_share']), flush=True)
    return out

