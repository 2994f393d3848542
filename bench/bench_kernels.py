#!/usr/bin/env python3
"""Benchmark of the compiled stepping kernels (fohssv_sim.kernels), side by side in one run.

    python bench/bench_kernels.py --out bench/results/kernels.json [--quick]

Measures
  1. cost per integration step, compiled against interpreted, same model and step, as the
     plant uses them: one call per control period of 1e-4 s (RK4 at 1e-5 s: 10 steps; FOM
     'soe' at 2e-5 s: 5 steps) with the command held, on the eq. 31 closed loop (the command
     computed between calls, untimed, so the state stays on the limit cycle: an open loop
     diverges into subnormal arithmetic, which would time the FPU, not the code; each call is
     timed on its own, which counts the timer against the compiled side); rounds interleaved,
     medians reported;
  2. the FOM's cost per step with the default online solver at step n = 1e3, 1e6 and 1e7
     (a plant stepped for real to each n, eq. 31 closed loop, 1000-step windows timed);
  3. accuracy of the default solver: the compiled 'soe' FOM closed loop (2 s, eq. 31
     continuous) against the exact ABM answer (solve_abm_fft);
  4. a 10-minute simulated FOM run with the batch runner (simulate, default solver): wall time
     per simulated second over the first and the last 1 % of the run.

The machine may be shared: the load average is printed and stored with the results.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
from benchutil import finish, target

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim import kernels
from fohssv_sim.fractional import solve_abm_fft
from fohssv_sim.models import AffineLaw, FractionalModel, make_plant, warm_up
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

PERIOD = 1e-4
X_START = (0.0, 0.5, 0.0, 0.0)


def settled_plant(model: str, engine: str):
    """A plant of ``model`` 0.05 s into the eq. 31 closed loop (planing active)."""
    plant = make_plant(ModelParameters(model=model), X_START, engine=engine)
    plant.advance(AffineLaw.from_controller(StateFeedback()), round(0.05 / plant.h))
    return plant


def time_periods(plant, law, hold: int, calls: int) -> float:
    """Seconds per integration step over ``calls`` control periods of ``hold`` steps, the
    command held over each and computed from the state before it (not timed)."""
    clock = time.perf_counter
    spent = 0.0
    for _ in range(calls):
        u = law(plant.t, plant.x)
        start = clock()
        plant.advance(u, hold)
        spent += clock() - start
    return spent / (calls * hold)


def per_step_costs(rounds: int) -> dict:
    """1. compiled vs interpreted, interleaved rounds."""
    u = StateFeedback().command
    out = {}
    for model in ('delay-free', 'delayed', 'fractional'):
        fast = settled_plant(model, 'compiled')
        slow = settled_plant(model, 'python')
        hold = round(PERIOD / fast.h)
        c_us, i_us = [], []
        for _ in range(rounds):
            i_us.append(time_periods(slow, u, hold, 40) * 1e6)
            c_us.append(time_periods(fast, u, hold, 4000) * 1e6)
        law = AffineLaw.from_controller(StateFeedback())   # eq. 31 inside the kernel
        start = time.perf_counter()
        for _ in range(20):
            fast.advance(law, 10_000)
        long_call = (time.perf_counter() - start) / 200_000 * 1e6
        out[model] = {'step': fast.h, 'steps_per_call': hold,
                      'compiled_us': statistics.median(c_us),
                      'interpreted_us': statistics.median(i_us),
                      'compiled_us_rounds': c_us, 'interpreted_us_rounds': i_us,
                      'compiled_us_in_10000_step_calls': long_call}
        out[model]['speedup'] = out[model]['interpreted_us'] / out[model]['compiled_us']
    return out


def cost_at_depth(levels: list[int], window: int = 1000, rounds: int = 5) -> dict:
    """2. FOM per-step cost at step n (default solver, open-ended horizon)."""
    plant = make_plant(ModelParameters(), X_START)
    law = AffineLaw.from_controller(StateFeedback())
    hold = round(PERIOD / plant.h)
    costs = {}
    for n in levels:
        plant.advance(law, n - plant.n)        # run for real up to n
        samples = []
        for _ in range(rounds):
            t0 = time.perf_counter()
            for _ in range(window // hold):
                plant.advance(law, hold)
            samples.append((time.perf_counter() - t0) / window * 1e6)
        costs[n] = statistics.median(samples)
    return {'n': levels, 'us_per_step': [costs[n] for n in levels],
            'solver': plant.params.solver, 'horizon_steps': plant.horizon_steps,
            'ratio_last_over_1e3': costs[levels[-1]] / costs[levels[0]]}


def soe_accuracy(duration: float) -> dict:
    """3. default (compiled soe) vs the exact ABM (FFT), eq. 31 continuous."""
    p = ModelParameters()
    law = StateFeedback().command
    t0 = time.perf_counter()
    sol = solve_abm_fft(FractionalModel(p, engine='python').rhs, p.fractional_order, p.step,
                        np.zeros(4), round(duration / p.step),
                        u=lambda t, x: np.array(law(t, x)))
    exact_wall = time.perf_counter() - t0
    r = simulate(p, StateFeedback(), duration)
    rel = float(np.abs(r.state - sol.x).max() / np.abs(sol.x).max())
    return {'duration': duration, 'solver': p.solver, 'rel_dev_from_abm': rel,
            'soe_wall': r.wall_time, 'abm_fft_wall': exact_wall}


def long_run(duration: float) -> dict:
    """4. simulate() over ``duration`` s of the FOM; wall per simulated second, start vs end."""
    marks: list[tuple[float, float]] = []

    def progress(frac: float) -> None:
        marks.append((frac, time.perf_counter()))

    t0 = time.perf_counter()
    r = simulate(ModelParameters(), StateFeedback(), duration, sample_every=50,
                 progress=progress)
    total = time.perf_counter() - t0
    marks.insert(0, (0.0, t0))
    first = (marks[1][1] - marks[0][1]) / ((marks[1][0] - marks[0][0]) * duration)
    last = (marks[-1][1] - marks[-2][1]) / ((marks[-1][0] - marks[-2][0]) * duration)
    return {'duration': duration, 'wall': total, 'steps': r.metadata['steps'],
            'wall_per_sim_s_first_1pct': first, 'wall_per_sim_s_last_1pct': last,
            'ratio_last_over_first': last / first,
            'final_state_finite': bool(np.isfinite(r.state[-1]).all())}


def targets(res: dict) -> list[dict]:
    rows = []

    add = partial(target, rows)

    cost = res['per_step']
    add('compiled / interpreted speed-up, RK4 delay-free', cost['delay-free']['speedup'],
        '>=', 20.0)
    add('compiled / interpreted speed-up, RK4 delayed', cost['delayed']['speedup'], '>=', 20.0)
    add('compiled / interpreted speed-up, FOM soe', cost['fractional']['speedup'], '>=', 10.0)
    add('compiled FOM soe step, median (us)', cost['fractional']['compiled_us'], '<=', 3.0)
    depth = res['cost_at_depth']
    for n, us in zip(depth['n'][1:], depth['us_per_step'][1:]):
        add(f'FOM cost per step at n={n:.0e} / at n=1e3', us / depth['us_per_step'][0],
            '<=', 1.5)
    add('default FOM solver vs exact ABM, 2 s closed loop (rel.)',
        res['accuracy']['rel_dev_from_abm'], '<=', 1e-6)
    add(f"simulate() {res['long_run']['duration']:g} s FOM: wall/sim-s last 1 % / first 1 %",
        res['long_run']['ratio_last_over_first'], '<=', 1.5)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--out', type=Path, default=None, help='write the results as JSON here')
    ap.add_argument('--quick', action='store_true', help='a smoke check: tiny runs, one round')
    args = ap.parse_args(argv)
    quick = args.quick
    res: dict = {'quick': quick, 'python': sys.version.split()[0], 'numpy': np.__version__,
                 'machine': platform.machine(), 'load_avg_start': os.getloadavg(),
                 'compiled': kernels.AVAILABLE}
    print(f"fohssv kernels benchmark  quick={quick}  load avg {os.getloadavg()[0]:.2f}")
    t0 = time.perf_counter()
    warm_up()
    res['warm_up_s'] = time.perf_counter() - t0
    print(f"kernels ready in {res['warm_up_s']:.2f} s (compiled, or loaded from the cache)")

    res['per_step'] = per_step_costs(rounds=1 if quick else 7)
    print('\n1. cost per integration step, one call per 1e-4 s control period (median, us)')
    print(f"{'model':<12} {'step':>7} {'interpreted':>12} {'compiled':>9} {'speed-up':>9} "
          f"{'compiled, 1e4-step calls, eq. 31 in the kernel':>48}")
    for model, c in res['per_step'].items():
        print(f"{model:<12} {c['step']:>7g} {c['interpreted_us']:>12.2f} {c['compiled_us']:>9.3f}"
              f" {c['speedup']:>8.1f}x {c['compiled_us_in_10000_step_calls']:>48.3f}")

    levels = [10**3, 2 * 10**3] if quick else [10**3, 10**6, 10**7]
    res['cost_at_depth'] = cost_at_depth(levels)
    d = res['cost_at_depth']
    print(f"\n2. FOM cost per step at step n (solver {d['solver']}, horizon "
          f"{d['horizon_steps']:.0e} steps, median of 5 x 1000-step windows)")
    for n, us in zip(d['n'], d['us_per_step']):
        print(f"   n = {n:>8.0e}: {us:.3f} us")

    res['accuracy'] = soe_accuracy(0.01 if quick else 2.0)
    a = res['accuracy']
    print(f"\n3. default solver ({a['solver']}, compiled) vs exact ABM, eq. 31 closed loop "
          f"{a['duration']:g} s: max deviation {a['rel_dev_from_abm']:.2e} of max|x| "
          f"(soe {a['soe_wall']:.2f} s, exact FFT ABM {a['abm_fft_wall']:.2f} s)")

    res['long_run'] = long_run(0.1 if quick else 600.0)
    lr = res['long_run']
    print(f"\n4. simulate() FOM {lr['duration']:g} s simulated ({lr['steps']:.2e} steps): "
          f"{lr['wall']:.1f} s wall; wall per simulated second "
          f"{lr['wall_per_sim_s_first_1pct']:.3f} s (first 1 %) and "
          f"{lr['wall_per_sim_s_last_1pct']:.3f} s (last 1 %)")

    res['targets'] = targets(res)
    return finish(res, 'Targets of issue #11 (ratios from this run)', args.out, width=62)


if __name__ == '__main__':
    raise SystemExit(main())
