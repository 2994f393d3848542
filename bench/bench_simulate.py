#!/usr/bin/env python3
"""Benchmark of ``simulate()`` against the compiled kernel it runs, all three models.

    python bench/bench_simulate.py --out bench/results/simulate.json [--quick]

For each model (alpha = 0.85 for the FOM, V = 75 m/s, the eq. 31 state feedback in
continuous mode, the default step), the wall time per simulated second of

  keep 1     ``simulate(p, StateFeedback(), duration)``: every step kept (the default);
  keep 50    the same with ``sample_every=50``;
  kernel     the compiled kernel alone for the same steps: one ``Plant.advance`` call with the
             law inside the kernel, nothing kept (the limit ``simulate`` can reach).

Each after a warm-up call; the three interleaved over a few rounds, medians reported, as wall
time and as the process's CPU time (``time.process_time``: all three run on one thread, so
CPU time is the wall time of a quiet machine, and what a shared machine's preemption does not
inflate). Targets, on the CPU times: keeping every step costs at most 1.5x keeping every 50th,
and both within 1.5x of the kernel. The load average is printed and stored.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

from benchutil import finish, target

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.models import AffineLaw, make_plant
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

MODELS = {'delay-free': {}, 'delayed': {}, 'fractional': {'fractional_order': 0.85}}


def _kernel(p: ModelParameters, duration: float) -> tuple[float, float]:
    plant = make_plant(p, duration=duration)
    law = AffineLaw.from_controller(StateFeedback())
    steps = round(duration / plant.h)
    wall, cpu = time.perf_counter(), time.process_time()
    plant.advance(law, steps)
    return time.perf_counter() - wall, time.process_time() - cpu


def _simulate(p: ModelParameters, duration: float, every: int) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    simulate(p, StateFeedback(), duration, sample_every=every)
    return time.perf_counter() - wall, time.process_time() - cpu


def measure(model: str, duration: float, rounds: int) -> dict:
    """Wall and CPU seconds per simulated second, medians over ``rounds``: ``keep_1``,
    ``keep_50``, ``kernel`` (wall) and the same with ``cpu_`` in front."""
    p = ModelParameters(model=model, speed=75.0, **MODELS[model])
    _simulate(p, min(duration, 0.01), 1)         # compile or load the kernels
    _kernel(p, min(duration, 0.01))
    runs: dict[str, list[tuple[float, float]]] = {'keep_1': [], 'keep_50': [], 'kernel': []}
    for _ in range(rounds):
        runs['keep_1'].append(_simulate(p, duration, 1))
        runs['keep_50'].append(_simulate(p, duration, 50))
        runs['kernel'].append(_kernel(p, duration))
    row = {}
    for k, v in runs.items():
        row[k] = statistics.median(w for w, _ in v) / duration
        row[f'cpu_{k}'] = statistics.median(c for _, c in v) / duration
    row['step'] = p.step
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', type=Path, default=None, help='write the results as JSON here')
    ap.add_argument('--quick', action='store_true', help='a tiny case (smoke check)')
    args = ap.parse_args(argv)
    duration, rounds = (0.02, 1) if args.quick else (4.0, 3)
    res: dict = {'quick': args.quick, 'duration': duration, 'rounds': rounds,
                 'load_avg_start': os.getloadavg(), 'models': {}}
    print(f'simulate() against its kernel, {duration:g} s simulated, median of {rounds}  '
          f'load avg {os.getloadavg()[0]:.2f}')
    print(f"{'model':<12} {'step':>7} {'keep 1':>10} {'keep 50':>10} {'kernel':>10}"
          '   (wall s per simulated s; CPU s in brackets)')
    rows = []
    res['figures'] = [['model', 'step (s)', 'keep 1', 'keep 50', 'kernel alone',
                       '(wall s per simulated s; CPU s in brackets)']]
    for model in MODELS:
        r = res['models'][model] = measure(model, duration, rounds)
        cells = [f"{r[k]:.4f} ({r['cpu_' + k]:.4f})" for k in ('keep_1', 'keep_50', 'kernel')]
        print(f"{model:<12} {r['step']:>7g} " + ' '.join(f'{c:>18}' for c in cells), flush=True)
        res['figures'].append([model, f"{r['step']:g}", *cells, ''])
        k1, k50, kern = r['cpu_keep_1'], r['cpu_keep_50'], r['cpu_kernel']
        target(rows, f'{model}: simulate keep 1 / keep 50 (CPU)', k1 / k50, '<=', 1.5)
        target(rows, f'{model}: simulate keep 1 / kernel (CPU)', k1 / kern, '<=', 1.5)
        target(rows, f'{model}: simulate keep 50 / kernel (CPU)', k50 / kern, '<=', 1.5)
    res['targets'] = rows
    return finish(res, 'Targets of issue #52 (ratios from this run)', args.out)


if __name__ == '__main__':
    raise SystemExit(main())
