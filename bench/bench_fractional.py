#!/usr/bin/env python3
"""Benchmark of the fractional solvers (fohssv_sim.fractional), side by side in one run.

    python bench/bench_fractional.py --out bench/results/fractional.json [--quick]

Measures
  1. per-step cost of ABMStepper and SOEStepper at step n = 1e3, 1e4, 1e5, 1e6 (ABM: history
     prefilled with arbitrary values, then a few steps timed; SOE: actually run to n);
  2. wall time and max error against the exact Mittag-Leffler solution E_a(A t^a) x0 for
     N = 1e4 and 1e5 steps of a 4-state linear problem: ABMStepper, solve_abm_fft,
     SOEStepper and pycaputo's PECE (about 10 min at N = 1e5, run once; skipped if the
     estimate exceeds --pycaputo-max-seconds);
  3. batched throughput (point-steps/s) of BatchSOE (and BatchABM) for P = 1, 64, 512.

BLAS is limited to one thread (per-core figures) unless the caller set the thread variables.
The machine may be shared: the load average is printed and stored with the results.
"""

from __future__ import annotations

import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import argparse  # noqa: E402
import copy  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from functools import partial  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from benchutil import finish, target  # noqa: E402

try:
    import fohssv_sim.fractional  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'src' / 'fohssv_sim'))

from fohssv_sim.fractional import (  # noqa: E402
    ABMStepper,
    BatchABM,
    BatchSOE,
    SOEStepper,
    soe_kernel_error,
    solve_abm_fft,
)

ALPHA = 0.85
A4 = np.array([[-1.0, 2.0, 0.0, 0.0],
               [-2.0, -1.0, 0.0, 0.5],
               [0.0, 0.0, -3.0, 1.0],
               [0.1, 0.0, -1.0, -0.5]])
X4 = np.array([1.0, 0.5, -0.3, 0.2])
T_END = 10.0


def rhs(t, x, u):
    return A4 @ x


def rhs_numba():
    """The same rhs compiled with numba (u is ignored, as above)."""
    import numba

    a4 = A4.copy()

    @numba.njit
    def rhs_jit(t, x, u):
        return a4 @ x

    return rhs_jit


def exact_solution(t: np.ndarray, alpha: float) -> np.ndarray:
    import pymittagleffler

    lam, V = np.linalg.eig(A4)
    c = np.linalg.solve(V, X4.astype(complex))
    E = np.asarray(pymittagleffler.mittag_leffler(np.multiply.outer(t ** alpha, lam), alpha, 1.0))
    return ((E * c) @ V.T).real


# -- 1. per-step cost ------------------------------------------------------------------------
# The machine may be shared: every cost is the minimum over several rounds, and the rounds
# visit all levels in turn, so a slow drift of the load affects every level alike.
def make_abm_at(n: int, spare: int) -> ABMStepper:
    st = ABMStepper(rhs, ALPHA, 1e-4, X4, capacity=n + spare + 16)
    rng = np.random.default_rng(0)
    F = rng.normal(size=(n, 4)) * 1e-3
    st.history.fill(F)                                 # arbitrary history f_0..f_{n-1}
    st.advanced(n, F[-1])                              # as if n steps had been taken
    st.step()                                          # warm-up (not timed)
    return st


def make_soe_at(levels: list[int]) -> dict[int, SOEStepper]:
    """One SOE stepper actually run to each level (copied on the way)."""
    st = SOEStepper(rhs, ALPHA, 1e-4, X4)
    out = {}
    for n in levels:
        while st.n < n:
            st.step()
        out[n] = copy.deepcopy(st)
    return out


def interleaved_min(steppers: dict[int, object], reps: dict[int, int], rounds: int) -> dict:
    best = {n: float('inf') for n in steppers}
    for _ in range(rounds):
        for n, st in steppers.items():
            r = reps[n]
            t0 = time.perf_counter()
            for _ in range(r):
                st.step()
            best[n] = min(best[n], (time.perf_counter() - t0) / r)
    return best


# -- 2. accuracy and wall time ---------------------------------------------------------------
def run_stepper(cls, N: int, h: float, f=rhs) -> np.ndarray:
    st = cls(f, ALPHA, h, X4)
    xs = np.empty((N + 1, 4))
    xs[0] = X4
    for n in range(N):
        xs[n + 1] = st.step()
    return xs


