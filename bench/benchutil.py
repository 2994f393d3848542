"""Shared ending of the benchmarks: the targets table, the load average, the JSON file.

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
