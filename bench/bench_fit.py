#!/usr/bin/env python3
"""Benchmark of ``fohssv fit`` (issue 23): a one-parameter fit of a 2 s bag at h = 2e-5 s.

    python bench/bench_fit.py --out bench/results/fit.json [--quick] [--workers N]
                                [--processes-too]

The bag: the FOM at alpha = 0.81, V = 75 m/s, solver 'soe', step 2e-5 s, under the eq. 31
state feedback with a zero-order hold of 1e-4 s, 2 s from x(0) = 0 (20 000 control periods,
1e5 steps), written as the recorder writes a lockstep run
(:func:`fohssv_sim.bag.synthetic.write_simulation`). The fit: ``fohssv fit BAG --fit
fractional_order --controller state_feedback`` (closed loop: an open-loop replay of a 2 s
tail-slap run departs from the data within ~0.1 s, so the open-loop fit stops its horizon
there; see the README), default population, profile and step check, on a local Dask cluster
of ``--workers`` threads (the default; ``--processes-too`` also runs it with ``--processes``,
side by side), the installed console script timed from start to exit (cluster start-up, imports
and the numba cache load included), wall and CPU seconds (user + system of the command and its
worker processes: the figure that does not depend on what else loads the machine).

Rows, side by side in one run:
  fit          wall seconds of the whole command (target <= 60 s on 2 cores), and its CPU
               seconds (CPU / cores is the wall time on an otherwise idle machine);
  population   one batched compiled call (:func:`fohssv_sim.analysis.population.run_population`)
               of 8 points over the 2 s, in this process;
  per point    the same 8 points through the plant contract period by period
               (``run_population_reference``: make_plant + Plant.advance per control period);
               their ratio is the batched kernel's gain over the Python-driven plant.
Check: the fitted alpha within 1e-3 of 0.81 (exit 1 otherwise).
"""

from __future__ import annotations

import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))                      # benchutil
if importlib.util.find_spec('fohssv_sim') is None:   # not in the environment: the source tree
    sys.path.insert(0, str(HERE.parent / 'src' / 'fohssv_sim'))

from benchutil import finish, target  # noqa: E402

ALPHA = 0.81


def _children_cpu() -> float:
    """User + system CPU seconds of the waited-for children (and theirs) so far."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench/results/fit.json'))
    ap.add_argument('--quick', action='store_true', help='a 0.5 s bag')
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    ap.add_argument('--processes-too', action='store_true',
                    help='also time the fit with --processes (local Dask worker processes)')
    args = ap.parse_args(argv)

    from ament_index_python.packages import get_package_prefix

    from fohssv_sim.analysis.population import run_population, run_population_reference
    from fohssv_sim.bag.synthetic import write_simulation
    from fohssv_sim.control import make
    from fohssv_sim.models import AffineLaw
    from fohssv_sim.params import ModelParameters
    from fohssv_sim.simulate import simulate

    duration = 0.5 if args.quick else 2.0
    p = ModelParameters(fractional_order=ALPHA)
    ctl = make('state_feedback')
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / 'run'
        r = simulate(p, ctl, duration, control_period=1e-4, sample_every=5)
        write_simulation(bag, r, {**p.to_dict(), 'control_period': 1e-4,
                                  'duration': duration, 'initial_state': [0.0] * 4})
        law = AffineLaw.from_controller(ctl).packed
        pts = [p.replace(fractional_order=a) for a in (0.78, 0.79, 0.8, 0.805, 0.81, 0.815,
                                                        0.82, 0.83)]
        n = round(duration / 1e-4)
        run_population(pts[:1], 10, 5, law=law)                    # compile / load the cache
        t0 = time.perf_counter()
        run_population(pts, n, 5, law=law, duration=duration)
        batched = time.perf_counter() - t0
        t0 = time.perf_counter()
        run_population_reference(pts, n, 5, law=law, duration=duration)
        serial = time.perf_counter() - t0

        exe = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'
        runs = {}
        for kind in ('threads', 'processes') if args.processes_too else ('threads',):
            out = Path(tmp) / f'fit-{kind}'
            c0 = _children_cpu()
            t0 = time.perf_counter()
            cmd = subprocess.run([str(exe), 'fit', str(bag), '--fit', 'fractional_order',
                                  '--controller', 'state_feedback', '--workers',
                                  str(args.workers), '--out', str(out)]
                                 + (['--processes'] if kind == 'processes' else []),
                                 capture_output=True, text=True)
            runs[kind] = (time.perf_counter() - t0, _children_cpu() - c0)
            print(cmd.stdout[-2500:])
            if cmd.returncode != 0:
                print(cmd.stderr[-3000:], file=sys.stderr)
                return 1
            if kind == 'threads':
                d = json.loads((out / 'fit.json').read_text())
        wall, cpu = runs['threads']
    alpha = d['values']['fractional_order']
    res = {'machine': platform.machine(), 'cpus': os.cpu_count(), 'workers': args.workers,
           'load_avg_start': load0, 'duration': duration, 'step': p.step,
           'fit_wall_s': wall, 'fit_cpu_s': cpu, 'alpha': alpha,
           'fit_processes_wall_s': runs.get('processes', (None, None))[0],
           'fit_processes_cpu_s': runs.get('processes', (None, None))[1],
           'interval': d['intervals']['fractional_order'],
           'residual': d['residual'], 'stages': d['stages'],
           'population_8_points_s': batched, 'per_point_8_points_s': serial,
           'batched_speedup': serial / batched, 'targets': []}
    print(f'fit of a {duration:g} s bag (1 parameter, h = {p.step:g} s, {args.workers} worker '
          f'threads): {wall:.1f} s wall, {cpu:.1f} s CPU (load {load0[0]:.1f} at the start); '
          f'alpha = {alpha:.6g} {d["intervals"]["fractional_order"]}')
    if 'processes' in runs:
        pw, pc = runs['processes']
        print(f'the same with --processes: {pw:.1f} s wall, {pc:.1f} s CPU '
              f'(threads / processes CPU: {cpu / pc:.2f})')
    print(f'8 points over {duration:g} s: batched {batched:.2f} s, per point through the plant '
          f'{serial:.2f} s (x{serial / batched:.1f})')
    target(res['targets'], f'one-parameter fit of a {duration:g} s bag, wall s', wall, '<=',
           60.0)
    target(res['targets'], f'the same, CPU s / {os.cpu_count()} cores (idle-machine wall)',
           cpu / (os.cpu_count() or 1), '<=', 60.0)
    target(res['targets'], 'batched population vs per-point plant (speed-up)',
           serial / batched, '>=', 1.0)
    finish(res, 'Targets of issue #23 (from this run)', args.out, width=48)
    return 0 if abs(alpha - ALPHA) <= 1e-3 else 1


if __name__ == '__main__':
    sys.exit(main())