def run_pycaputo(N: int, h: float, f=rhs) -> np.ndarray:
    from pycaputo.controller import make_fixed_controller
    from pycaputo.derivatives import CaputoDerivative
    from pycaputo.events import StepCompleted
    from pycaputo.fode import caputo
    from pycaputo.stepping import evolve

    m = caputo.PECE(ds=tuple(CaputoDerivative(ALPHA) for _ in range(4)),
                    control=make_fixed_controller(h, tstart=0.0, nsteps=N),
                    source=lambda t, y: f(t, y, None), y0=(X4.copy(),), corrector_iterations=1)
    return np.array([ev.y for ev in evolve(m, dtinit=h) if isinstance(ev, StepCompleted)])


def timed(fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


# -- 3. batched throughput -------------------------------------------------------------------
def batch_throughput(cls, P: int, steps: int, warm: int, windows: int = 4) -> float:
    """Best of ``windows`` windows of steps // windows steps (point-steps/s)."""
    AT = A4.T.copy()
    X0 = np.random.default_rng(0).normal(size=(P, 4))
    B = cls(lambda t, X, U: X @ AT, ALPHA, 1e-4, X0)
    for _ in range(warm):
        B.step()
    best = 0.0
    per = max(steps // windows, 1)
    for _ in range(windows):
        t0 = time.perf_counter()
        for _ in range(per):
            B.step()
        best = max(best, P * per / (time.perf_counter() - t0))
    return best


def targets(res: dict) -> list[dict]:
    """The issue's targets, each with the figure measured in this run (when it was run)."""
    rows = []

    add = partial(target, rows)

    cost = res['per_step_cost']
    last = cost['n'][-1]
    add(f'SOE cost at n={last:.0e} / at n=1e3', cost['soe_ratio_last_over_1e3'], '<=', 1.5)
    if last == 10**6:
        add('ABM / SOE cost per step at n=1e6', cost['abm_us'][-1] / cost['soe_us'][-1],
            '>=', 100.0)
    acc = res['accuracy_and_wall']
    for N, by_kind in acc.items():
        for kind, e in by_kind.items():
            add(f'SOE rel. deviation from ABM, N={int(N):.0e}, rhs={kind}',
                e['SOEStepper']['rel_dev_from_abm'], '<=', 1e-8)
            add(f'FFT rel. deviation from ABM, N={int(N):.0e}, rhs={kind}',
                e['solve_abm_fft']['rel_dev_from_abm'], '<=', 1e-12)
            if N == str(10**5):
                add(f'FFT speed-up over ABMStepper, N=1e5, rhs={kind}',
                    e['fft_speedup_vs_abm'], '>=', 10.0)
            if N == str(10**4):
                add(f'FFT speed-up over pycaputo, N=1e4, rhs={kind}',
                    e.get('fft_speedup_vs_pycaputo'), '>=', 100.0)
                err_ratio = e['solve_abm_fft']['max_abs_err'] / e['pycaputo PECE']['max_abs_err']
                add(f'FFT error / pycaputo error, N=1e4, rhs={kind}', err_ratio, '<=', 1.0)
    add('BatchSOE point-steps/s at P=512', res['batch_throughput']['512']['BatchSOE'],
        '>=', 1e6)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--out', type=Path, default=None, help='write the results as JSON here')
    ap.add_argument('--quick', action='store_true', help='smoke check: smallest sizes')
    ap.add_argument('--pycaputo-max-seconds', type=float, default=1200.0,
                    help='skip pycaputo at a size whose estimated time exceeds this')
    args = ap.parse_args(argv)
    quick = args.quick
    res: dict = {
        'alpha': ALPHA, 'problem': '4-state linear D^a x = A x, t in [0, 10] s',
        'quick': quick, 'python': sys.version.split()[0], 'numpy': np.__version__,
        'machine': platform.machine(), 'load_avg_start': os.getloadavg(),
        'blas_threads': os.environ.get('OPENBLAS_NUM_THREADS'),
    }
    print(f"fohssv fractional benchmark  alpha={ALPHA}  quick={quick}  "
          f"load avg {os.getloadavg()[0]:.2f}  BLAS threads {res['blas_threads']}")

    # 1 ------------------------------------------------------------------------------------
    levels = [10**3] if quick else [10**3, 10**4, 10**5, 10**6]
    rounds = 1 if quick else 5
    abm_reps = {10**3: 400, 10**4: 200, 10**5: 40, 10**6: 5}
    abm = {n: make_abm_at(n, rounds * abm_reps[n] + 1) for n in levels}
    soe = make_soe_at(levels)
    abm_cost = interleaved_min(abm, abm_reps, rounds)
    soe_cost = interleaved_min(soe, {n: 1000 for n in levels}, rounds)
    cost = {'n': levels, 'abm_us': [abm_cost[n] * 1e6 for n in levels],
            'soe_us': [soe_cost[n] * 1e6 for n in levels]}
    cost['soe_ratio_last_over_1e3'] = cost['soe_us'][-1] / cost['soe_us'][0]
    cost['abm_note'] = 'ABM: history prefilled with arbitrary values, then steps timed'
    cost['soe_note'] = 'SOE: stepped for real up to each n, then 1000-step windows timed'
    cost['timing'] = f'min over {rounds} interleaved rounds'
    res['per_step_cost'] = cost
    print('\n1. cost per step (microseconds)')
    print(f"{'n':>10} {'ABMStepper':>12} {'SOEStepper':>12} {'ABM/SOE':>9}")
    for n, a, s in zip(levels, cost['abm_us'], cost['soe_us']):
        print(f"{n:>10.0e} {a:>12.1f} {s:>12.1f} {a / s:>9.1f}")
    print(f"   SOE cost at n={levels[-1]:.0e} / at n=1e3: {cost['soe_ratio_last_over_1e3']:.2f} "
          f"(target <= 1.5)")

    # 2 ------------------------------------------------------------------------------------
    # Every solver gets the same rhs object: first a plain Python (numpy) function, then the
    # same function compiled with numba (solve_abm_fft then runs its base blocks compiled; the
    # others, pycaputo included, call it from Python).
    sizes = [10**3] if quick else [10**4, 10**5]
    acc: dict = {}
    rhs_kinds = {'python': rhs, 'numba': rhs_numba()}
    t0c = time.perf_counter()
    solve_abm_fft(rhs_kinds['numba'], ALPHA, 1e-3, X4, 300)
    res['numba_compile_s'] = time.perf_counter() - t0c
    print(f"\n2. wall time (s) and max error vs exact Mittag-Leffler, T = 10 s "
          f"(numba compile of the FFT base block, once: {res['numba_compile_s']:.2f} s, "
          f"not counted)")
    print(f"{'N':>8} {'rhs':>7} {'solver':>14} {'wall s':>9} {'max abs err':>12} "
          f"{'max dev from abm':>17}")
    pyc_rate = None
    for N in sizes:
        h = T_END / N
        t = h * np.arange(N + 1)
        ex = exact_solution(t, ALPHA)
        acc[str(N)] = {}
        pyc_rows: dict = {}
        for kind, f in rhs_kinds.items():
            rows = {}
            sol, w1 = timed(solve_abm_fft, f, ALPHA, h, X4, N)
            x_abm, w = timed(run_stepper, ABMStepper, N, h, f)
            rows['ABMStepper'] = (w, x_abm)
            sol, w2 = timed(solve_abm_fft, f, ALPHA, h, X4, N)   # bracket the ABM run
            rows['solve_abm_fft'] = ((w1 + w2) / 2, sol.x)
            x, w = timed(run_stepper, SOEStepper, N, h, f)
            rows['SOEStepper'] = (w, x)
            est = None if pyc_rate is None else pyc_rate * N ** 2
            pyc_reused = False
            if kind != 'python' and N > 10**4 and 'python' in pyc_rows:
                # one pycaputo run per size above 1e4: its cost is its own history sums, not
                # the rhs (equal times with both rhs kinds at 1e4, printed above)
                rows['pycaputo PECE'] = pyc_rows['python']
                pyc_reused = True
                print(f"{N:>8} {kind:>7} {'pycaputo PECE':>14}   (the run with the Python rhs, "
                      f"above)")
            elif est is not None and est > args.pycaputo_max_seconds:
                rows['pycaputo PECE'] = None
                print(f"{N:>8} {kind:>7} {'pycaputo PECE':>14}   skipped: estimated {est:.0f} s "
                      f"(> --pycaputo-max-seconds {args.pycaputo_max_seconds:.0f}, O(N^2) from "
                      f"the smaller run)")
            else:
                if est is not None:
                    print(f"   pycaputo PECE at N={N:.0e}: about {est:.0f} s (O(N^2) from the "
                          f"smaller run) ...", flush=True)
                x, w = timed(run_pycaputo, N, h, f)
                rows['pycaputo PECE'] = (w, x)
                pyc_rows[kind] = rows['pycaputo PECE']
                pyc_rate = w / N ** 2 if pyc_rate is None else min(pyc_rate, w / N ** 2)
            entry = {}
            for name, val in rows.items():
                if val is None:
                    entry[name] = {'skipped': True, 'estimated_s': est}
                    continue
                w, x = val
                err = float(np.max(np.abs(x - ex)))
                dev = float(np.max(np.abs(x - x_abm)) / np.max(np.abs(x_abm)))
                entry[name] = {'wall_s': w, 'max_abs_err': err, 'rel_dev_from_abm': dev}
                if name == 'pycaputo PECE' and pyc_reused:
                    entry[name]['measured_with_rhs'] = 'python'
                print(f"{N:>8} {kind:>7} {name:>14} {w:>9.3f} {err:>12.3e} {dev:>17.2e}")
            entry['fft_runs_s'] = [w1, w2]
            entry['fft_speedup_vs_abm'] = rows['ABMStepper'][0] / rows['solve_abm_fft'][0]
            entry['soe_speedup_vs_abm'] = rows['ABMStepper'][0] / rows['SOEStepper'][0]
            if rows['pycaputo PECE'] is not None:
                pw = rows['pycaputo PECE'][0]
                entry['fft_speedup_vs_pycaputo'] = pw / rows['solve_abm_fft'][0]
                entry['soe_speedup_vs_pycaputo'] = pw / rows['SOEStepper'][0]
            print(f"   N={N:.0e} rhs={kind}: solve_abm_fft runs {w1:.3f} s, {w2:.3f} s (mean "
                  f"used): {entry['fft_speedup_vs_abm']:.1f}x ABMStepper, SOEStepper "
                  f"{entry['soe_speedup_vs_abm']:.1f}x" + (
                      f"; vs pycaputo: FFT {entry['fft_speedup_vs_pycaputo']:.0f}x, SOE "
                      f"{entry['soe_speedup_vs_pycaputo']:.0f}x"
                      if 'fft_speedup_vs_pycaputo' in entry else ''))
            acc[str(N)][kind] = entry
    res['accuracy_and_wall'] = acc

    # 3 ------------------------------------------------------------------------------------
    steps = 8 if quick else 2000
    thr: dict = {}
    print(f"\n3. batched throughput (point-steps/s, linear rhs, best of 4 windows of "
          f"{steps // 4} steps after 100)")
    abm_label = f"BatchABM@n<={steps + 100}"
    print(f"{'P':>6} {'BatchSOE':>12} {abm_label:>18}")
    for P in (1, 64, 512):
        s = batch_throughput(BatchSOE, P, steps, 100)
        a = batch_throughput(BatchABM, P, steps, 100)
        thr[str(P)] = {'BatchSOE': s, 'BatchABM': a, 'BatchABM_max_n': steps + 100}
        print(f"{P:>6} {s:>12.3g} {a:>18.3g}")
    thr['soe_P512_over_target_1e6'] = thr['512']['BatchSOE'] / 1e6
    print(f"   BatchSOE at P=512: {thr['soe_P512_over_target_1e6']:.2f} x the 1e6 target")
    res['batch_throughput'] = thr

    rep = soe_kernel_error(ALPHA)
    res['soe_kernel'] = rep._asdict()
    print(f"\nSOE kernel (alpha={ALPHA}, tol 1e-10, horizon 1e8): {rep.n_modes} modes, max rel "
          f"weight error {rep.max:.2e} over {rep.n_lags_checked} lags")
    res['targets'] = targets(res)
    return finish(res, 'Targets of issue #4 (ratios from this run)', args.out, width=58)


if __name__ == '__main__':
    raise SystemExit(main())
