#!/usr/bin/env python3
"""Benchmark: a branch of periodic orbits by continuation beside the brute-force orbit
diagram (``run_sweep``) over the same grid.

    python bench/bench_continuation.py [--quick] [--branch-only] [--workers 2] [--out FILE.json]

Three cases, each timed both ways (wall-clock seconds; the branch's CPU seconds too):
  delay-free over V  ``follow_orbits`` (compiled shooting) over V = 60 .. 120 m/s, about 50
                     points, against ``run_sweep`` of the delay-free model on a 50-value V
                     grid (target: the branch in at most 30 s).
  FOM over alpha     ``follow_orbits`` (harmonic balance, 32 harmonics, with its stability
                     simulations) over alpha = 0.7 .. 1 at V = 75 m/s, against ``run_sweep``
                     of the FOM on a 50-value alpha grid (target: at most 60 s).
  delayed over V     ``follow_orbits`` (harmonic balance of the DDE, 16 harmonics, the
                     monodromy operator's multipliers at every point) over V = 60 .. 120 m/s,
                     against ``run_sweep`` of the delayed model.

``--branch-only`` skips the sweeps (the branch times alone, a cheap check).

The sweeps use their defaults (transient 1.5 s, window 0.5 s). ``--quick`` runs 10 points
and a 10-value grid (a smoke run, not a figure). The ratio sweep / branch is the figure; a
branch gives unstable orbits and bifurcation points a sweep cannot. BLAS is limited to one
thread per process unless the caller set the thread variables; the load average is printed
(the machine may be shared).
"""

from __future__ import annotations

import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

try:
    import fohssv_sim  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'src' / 'fohssv_sim'))

from benchutil import finish, target  # noqa: E402

from fohssv_sim.analysis.sweep import SweepSpec, run_sweep  # noqa: E402
from fohssv_sim.continuation.run import follow_orbits  # noqa: E402
from fohssv_sim.control import make  # noqa: E402
from fohssv_sim.params import ModelParameters  # noqa: E402

CASES = (
    # name, model parameters, varied, start, end, harmonics
    ('delay-free over V', {'model': 'delay-free'}, 'speed', 60.0, 120.0, 16),
    ('FOM over alpha', {'model': 'fractional', 'speed': 75.0}, 'fractional_order', 0.7, 1.0,
     32),
    ('delayed over V', {'model': 'delayed'}, 'speed', 60.0, 120.0, 16),
)


def time_branch(params: ModelParameters, name: str, start: float, end: float, points: int,
                harmonics: int) -> tuple[float, float, int, list]:
    t0, c0 = time.perf_counter(), time.process_time()
    b = follow_orbits(params, make('state_feedback'), name, start, end, points=points,
                      harmonics=harmonics)
    return (time.perf_counter() - t0, time.process_time() - c0, len(b.points),
            b.bifurcations)


def time_sweep(params: ModelParameters, name: str, start: float, end: float, n: int,
               workers: int) -> float:
    grid = tuple(float(v) for v in np.linspace(start, end, n))
    base = params.to_dict()
    alphas = grid if name == 'fractional_order' else (base['fractional_order'],)
    speeds = grid if name == 'speed' else (base['speed'],)
    base.pop('fractional_order')
    base.pop('speed')
    spec = SweepSpec(base=base, alphas=alphas, speeds=speeds,
                     chunk_size=max(1, -(-n // workers)))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        run_sweep(spec, Path(tmp) / 'sweep', workers=workers)
        return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--quick', action='store_true', help='10 points (smoke run)')
    ap.add_argument('--branch-only', action='store_true', help='time the branches only')
    ap.add_argument('--workers', type=int, default=2, help='Dask workers of the sweep')
    ap.add_argument('--out', type=Path, help='write the table as JSON here')
    args = ap.parse_args(argv)
    n = 10 if args.quick else 50
    rows = []
    for label, values, name, start, end, harmonics in CASES:
        params = ModelParameters(**values)
        print(f'{label}: branch ({n} points) ...', flush=True)
        tb, cpu, count, bifs = time_branch(params, name, start, end, n, harmonics)
        print(f'  {tb:.1f} s ({cpu:.1f} CPU s), {count} points, bifurcations: '
              + (', '.join(f"{b['kind']} {b['value']:.5g}" for b in bifs) or 'none'),
              flush=True)
        ts = math.nan
        if not args.branch_only:
            print(f'{label}: sweep ({n} values, {args.workers} workers) ...', flush=True)
            ts = time_sweep(params, name, start, end, n, args.workers)
            print(f'  {ts:.1f} s', flush=True)
        rows.append({'case': label, 'branch_s': tb, 'branch_cpu_s': cpu,
                     'branch_points': count, 'sweep_s': ts, 'sweep_values': n,
                     'ratio_sweep_over_branch': ts / tb})
    load = os.getloadavg()[0]
    print(f"\n{'case':<20}{'branch (s)':>12}{'points':>8}{'sweep (s)':>12}{'ratio':>8}")
    for r in rows:
        print(f"{r['case']:<20}{r['branch_s']:>12.1f}{r['branch_points']:>8}"
              f"{r['sweep_s']:>12.1f}{r['ratio_sweep_over_branch']:>8.2f}")
    print(f'load average (1 min): {load:.2f}')
    res = {'targets': [], 'load1': load,
           'rows': [{k: (None if isinstance(v, float) and math.isnan(v) else v)
                     for k, v in r.items()} for r in rows]}
    # the branch runs in one thread: its CPU seconds are its wall time on an idle machine
    for r, goal in zip(rows, (30.0, 60.0)):
        if not args.quick:
            target(res['targets'], f"{r['case']}: branch CPU s (idle-machine wall)",
                   r['branch_cpu_s'], '<=', goal)
    return finish(res, 'bench_continuation targets', args.out)


if __name__ == '__main__':
    sys.exit(main())
