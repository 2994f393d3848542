#!/usr/bin/env python3
"""Benchmark of ``fohssv fit`` (issues 23, 49): a one-parameter fit of a 2 s bag with 1 %
noise at h = 2e-5 s, and the table of fits of noisy independent data over seeds.

    python bench/bench_fit.py --out bench/results/fit.json [--quick] [--workers N]
                                [--processes-too] [--noise-table [--seeds 10] [--open-loop]]

The bag: the FOM at alpha = 0.81, V = 75 m/s, solver 'soe', step 2e-5 s, under the eq. 31
state feedback with a zero-order hold of 1e-4 s, 2 s from x(0) = 0 (20 000 control periods,
1e5 steps), Gaussian noise of 1 % of each state's standard deviation added to the states after
t = 0 (seed 1), written as the recorder writes a lockstep run
(:func:`fohssv_sim.bag.synthetic.write_simulation`). The fit: ``fohssv fit BAG --fit
fractional_order --controller state_feedback`` (closed loop: without the controller the fit
replays the recorded commands through the model's Kalman filter, docs/fit.md), default
population, profile and step check, on a local Dask cluster
of ``--workers`` threads (the default; ``--processes-too`` also runs it with ``--processes``,
side by side), the installed console script timed from start to exit (cluster start-up, imports
and the numba cache load included), wall and CPU seconds (user + system of the command and its
worker processes: the figure that does not depend on what else loads the machine).

Rows, side by side in one run:
  fit          wall seconds of the whole command (target <= 60 s on 2 cores), and its CPU
               seconds (CPU / cores is the wall time on an otherwise idle machine);
  open loop    the same fit without ``--controller``: the recorded commands replayed through
               the model's Kalman filter (target <= 60 s);
  population   one batched compiled call (:func:`fohssv_sim.analysis.population.run_population`)
               of 8 points over the 2 s, in this process;
  per point    the same 8 points through the plant contract period by period
               (``run_population_reference``: make_plant + Plant.advance per control period);
               their ratio is the batched kernel's gain over the Python-driven plant.
Check, for both fits: the fitted alpha within 1e-3 of 0.81, its interval holding it, the run
reproduced (exit 1 otherwise).

``--noise-table``: issue 49's statistics. Independent data: the FOM's closed loop (alpha =
0.81, eq. 31, 0.2 s) by the exact predictor-corrector 'abm' at half the fit's step, the bag's
metadata saying alpha = 0.85 (the truth withheld); per noise level (1, 5, 10 % of each state's
standard deviation) and measured set (all four states; z and theta only) ``--seeds`` seeds of
noise; each fitted in this process (closed loop, defaults, step check; with ``--open-loop``
the recorded commands replayed instead: the prediction errors of the model's Kalman filter).
Printed: per row, in how many seeds the interval holds 0.81 and the run is reproduced (the
issue asks >= 9 of 10), the noise estimated against the generator's, the median and spread
of alpha, and the CPU seconds per fit.
"""

from __future__ import annotations

import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
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


