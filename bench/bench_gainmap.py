#!/usr/bin/env python3
"""Benchmark of a 32 x 32 gain map (issue 15): the Dask map against the per-point loop.

    python bench/bench_gainmap.py --out bench/results/gainmap.json [--quick] [--workers N]

The map: the eq. 31 state feedback (``state_feedback``), pitch_rate_gain in [-1.2, 0] x
vertical_velocity_gain in [-0.2, 0.3] (32 x 32 = 1024 pairs, the other gains as in eq. 31),
the FOM at alpha = 0.85, V = 75 m/s, solver 'soe' at the converged default step 2e-5 s, a
zero-order hold of 1e-4 s (the plant's default control period), 2 s per pair from x(0) = 0
(transient 1.5 s, classification window 0.5 s).

Rows (wall-clock seconds, side by side in one run):
  per-point   :func:`fohssv_sim.analysis.gainmap.run_points` with ``batched=False`` (one
              ``simulate()`` per pair, compiled kernels, plus the same equilibrium search and
              metrics) in this process, on a subset of pairs spread over the map; the mean
              time per pair times 1024 (marked "extrapolated").
  gainmap     :func:`fohssv_sim.analysis.gainmap.run_gain_map`, the production path: chunks of
              1024 / workers pairs on a local Dask cluster of ``--workers`` single-threaded
              processes (default: all cores), incl. cluster start-up, equilibria and alpha_c
              of every pair, CSV chunks.

Both rows run the same compiled kernel per pair (``simulate_batch`` with a compiled solver
runs each point through ``simulate()``), so the map gains only by spreading the pairs over
its workers: its wall-time speed-up cannot exceed their number and is printed, not a target.
The target is the map's per-core figure: per-point seconds per pair in one process / (map
wall x workers / pairs), 1 when the cluster costs nothing; >= 0.75 bounds what Dask
(start-up, scheduling, chunk files) loses per core. Check: the subset's per-point rows equal
the map's rows (outcome, label, settle time, alpha_c exactly; metrics to 1e-9 relative).
The map's figures go to ``<out>`` without suffix + ``_map/`` (the README's worked result).
Exit 1 if the check fails.
"""

from __future__ import annotations

import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))                      # benchutil
if importlib.util.find_spec('fohssv_sim') is None:   # not in the environment: the source tree
    sys.path.insert(0, str(HERE.parent / 'src' / 'fohssv_sim'))

from benchutil import finish, target  # noqa: E402

from fohssv_sim.analysis import gainmap as gm  # noqa: E402


