"""Shared parts of the benchmarks: the targets table, the load average, the JSON file, and
the host around a run (the hypervisor's steal, the kernel's preemption model), read here
rather than by the product.

Not a benchmark itself (scripts/bench.py runs ``bench_*.py`` only).
"""

from __future__ import annotations

import json
import os
from pathlib import Path


def target(rows: list[dict], name: str, measured, op: str, goal: float) -> None:
    """Append one target row (skipped when ``measured`` is None: not run this time)."""
    if measured is None:
        return
    met = measured <= goal if op == '<=' else measured >= goal
    rows.append({'name': name, 'measured': float(measured), 'op': op, 'goal': goal,
                 'met': bool(met)})


def finish(res: dict, title: str, out: Path | None, width: int = 62) -> int:
    """Print ``res['targets']`` under ``title`` and the load average; write ``res`` as JSON to
    ``out`` (when given). Returns 0 (the exit code: missed targets are figures, not errors)."""
    print(f'\n{title}')
    print(f"{'target':<{width}} {'measured':>10} {'goal':>10}  met")
    for row in res['targets']:
        print(f"{row['name']:<{width}} {row['measured']:>10.3g} {row['op']}{row['goal']:>8g}  "
              f"{'yes' if row['met'] else 'NO'}")
    res['load_avg_end'] = os.getloadavg()
    print(f"load avg at end {os.getloadavg()[0]:.2f}")
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=2))
        print(f"wrote {out}")
    return 0


# -- the host around a run: the hypervisor's steal and the kernel's preemption model ----------

def host_cpu_ticks(stat: str = '/proc/stat') -> tuple[int, int] | None:
    """(all ticks, steal ticks) of the machine's CPUs since boot, from ``stat`` (Linux's
    /proc/stat ``cpu`` line); None where unavailable. Steal is time the hypervisor ran
    something else while this virtual machine had work: a vCPU stalled for milliseconds, which
    no scheduling inside the guest (SCHED_FIFO included) avoids."""
    try:
        with open(stat, encoding='ascii') as f:
            fields = f.readline().split()
        if fields[0] != 'cpu':
            return None
        # user nice system idle iowait irq softirq steal (guest time is inside user)
        ticks = [int(v) for v in fields[1:9]]
    except (OSError, ValueError, IndexError):
        return None
    if len(ticks) < 8:
        return None
    return sum(ticks), ticks[7]


def steal_share(before: tuple[int, int] | None, after: tuple[int, int] | None
                ) -> float | None:
    """The share of all CPU time stolen by the hypervisor between two :func:`host_cpu_ticks`
    readings (None when either is missing or no tick passed)."""
    if before is None or after is None or after[0] <= before[0]:
        return None
    return (after[1] - before[1]) / (after[0] - before[0])


def steal_seconds(before: tuple[int, int] | None, after: tuple[int, int] | None
                  ) -> float | None:
    """The CPU time (s, all CPUs) stolen between two :func:`host_cpu_ticks` readings (None
    when either is missing), to a tick (1 / ``SC_CLK_TCK`` s)."""
    if before is None or after is None:
        return None
    return (after[1] - before[1]) / os.sysconf('SC_CLK_TCK')
