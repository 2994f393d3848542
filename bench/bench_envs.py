#!/usr/bin/env python3
"""Benchmark of the Gymnasium environments (fohssv_sim.envs): env-steps per second.

    python bench/bench_envs.py --out bench/results/envs.json [--quick]

Measures, for the FOM at the default 1e-4 s control period (5 'soe' steps of 2e-5 s per
env step), under the eq. 31 law (the actions computed between steps, untimed, so the
vehicles stay on the closed loop's orbit, not in subnormal arithmetic):

  1. ``HSSV-v0``: env steps per second of one env, and its Python overhead per step (the env
     step's time less that of the compiled held-input call ``Plant.advance`` doing the same
     work);
  2. the vectorised env at N = 1, 8, 64: env steps (vehicle periods) per second, beside the
     compiled kernel's own rate for the same work (the limit: the env's compiled advance,
     ``stepping.periods``, called without the env's checks, rewards and observations), and
     their ratio (goal: at least 0.8 at N = 64); and, for reference, ``run_population`` (the
     same per-vehicle kernel, all the periods in one call, the history's weights laid out by
     step rather than by vehicle).

Side by side: the env and a twin of it (the same vehicles, seed and actions, so the same
states and work) are timed call by call in turn, the env's step on one and the kernel alone
on the other, so a neighbour's load falls on both alike. Times are the CPU time of this
thread (``time.thread_time``: what the calls cost, not the time other processes held the
core); on an idle machine that is wall time. The load average is printed and stored.
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
from fohssv_sim.envs.stepping import periods as periods_alone
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
    """(env steps per CPU second of one HSSV-v0, its Python overhead per step in us): each
    env step beside its twin plant's compiled call with the same input."""
    law, *_ = _law()
    env, twin = HSSVEnv(**ENV), HSSVEnv(**ENV)
    obs, info = env.reset(seed=0)
    twin.reset(seed=0)
    hold, plant = env.task.hold, twin.plant
    clock = time.thread_time
    spent = kernel = 0.0
    for k in range(steps + 1):
        a = law.command(info['t'], obs)
        t0 = clock()
        obs, _, _, _, info = env.step(a)
        t1 = clock()
        plant.advance((a[0], a[1]), hold)
        t2 = clock()
        if k:                                        # the first compiles / loads the cache
            spent += t1 - t0
            kernel += t2 - t1
    return steps / spent, (spent - kernel) / steps * 1e6


def vector_env(n: int, periods: int, rounds: int = 5) -> tuple[float, float, float, float]:
    """Env steps per CPU second at N = ``n``: of the vectorised env, of its compiled advance
    alone on a twin (the limit), the ratio (the median of ``rounds`` rounds of ``periods``
    periods), and of ``run_population`` (all the periods in one call, for reference)."""
    _, K, u0, lim = _law()
    venv, twin = HSSVVectorEnv(n, **ENV), HSSVVectorEnv(n, **ENV)
    obs, _ = venv.reset(seed=0)
    twin.reset(seed=0)
    clock = time.thread_time
    active = np.ones(n, dtype=bool)
    state, model = twin._state, twin._model
    env_rates, kernel_rates, ratios = [], [], []
    for r in range(rounds + 1):
        spent = kernel = 0.0
        for _ in range(periods):
            act = np.clip(obs[:, :4] @ K.T + u0, -lim, lim)
            twin.U[:] = act
            t0 = clock()
            obs, *_ = venv.step(act)
            t1 = clock()
            periods_alone(active, state, model)
            t2 = clock()
            spent += t1 - t0
            kernel += t2 - t1
        if r:                                        # the first round warms up
            env_rates.append(n * periods / spent)
            kernel_rates.append(n * periods / kernel)
            ratios.append(kernel / spent)
    assert np.array_equal(obs, twin.X), 'the twin did other work'
    params = [ModelParameters()] * n                 # the population kernel, for reference
    packed = AffineLaw(K, u0, lim).packed
    duration = venv.tasks[0].duration
    run_population(params, 1, 5, law=packed, initial_state=X_START, duration=duration)
    t0 = clock()
    run_population(params, periods, 5, law=packed, initial_state=X_START, duration=duration)
    population = n * periods / (clock() - t0)
    return (statistics.median(env_rates), statistics.median(kernel_rates),
            statistics.median(ratios), population)


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
    print(f'HSSV-v0, one env: {rate:,.0f} env steps/s; Python overhead {overhead:.1f} us/step '
          '(beyond its compiled call)', flush=True)
    res['vector'] = {}
    for n in (1, 8, 64):
        periods = max(200, steps // (5 * n))
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
