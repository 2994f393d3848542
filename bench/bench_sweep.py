#!/usr/bin/env python3
"""Benchmark of a batched alpha sweep of the FOM against the serial per-point loop.

    python bench/bench_sweep.py --out bench/results/sweep.json [--quick] [--workers 2]

The sweep: 100 orders alpha = 0.6 .. 0.995 (step ~0.004) at V = 84.5 m/s, the fractional-order
model with solver 'soe' at its default step (2e-5 s), the eq. 31 state feedback in continuous
mode, 2 s per point (transient 1.5 s + window 0.5 s, every step recorded in the window).

Rows of the table (wall-clock seconds for the whole sweep):
  serial      ``fohssv_sim.simulate.simulate`` point by point in one process. Too long to run
              in full (100 x 2 s of model time): a subset of points spread over the alpha
              range is timed and the mean time per point is multiplied by the number of
              points (marked "extrapolated").
  batch-1p    ``fohssv_sim.batch.simulate_batch`` on all points in one call, one process
              (the same core count as the serial loop; each point through its compiled
              kernel, keeping the window only).
  sweep-dask  ``fohssv_sim.analysis.sweep.run_sweep`` (the production path: a
              ``simulate_batch`` per chunk, chunks on a local Dask cluster of single-threaded
              worker processes, orbit classification, CSV chunks), once per worker count in
              ``--workers`` with one chunk per worker. Includes the cluster start-up.

The SOE modes of an order are built once per process (about 10 ms per order) and reused: the
first timed row pays for them, under 1 % of a row's time. Check: the serial subset's
trajectories are compared with the same points of the batch-1p run (max deviation over the
window), and the orbit classification of the serial runs (label, number and values of the
maxima) with the sweep's rows. Exit status 1 if a check fails.

BLAS is limited to one thread per process unless the caller set the thread variables. The
machine may be shared: the load average is printed and stored.
"""

from __future__ import annotations

import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

try:
    import fohssv_sim  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'src' / 'fohssv_sim'))

from fohssv_sim.analysis.orbits import classify  # noqa: E402
from fohssv_sim.analysis.sweep import SweepSpec, run_sweep, state_scale  # noqa: E402
from fohssv_sim.batch import simulate_batch  # noqa: E402
from fohssv_sim.params import ModelParameters  # noqa: E402
from fohssv_sim.simulate import simulate  # noqa: E402

SPEED = 84.5


def settings(quick: bool) -> dict:
    if quick:
        return {'alphas': [0.8, 0.9], 'transient': 0.01, 'window': 0.01, 'serial_subset': 2}
    return {'alphas': np.linspace(0.6, 0.995, 100).tolist(), 'transient': 1.5,
            'window': 0.5, 'serial_subset': 5}


def make_controller():
    from fohssv_controller.state_feedback import StateFeedback

    return StateFeedback()