def settings(quick: bool) -> dict:
    if quick:
        return {'n': 2, 'duration': 0.02, 'transient': 0.01, 'subset': 2}
    return {'n': 32, 'duration': 2.0, 'transient': 1.5, 'subset': 6}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench/results/gainmap.json'))
    ap.add_argument('--quick', action='store_true', help='a smoke check: 2 x 2 pairs, 0.02 s each')
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    args = ap.parse_args(argv)
    cfg = settings(args.quick)
    n = cfg['n']
    workers = 1 if args.quick else max(1, args.workers)
    spec = gm.GainMapSpec(
        controller='state_feedback', gain_x='pitch_rate_gain',
        x_values=tuple(np.linspace(-1.2, 0.0, n).round(12).tolist()),
        gain_y='vertical_velocity_gain',
        y_values=tuple(np.linspace(-0.2, 0.3, n).round(12).tolist()),
        alpha=0.85, speed=75.0, duration=cfg['duration'], transient=cfg['transient'],
        control_period=1e-4, chunk_size=math.ceil(n * n / workers))
    spec.validate()
    p0 = spec.params_for(spec.alpha, spec.speed)
    n_pts = spec.n_points
    load0 = os.getloadavg()
    print(f'gain map: {n} x {n} = {n_pts} pairs of (pitch_rate_gain, vertical_velocity_gain), '
          f'FOM alpha = 0.85, V = 75 m/s, solver {p0.solver}, step {p0.step:g} s, ZOH 1e-4 s, '
          f"{cfg['duration']:g} s per pair; load average {load0[0]:.2f}", flush=True)

    subset = sorted({round(k * (n_pts - 1) / (cfg['subset'] - 1)) for k in range(cfg['subset'])})
    print(f'per-point: timing {len(subset)} of {n_pts} pairs ...', flush=True)
    gm.run_points(spec.to_dict(), [0], batched=False)     # compile/warm up, not timed
    times, ref = [], {}
    for i in subset:
        t0 = time.perf_counter()
        (row,) = gm.run_points(spec.to_dict(), [i], batched=False)
        times.append(time.perf_counter() - t0)
        ref[i] = row
        print(f"  pair {i} ({row['x']:g}, {row['y']:g}): {times[-1]:.2f} s, {row['label']}",
              flush=True)
    per_point_total = float(np.mean(times)) * n_pts

    out_dir = args.out.parent / (args.out.stem + '_map')
    shutil.rmtree(out_dir, ignore_errors=True)
    print(f'gainmap: run_gain_map, {workers} worker(s), chunks of {spec.chunk_size} ...',
          flush=True)
    last = [0.0]

    def progress(done: int, total: int, elapsed: float) -> None:
        if elapsed - last[0] >= 10 or done == total:
            last[0] = elapsed
            print(f'  {done}/{total} pairs, {elapsed:.0f} s', flush=True)

    t0 = time.perf_counter()
    res = gm.run_gain_map(spec, out_dir, workers=workers, progress=progress)
    wall = time.perf_counter() - t0
    print(f'  {wall:.1f} s', flush=True)
    for line in gm.summary_lines(res):
        print(line)
    figures = gm.plot_gain_map(res, out_dir / 'gainmap')
    print(f"figures: {', '.join(str(p) for p in figures if p.suffix == '.png')}")

    mismatch, dev = [], 0.0
    for i, r in ref.items():
        row = res.rows[i]
        for k in ('outcome', 'label', 'settle_time', 'alpha_c'):
            if repr(row[k]) != repr(r[k]):
                mismatch.append((i, k, row[k], r[k]))
        for k in ('peak_fp', 'effort_rms', 'amplitude'):
            if math.isfinite(r[k]):
                dev = max(dev, abs(row[k] - r[k]) / max(abs(r[k]), 1e-300))
    load1 = os.getloadavg()
    speedup = per_point_total / wall
    per_core = (per_point_total / n_pts) / (wall * workers / n_pts)
    print(f'\n{"method":40s} {"proc":>4s} {"wall [s]":>9s} {"s/pair":>8s}  note')
    print(f'{"per-point (simulate per pair)":40s} {1:4d} {per_point_total:9.1f} '
          f'{per_point_total / n_pts:8.3f}  extrapolated from {len(subset)} pairs '
          f'(mean {np.mean(times):.2f} s)')
    print(f'{"gainmap (Dask map)":40s} {workers:4d} {wall:9.1f} {wall / n_pts:8.3f}  '
          f'measured, incl. cluster start-up and alpha_c')
    print(f'map vs per-point: {speedup:.2f}x wall on {workers} worker(s), {per_core:.2f} per '
          f'core (1 = nothing lost to Dask)')
    print(f'check: {len(mismatch)} mismatches, max relative metric deviation {dev:.1e}')
    print(f'load average before/after: {load0[0]:.2f} / {load1[0]:.2f}')

    res_json = {
        'settings': {'pairs': n_pts, 'grid': [n, n], 'duration': cfg['duration'],
                     'transient': cfg['transient'], 'step': p0.step, 'solver': p0.solver,
                     'control_period': 1e-4, 'alpha': 0.85, 'speed': 75.0,
                     'workers': workers, 'chunk_size': spec.chunk_size, 'quick': args.quick,
                     'subset': subset},
        'rows': [{'method': 'per-point', 'processes': 1, 'wall_s': per_point_total,
                  'note': f'extrapolated from {len(subset)} pairs'},
                 {'method': 'gainmap', 'processes': workers, 'wall_s': wall,
                  'note': 'measured'}],
        'per_point_times_s': dict(zip(map(str, subset), times)),
        'speedup_wall': speedup, 'per_core_ratio': per_core,
        'summary': gm.summary_lines(res),
        'check': {'mismatches': mismatch, 'max_rel_metric_deviation': dev},
        'machine': {'python': sys.version.split()[0], 'numpy': np.__version__,
                    'platform': platform.platform(), 'cpus': os.cpu_count(),
                    'load_average_before': load0},
        'targets': [],
    }
    target(res_json['targets'], f'{n}x{n} map, {cfg["duration"]:g} s each, wall s', wall, '<=',
           600.0)
    target(res_json['targets'], 'map per core: per-point s/pair / (wall x workers / pairs)',
           per_core, '>=', 0.75)
    finish(res_json, 'Targets of issue #15 (from this run)', args.out)
    return 0 if not mismatch and dev <= 1e-9 else 1


if __name__ == '__main__':
    sys.exit(main())
