#!/usr/bin/env python3
"""Benchmark of the Gymnasium environments (fohssv_sim.envs): env-steps per second.

    python bench/bench_envs.py --out bench/results/envs.json [--quick]

Measures, for the FOM at the default 1e-4 s control period (5 'soe' steps of 2e-5 s per
env step), under the eq. 31 law (the actions computed between steps, untimed, so the
vehicles stay on the closed loop's orbit, not in subnormal arithmetic):

  1. ``HSSV-v0``: env steps per second of one env, and its Python overhead per step (the env
     step's time less the compiled held-input call's own, ``Plant.advance``);
  2. the vectorised env at N = 1, 8, 64: env steps (vehicle periods) per second, beside the
     compiled kernel's own rate for the same work (the limit: the env's one compiled call
     per period, called back to back without the env's checks, rewards and observations),
     and their ratio (goal: at least 0.8 at N = 64); and, for reference, ``run_population``
     (the same per-vehicle kernel, all the periods in one call, the history's weights laid
     out by step rather than by vehicle).

The machine may be shared: the load average is printed and stored with the results.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from benchutil import finish, target

from fohssv_sim import control
from fohssv_sim.analysis.population import run_population
from fohssv_sim.envs import HSSVEnv, HSSVVectorEnv
from fohssv_sim.models import AffineLaw
from fohssv_sim.params import ModelParameters

X_START = (0.0, 0.5, 0.0, 0.0)
ENV = {'fin': True, 'initial_state': X_START, 'initial_spread': (0, 0, 0, 0),
       'episode_steps': 10**8}


def _law():
    law = control.make('state_feedback')
    K, u0 = (np.asarray(v, dtype=float) for v in law.affine())
    lim = np.array([law.params.max_fin_deflection, law.params.max_cavitator_deflection])
    return law, K, u0, lim


def single_env(steps: int) -> tuple[float, float]:
    """(env steps per second, Python overhead per step in us) of one HSSV-v0."""
    law, *_ = _law()
    env = HSSVEnv(**ENV)
    obs, info = env.reset(seed=0)
    env.step(law.command(0.0, obs))                 # compile / load from the cache
    spent = 0.0
    clock = time.perf_counter
    for _ in range(steps):
        a = law.command(info['t'], obs)
        t0 = clock()
        obs, _, _, _, info = env.step(a)
        spent += clock() - t0
    plant = env.plant                                # the compiled call alone, same work
    t0 = clock()
    for _ in range(steps):
        plant.advance((0.01, -0.01), env.task.hold)
    kernel = clock() - t0
    return steps / spent, (spent - kernel) / steps * 1e6


def vector_env(n: int, periods: int, rounds: int = 5) -> tuple[float, float, float, float]:
    """Env steps per second at N = ``n``: of the vectorised env, of its compiled call alone
    (the limit; the same law's inputs set untimed between calls), their ratio, and of
    ``run_population`` (all the periods in one call, for reference). Env and kernel rounds
    of ``periods`` periods alternate; the medians of ``rounds`` rounds."""
    _, K, u0, lim = _law()
    venv = HSSVVectorEnv(n, **ENV)
    obs, _ = venv.reset(seed=0)
    venv.step(np.clip(obs @ K.T + u0, -lim, lim))   # compile / load from the cache
    clock = time.perf_counter
    active = np.ones(n, dtype=bool)
    env_rates, kernel_rates = [], []
    for _ in range(rounds):
        spent = 0.0
        for _ in range(periods):
            act = np.clip(obs[:, :4] @ K.T + u0, -lim, lim)
            t0 = clock()
            obs, *_ = venv.step(act)
            spent += clock() - t0
        env_rates.append(n * periods / spent)
        spent = 0.0
        for _ in range(periods):
            venv.U[:] = np.clip(venv.X @ K.T + u0, -lim, lim)
            t0 = clock()
            venv._advance(active)                    # the env's one compiled call alone
            spent += clock() - t0
        kernel_rates.append(n * periods / spent)
        obs = venv._observe()
    params = [ModelParameters()] * n                 # the population kernel, for reference
    packed = AffineLaw(K, u0, lim).packed
    duration = venv.tasks[0].duration
    run_population(params, 1, 5, law=packed, initial_state=X_START, duration=duration)
    t0 = clock()
    run_population(params, periods, 5, law=packed, initial_state=X_START, duration=duration)
    population = n * periods / (clock() - t0)
    ratio = statistics.median(e / k for e, k in zip(env_rates, kernel_rates))
    return (statistics.median(env_rates), statistics.median(kernel_rates), ratio,
            population)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=None)
    ap.add_argument('--quick', action='store_true', help='fewer steps (a smoke run)')
    args = ap.parse_args()
    steps = 2000 if args.quick else 20000
    res: dict = {'load_avg_start': os.getloadavg(), 'targets': []}
    print(f'load avg at start {os.getloadavg()[0]:.2f}', flush=True)
    rate, overhead = single_env(steps)
    res['single'] = {'steps_per_s': rate, 'python_overhead_us': overhead}
    print(f'HSSV-v0, one env: {rate:,.0f} env steps/s; Python overhead {overhead:.1f} us/step',
          flush=True)
    res['vector'] = {}
    for n in (1, 8, 64):
        periods = max(50, steps // (5 * n))
        got, limit, ratio, population = vector_env(n, periods)
        res['vector'][n] = {'steps_per_s': got, 'kernel_steps_per_s': limit,
                            'population_steps_per_s': population, 'ratio': ratio}
        print(f'vectorised, N = {n:2d}: {got:,.0f} env steps/s; its compiled call alone '
              f'{limit:,.0f}/s (ratio {ratio:.2f}); run_population {population:,.0f}/s',
              flush=True)
    target(res['targets'], 'vectorised env / compiled kernel at N = 64',
           res['vector'][64]['ratio'], '>=', 0.8)
    return finish(res, 'bench_envs targets', args.out)


if __name__ == '__main__':
    sys.exit(main())