def run_serial(params: list[ModelParameters], subset: list[int], duration: float,
               transient: float) -> tuple[list[float], dict[int, tuple[np.ndarray, np.ndarray]]]:
    times, traj = [], {}
    for i in subset:
        t0 = time.perf_counter()
        r = simulate(params[i], make_controller(), duration)
        times.append(time.perf_counter() - t0)
        keep = r.t >= transient - 1e-12
        traj[i] = (r.t[keep], r.state[keep])
        print(f'  serial point {i} (alpha={params[i].fractional_order:.4f}): '
              f'{times[-1]:.2f} s', flush=True)
    return times, traj


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench/results/sweep.json'))
    ap.add_argument('--quick', action='store_true', help='smoke check: 2 points, 1 worker')
    ap.add_argument('--workers', default=f'1,{os.cpu_count() or 1}',
                    help='comma-separated Dask worker counts, one sweep row each '
                         '(default: 1 and all cores); chunk size = points / workers')
    args = ap.parse_args(argv)
    args.workers = sorted({max(1, int(w)) for w in str(args.workers).split(',')})
    if args.quick:
        args.workers = [1]
    cfg = settings(args.quick)
    alphas = cfg['alphas']
    n_pts = len(alphas)
    duration = cfg['transient'] + cfg['window']
    base = ModelParameters(model='fractional', solver='soe', speed=SPEED)
    params = [base.replace(fractional_order=a) for a in alphas]
    h = base.step
    n_steps = int(math.ceil(duration / h - 1e-9))
    subset = sorted({round(k * (n_pts - 1) / (cfg['serial_subset'] - 1))
                     for k in range(cfg['serial_subset'])})
    load0 = os.getloadavg()
    print(f'alpha sweep: {n_pts} points, alpha {alphas[0]:g}..{alphas[-1]:g}, V={SPEED} m/s, '
          f'FOM solver={base.solver}, h={h:g} s, {duration:g} s per point '
          f'({n_steps} steps); load average {load0[0]:.2f}', flush=True)

    # serial subset ---------------------------------------------------------------------------
    print(f'serial: timing {len(subset)} of {n_pts} points ...', flush=True)
    s_times, s_traj = run_serial(params, subset, duration, cfg['transient'])
    serial_total = float(np.mean(s_times)) * n_pts

    # batched in one process --------------------------------------------------------------------
    print(f'batch-1p: simulate_batch on {n_pts} points in one process ...', flush=True)
    t0 = time.perf_counter()
    b = simulate_batch(params, [make_controller()], duration, record_from=cfg['transient'])
    batch_total = time.perf_counter() - t0
    print(f'  {batch_total:.2f} s', flush=True)
    dev_state = 0.0
    for i, (t, x) in s_traj.items():
        assert np.allclose(b.t, t, rtol=0, atol=1e-12)
        scale = max(1.0, float(np.max(np.abs(x))))
        dev_state = max(dev_state, float(np.max(np.abs(b.states[i] - x))) / scale)
    del b

    # the sweep machinery on Dask -------------------------------------------------------------
    bdict = base.to_dict()
    bdict.pop('fractional_order')
    bdict.pop('speed')
    sweeps = []
    dev_max = 0.0
    labels: set[str] = set()
    label_mismatch: list[tuple] = []
    for workers in args.workers:
        chunk = math.ceil(n_pts / workers)
        spec = SweepSpec(base=bdict, alphas=tuple(alphas), speeds=(SPEED,),
                         transient=cfg['transient'], window=cfg['window'], chunk_size=chunk)
        print(f'sweep-dask: run_sweep, {workers} worker(s), chunk size {chunk} ...', flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            res = run_sweep(spec, Path(tmp) / 'sweep', workers=workers)
            wall = time.perf_counter() - t0
        n_chunks = len(res.sidecar['chunks'])
        sweeps.append((workers, chunk, n_chunks, wall))
        print(f'  {wall:.2f} s ({n_chunks} chunks)', flush=True)
        for i, (t, x) in s_traj.items():
            cls, peaks = classify(t, x[:, 1], steady_rtol=spec.steady_rtol, rel_tol=spec.rel_tol,
                                  scale=state_scale(x, 1, 1.0))
            row = res.rows[i]
            if row['label'] != cls.label or row['n_maxima'] != peaks.size:
                label_mismatch.append((workers, i, row['label'], cls.label))
            elif peaks.size:          # (a steady orbit's row holds its settled value instead)
                ref = peaks[-64:]
                dev_max = max(dev_max, float(np.max(np.abs(np.array(row['maxima']) - ref))))
        labels |= {r['label'] for r in res.rows}
    labels = sorted(labels)

    load1 = os.getloadavg()
    rows = [
        {'method': 'serial (simulate per point)', 'processes': 1, 'wall_s': serial_total,
         'per_point_s': serial_total / n_pts,
         'note': f'extrapolated from {len(subset)} measured points '
                 f'(mean {np.mean(s_times):.2f} s, min {min(s_times):.2f}, '
                 f'max {max(s_times):.2f})'},
        {'method': 'batch-1p (simulate_batch, all points)', 'processes': 1,
         'wall_s': batch_total, 'per_point_s': batch_total / n_pts, 'note': 'measured'},
    ] + [
        {'method': f'sweep-dask (run_sweep, {w} worker{"s" if w > 1 else ""})',
         'processes': w, 'wall_s': wall, 'per_point_s': wall / n_pts,
         'note': f'measured, {nc} chunk(s) of <= {ch}, incl. cluster start-up'}
        for w, ch, nc, wall in sweeps
    ]
    for r in rows:
        r['speedup_vs_serial'] = serial_total / r['wall_s']

    print()
    print(f"{'method':44s} {'proc':>4s} {'wall [s]':>10s} {'s/point':>8s} {'speed-up':>8s}  note")
    for r in rows:
        print(f"{r['method']:44s} {r['processes']:4d} {r['wall_s']:10.1f} "
              f"{r['per_point_s']:8.3f} {r['speedup_vs_serial']:7.1f}x  {r['note']}")
    print(f'check: batched vs serial states over the window, max |dx|/max(1,|x|) = '
          f'{dev_state:.2e} ({len(subset)} points); sweep rows vs classify(serial run): '
          f'{len(label_mismatch)} label/count mismatches, max |maxima dw| = {dev_max:.2e} m/s')
    print(f'labels in the sweep: {", ".join(labels)}')
    print(f'load average before/after: {load0[0]:.2f} / {load1[0]:.2f} (2-core machine may be '
          f'shared)')

    out = {
        'settings': {'n_points': n_pts, 'alpha_min': alphas[0], 'alpha_max': alphas[-1],
                     'speed': SPEED, 'model': base.model, 'solver': base.solver, 'step': h,
                     'transient': cfg['transient'], 'window': cfg['window'],
                     'steps_per_point': n_steps, 'controller': 'state_feedback (continuous)',
                     'serial_subset': subset, 'workers': args.workers, 'quick': args.quick},
        'rows': rows,
        'serial_point_times_s': dict(zip(map(str, subset), s_times)),
        'check': {'max_rel_state_deviation_batch_vs_serial': dev_state,
                  'max_abs_maxima_deviation_sweep_vs_serial': dev_max,
                  'label_mismatches_sweep_vs_serial': label_mismatch,
                  'labels': labels},
        'machine': {'python': sys.version.split()[0], 'numpy': np.__version__,
                    'platform': platform.platform(), 'cpus': os.cpu_count(),
                    'load_average_before': load0, 'load_average_after': load1,
                    'blas_threads': os.environ.get('OPENBLAS_NUM_THREADS')},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + '\n')
    print(f'wrote {args.out}')
    ok = dev_state <= 1e-10 and dev_max <= 1e-10 and not label_mismatch
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