def noise_table(seeds: int, open_loop: bool = False, levels=(0.01, 0.05, 0.10),
                measured_sets=((0, 1, 2, 3), (0, 2))) -> int:
    """The table of ``--noise-table`` (see the module docstring), closed loop or
    ``open_loop``; exit 1 when a row falls below 9 of 10 (scaled to ``seeds``)."""
    import copy

    import numpy as np

    from fohssv_sim.analysis.fit import (
        FitSpec,
        base_from_run,
        data_from_run,
        resolve_bounds,
        run_fit,
    )
    from fohssv_sim.bag import load_run
    from fohssv_sim.bag.synthetic import write_simulation
    from fohssv_sim.control import make
    from fohssv_sim.params import ModelParameters
    from fohssv_sim.simulate import simulate

    nominal = ModelParameters(fractional_order=0.85)
    truth = ModelParameters(fractional_order=ALPHA, solver='abm', step=nominal.step / 2)
    t0 = time.process_time()
    clean = simulate(truth, make('state_feedback'), 0.2, control_period=1e-4,
                     sample_every=round(1e-4 / truth.step))
    print(f'independent data: abm at h = {truth.step:g} s, 0.2 s, in '
          f'{time.process_time() - t0:.1f} s CPU', flush=True)
    std = clean.state.std(axis=0)
    ok_all = True
    with tempfile.TemporaryDirectory() as tmp:
        for level in levels:
            for measured in measured_sets:
                covered = reproduced = 0
                ratios, cpu, alphas = [], [], []
                for seed in range(seeds):
                    rng = np.random.default_rng(1000 + seed)
                    r = copy.copy(clean)
                    x = np.array(clean.state)
                    x[1:] += level * std * rng.standard_normal(x[1:].shape)
                    for j in set(range(4)) - set(measured):
                        x[1:, j] = rng.uniform(-1e3, 1e3, x.shape[0] - 1)  # not measured
                    r.state = x
                    bag = Path(tmp) / f'run_{level}_{len(measured)}_{seed}'
                    write_simulation(bag, r, {**nominal.to_dict(), 'control_period': 1e-4,
                                              'duration': 0.2, 'initial_state': [0.0] * 4})
                    run = load_run(bag)
                    base = base_from_run(run)
                    names = ('fractional_order',)
                    spec = FitSpec(names=names, bounds=resolve_bounds(names, {}, base),
                                   base=base.to_dict(),
                                   controller=None if open_loop else 'state_feedback',
                                   weights=tuple(float(j in measured) for j in range(4)))
                    c0 = time.process_time()
                    res = run_fit(spec, data_from_run(run, base), bag.with_suffix('.out'))
                    cpu.append(time.process_time() - c0)
                    lo, hi = res.intervals['fractional_order']
                    alphas.append(res.values['fractional_order'])
                    covered += lo <= ALPHA <= hi
                    reproduced += res.reproduces
                    print(f'  seed {seed}: alpha {alphas[-1]:.5f} [{lo:.5f}, {hi:.5f}], '
                          f'reproduced {res.reproduces}, {cpu[-1]:.1f} s CPU', flush=True)
                    sig = np.array(res.settings['noise']['sigma'])
                    ratios.append(float(np.mean([sig[j] / (level * std[j]) for j in measured])))
                need = math.ceil(0.9 * seeds)
                ok_all &= covered >= need and reproduced >= need
                states = 'z, w, theta, q' if len(measured) == 4 else 'z, theta'
                q = np.percentile(alphas, [0, 50, 100])
                print(f'noise {level:.0%} on {states}: alpha in its interval {covered}/{seeds}, '
                      f'reproduced {reproduced}/{seeds}; alpha median {q[1]:.4f} (min '
                      f'{q[0]:.4f}, max {q[2]:.4f}); estimated / true noise '
                      f'{np.mean(ratios):.3f}; {np.mean(cpu):.1f} s CPU per fit', flush=True)
    return 0 if ok_all else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench/results/fit.json'))
    ap.add_argument('--quick', action='store_true', help='a 0.5 s bag')
    ap.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    ap.add_argument('--processes-too', action='store_true',
                    help='also time the fit with --processes (local Dask worker processes)')
    ap.add_argument('--noise-table', action='store_true',
                    help="issue 49's table of noisy independent data over seeds, only")
    ap.add_argument('--seeds', type=int, default=10, help='seeds per row of --noise-table')
    ap.add_argument('--open-loop', action='store_true',
                    help='--noise-table: fit open loop (the recorded commands replayed)')
    ap.add_argument('--levels', default='1,5,10',
                    help='--noise-table: the noise levels, %% of each state\'s standard deviation')
    ap.add_argument('--measured', choices=('both', 'all', 'z,theta'), default='both',
                    help='--noise-table: the measured sets (all states, z and theta, or both)')
    args = ap.parse_args(argv)
    if args.noise_table:
        sets = {'both': ((0, 1, 2, 3), (0, 2)), 'all': ((0, 1, 2, 3),),
                'z,theta': ((0, 2),)}[args.measured]
        levels = tuple(float(v) / 100 for v in args.levels.split(','))
        return noise_table(args.seeds, args.open_loop, levels, sets)

    import numpy as np
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
        rng = np.random.default_rng(1)
        r.state = np.array(r.state)
        r.state[1:] += 0.01 * r.state.std(axis=0) * rng.standard_normal(r.state[1:].shape)
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
        kinds = ('threads', 'open') + (('processes',) if args.processes_too else ())
        for kind in kinds:
            out = Path(tmp) / f'fit-{kind}'
            c0 = _children_cpu()
            t0 = time.perf_counter()
            loop = [] if kind == 'open' else ['--controller', 'state_feedback']
            cmd = subprocess.run([str(exe), 'fit', str(bag), '--fit', 'fractional_order',
                                  *loop, '--workers', str(args.workers), '--out', str(out)]
                                 + (['--processes'] if kind == 'processes' else []),
                                 capture_output=True, text=True)
            runs[kind] = (time.perf_counter() - t0, _children_cpu() - c0)
            print(cmd.stdout[-2500:])
            if cmd.returncode != 0:
                print(cmd.stderr[-3000:], file=sys.stderr)
                return 1
            if kind == 'threads':
                d = json.loads((out / 'fit.json').read_text())
            if kind == 'open':
                d_open = json.loads((out / 'fit.json').read_text())
        wall, cpu = runs['threads']
        open_wall, open_cpu = runs['open']
    alpha = d['values']['fractional_order']
    res = {'machine': platform.machine(), 'cpus': os.cpu_count(), 'workers': args.workers,
           'load_avg_start': load0, 'duration': duration, 'step': p.step,
           'fit_wall_s': wall, 'fit_cpu_s': cpu, 'alpha': alpha,
           'fit_open_loop_wall_s': open_wall, 'fit_open_loop_cpu_s': open_cpu,
           'open_loop_alpha': d_open['values']['fractional_order'],
           'open_loop_interval': d_open['intervals']['fractional_order'],
           'fit_processes_wall_s': runs.get('processes', (None, None))[0],
           'fit_processes_cpu_s': runs.get('processes', (None, None))[1],
           'interval': d['intervals']['fractional_order'],
           'residual': d['residual'], 'stages': d['stages'],
           'population_8_points_s': batched, 'per_point_8_points_s': serial,
           'batched_speedup': serial / batched, 'targets': []}
    print(f'fit of a {duration:g} s bag (1 parameter, h = {p.step:g} s, {args.workers} worker '
          f'threads): {wall:.1f} s wall, {cpu:.1f} s CPU (load {load0[0]:.1f} at the start); '
          f'alpha = {alpha:.6g} {d["intervals"]["fractional_order"]}')
    print(f'the same open loop (the recorded commands, the Kalman filter\'s prediction '
          f'errors): {open_wall:.1f} s wall, {open_cpu:.1f} s CPU; alpha = '
          f"{d_open['values']['fractional_order']:.6g} {d_open['intervals']['fractional_order']}")
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
    target(res['targets'], 'the same open loop (Kalman filter), wall s', open_wall, '<=',
           60.0)
    target(res['targets'], 'batched population vs per-point plant (speed-up)',
           serial / batched, '>=', 1.0)
    finish(res, 'Targets of issue #23 (from this run)', args.out, width=48)
    ok = all(abs(r['values']['fractional_order'] - ALPHA) <= 1e-3 and r['reproduces']
             and r['intervals']['fractional_order'][0] <= ALPHA
             <= r['intervals']['fractional_order'][1] for r in (d, d_open))
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
