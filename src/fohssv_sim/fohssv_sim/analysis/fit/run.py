"""The fit: the growing horizon, the profile over alpha, the intervals and the
half-step check (:func:`run_fit`, :class:`FitResult`).

Pure: numpy, scipy; never imports rclpy or the CLI.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ...params import ParameterError
from .data import STATE_NAMES, FitData, FitError
from .noise import effective_fraction
from .observer import PROCESS_NOISE
from .problem import FitSpec, Problem, cycle_features
from .result import FitResult, summary_line
from .search import Evaluator, Local, latin, lines


def _jacobian_interval(local: Local, x: np.ndarray, r: np.ndarray, bounds: np.ndarray,
                       problem: Problem) -> tuple[np.ndarray, float, int, float]:
    """(half widths, s^2, dof, n_eff / n) of the Jacobian interval at ``x``: s^2 = SSR / dof,
    cov = s^2 (J^T J)^-1 widened by n / n_eff for correlated residuals
    (:func:`.noise.effective_fraction`)."""
    from scipy.stats import t as student

    J = local.jac(x)
    n, p = J.shape
    dof = max(n - p, 1)
    s2 = float(r @ r) / dof
    frac = (effective_fraction(r.reshape(-1, 4)[:, problem.w > 0])
            if problem.spec.objective == 'trajectory' else 1.0)
    dof_eff = max(dof * frac, 1.0)
    try:
        cov = s2 / frac * np.linalg.pinv(J.T @ J)
        half = student.ppf(0.975, dof_eff) * np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        half = np.full(p, np.inf)
    half = np.where(np.isfinite(half), half, np.inf)
    blind = np.linalg.norm(J, axis=0) * (bounds[:, 1] - bounds[:, 0]) <= 1e-9 * max(
        math.sqrt(float(r @ r)), 1e-300)
    half[blind] = np.inf        # the residual does not depend on it: pinv would say 0
    return half, s2, dof, frac


def _fisher_std(local: Local, x: np.ndarray, problem: Problem) -> np.ndarray | None:
    """The standard deviation of each name from the Fisher information of the noise
    (J_e^T J_e, J_e the Jacobian of the residuals in noise units; white noise), or None for
    the cycle objective. Inf where the information is zero."""
    if problem.noise is None:
        return None
    J = local.jac(x)
    m = problem.w > 0
    per = np.where(m, problem.scale / (np.where(m, problem.w, 1.0) * problem.noise.sigma), 0.0)
    Je = J * np.tile(per, J.shape[0] // 4)[:, None]
    info = Je.T @ Je
    out = np.full(J.shape[1], np.inf)
    seen = np.diag(info) > 0
    if seen.any():
        try:
            cov = np.linalg.inv(info[np.ix_(seen, seen)])
            out[seen] = np.sqrt(np.maximum(np.diag(cov), 0.0))
        except np.linalg.LinAlgError:
            pass
    return out


def _profile_interval(grid: np.ndarray, ssr: np.ndarray, level: float) -> list[float] | None:
    """The connected range of ``grid`` around the minimum of ``ssr`` where ssr <= level,
    crossings interpolated linearly (an end of the grid where it is still below: that end)."""
    ok = np.isfinite(ssr)
    if not ok.any():
        return None
    g, s = grid[ok], ssr[ok]
    i = int(np.argmin(s))
    lo_i = i
    while lo_i > 0 and s[lo_i - 1] <= level:
        lo_i -= 1
    hi_i = i
    while hi_i < s.size - 1 and s[hi_i + 1] <= level:
        hi_i += 1

    def cross(a: int, b: int) -> float:
        if s[b] == s[a]:
            return float(g[a])
        return float(g[a] + (g[b] - g[a]) * (level - s[a]) / (s[b] - s[a]))

    lo = cross(lo_i, lo_i - 1) if lo_i > 0 else float(g[0])
    hi = cross(hi_i, hi_i + 1) if hi_i < s.size - 1 else float(g[-1])
    return [min(lo, float(g[i])), max(hi, float(g[i]))]


def run_fit(spec: FitSpec, data: FitData, out: Path, *, client: Any = None,
            progress: Callable[[int, int, float], None] | None = None,
            log: Callable[[str], None] | None = None, sidecar: dict[str, Any] | None = None,
            threads: int = 0) -> FitResult:
    """Run the fit ``spec`` of ``data``; population jobs go to ``out/population`` on the
    Dask ``client`` (None: in this process). See the module docstring. ``threads``: the
    local stage's (and, without a client, the population's) simulations are split over this
    many threads (0: one per core); the numbers do not depend on it.

    Raises:
        FitError: an invalid spec, an empty window, no commands and no controller.
    """
    import os

    spec.validate()
    say = log or (lambda s: None)
    threads = threads or os.cpu_count() or 1
    problem = Problem(spec, data)
    bounds = np.array(spec.bounds, dtype=float)
    ev = Evaluator(problem, out / 'population', client, progress,
                   {**(sidecar or {}), 'fit': spec.to_dict()}, threads=threads)
    stages: list[dict[str, Any]] = []
    best = None          # (x, r, upto) of the last reproduced stage
    last = None          # of the last stage run
    m = problem.index.size
    upto = problem.first_horizon()
    min_step = max(5, m // 100)
    seen = np.zeros(len(spec.names), dtype=bool)     # which names the last stage could see
    span = bounds[:, 1] - bounds[:, 0]
    failed = None        # (horizon, warm start) of the last stage not reproduced after one was
    for s in range(spec.max_stages):
        started, cpu = time.monotonic(), time.process_time()
        # a Latin hypercube until a horizon is reproduced (a halved horizon searches afresh:
        # its basin is wider); then lines through the estimate for the names not yet seen
        pts = (latin(bounds, spec.population, spec.seed) if best is None
               else lines(bounds, best[0], spec.population, seen))
        costs = ev.costs(f'stage{s}', pts, upto)
        order = np.argsort(costs, kind='stable')
        local = Local(problem, bounds, upto, threads)
        # a search afresh starts from the best spec.starts points; later stages from the
        # warm start (or a better line point)
        starts = order[:spec.starts if best is None else 1]
        found = [local.solve(pts[j], spec.max_nfev) for j in starts]
        sol = min(found, key=lambda r: r.cost)
        r = local.fun(sol.x)
        seen = np.linalg.norm(sol.jac, axis=0) * (bounds[:, 1] - bounds[:, 0]) > 1e-6
        verdict = problem.judge(r)
        res, ok = verdict['residual'], verdict['reproduced']
        t_end = float(data.t[problem.index[upto - 1]])
        stages.append({'stage': s, 'horizon_end': t_end, 'samples': int(upto),
                       'population': len(pts), 'best_population_cost': float(costs[order[0]]),
                       'values': sol.x.tolist(), **verdict,
                       'nfev': int(sol.nfev), 'evaluations': local.evaluations,
                       'wall_time': time.monotonic() - started,
                       'cpu_time': time.process_time() - cpu})
        say(f'  stage {s}: horizon {t_end:.6g} s ({upto} samples), residual {res:.3g}'
            + (f" = {verdict['noise_ratio']:.3g} x the noise (bound "
               f"{verdict['noise_bound']:.3g})" if 'noise_ratio' in verdict else '')
            + f"{'' if ok else ' (not reproduced)'} in {time.monotonic() - started:.1f} s "
            f'(CPU {time.process_time() - cpu:.1f} s of this process): '
            + ', '.join(f'{n}={v:.8g}' for n, v in zip(spec.names, sol.x)))
        last = (sol.x, r, upto)
        if ok:
            best = last
        elif best is not None:
            failed = (upto, best[0])
        upto = _next_horizon(problem, ok, upto, best, failed, span, min_step)
        if upto is None:
            break
    reproduced = best is not None
    x, r, upto = best if reproduced else last
    local = Local(problem, bounds, upto, threads)
    started, cpu = time.monotonic(), time.process_time()
    # the coarse profile over the bounds is also a last global check: a better grid point
    # (the population missed its basin) starts one more local fit
    jp = spec.names.index('fractional_order') if 'fractional_order' in spec.names else 0
    coarse, coarse_cost = _global_profile(ev, x, jp, bounds, spec.profile_points, upto)
    cpts = np.repeat(x[None], coarse.size, axis=0)
    cpts[:, jp] = coarse
    r = local.fun(x)
    i = int(np.argmin(coarse_cost))
    if coarse_cost[i] < 0.5 * float(r @ r) * (1 - 1e-9):
        sol = local.solve(cpts[i], spec.max_nfev)
        if sol.cost < 0.5 * float(r @ r):
            x = sol.x
            say(f'  the coarse profile found a better start: {spec.names[jp]}={coarse[i]:.6g} '
                f'-> ' + ', '.join(f'{n}={v:.8g}' for n, v in zip(spec.names, x)))
    r = local.fun(x)
    half, s2, dof, frac = _jacobian_interval(local, x, r, bounds, problem)
    fisher = _fisher_std(local, x, problem)
    jac_iv = {n: [float(max(bounds[j, 0], x[j] - half[j])), float(min(bounds[j, 1],
                                                                       x[j] + half[j]))]
              for j, n in enumerate(spec.names)}
    profile = _profile(problem, ev, local, spec, bounds, x, half, s2 / frac, upto, coarse,
                       coarse_cost)
    profile['wall_time'] = time.monotonic() - started
    profile['cpu_time'] = time.process_time() - cpu
    say(f"  profile over {profile['name']}: {len(profile['coarse'])} + "
        f"{len(profile['fine'])} points in {profile['wall_time']:.1f} s (CPU "
        f"{profile['cpu_time']:.1f} s of this process)")
    intervals = {n: list(v) for n, v in jac_iv.items()}
    j0 = profile['index']
    piv = profile.get('interval')
    if piv is not None:
        n0 = spec.names[j0]
        intervals[n0] = [min(jac_iv[n0][0], piv[0]), max(jac_iv[n0][1], piv[1])]
    check = (_step_check(problem, spec, data, bounds, x, upto, say, threads)
             if spec.step_check else None)
    if check is not None:
        for j, n in enumerate(spec.names):
            d = 2.0 * check['shift'][j]
            intervals[n] = [float(max(bounds[j, 0], intervals[n][0] - d)),
                            float(min(bounds[j, 1], intervals[n][1] + d))]
    span = bounds[:, 1] - bounds[:, 0]
    identifiable = {n: bool(math.isfinite(half[j]) and intervals[n][1] - intervals[n][0]
                            < 0.5 * span[j]) for j, n in enumerate(spec.names)}
    blind_reason = None
    if problem.mode == 'filter' and not spec.measured.all():
        # measured over ten seeds of depth and pitch alone: the interval held the truth in 3
        # at 1 % noise, in none at 5 % (docs/fit.md, Limits)
        off = ', '.join(n for n, m in zip(STATE_NAMES, spec.measured) if not m)
        blind_reason = (f'open loop with {off} not measured, what the parameters do is taken '
                        'up by the estimates of the unmeasured states; close the loop with '
                        '--controller NAME')
        identifiable = dict.fromkeys(spec.names, False)
    horizon_verdict, window_verdict, verdict = _verdicts(problem, x, r, upto, check)
    res, window_res = horizon_verdict['residual'], window_verdict['residual']
    reproduced = verdict['reproduced']
    t_end = float(data.t[problem.index[upto - 1]])
    fitted = _fitted_states(problem, x)
    params = problem.params_for(x)
    if params is None:              # every point the search tried: legal but unusable
        rng = ', '.join(f'{n}={lo:g}:{hi:g}' for n, (lo, hi) in zip(spec.names, spec.bounds))
        raise FitError(f'--bounds {rng}: the best point found, '
                       + ', '.join(f'{n}={v:g}' for n, v in zip(spec.names, x))
                       + ", gives no model that runs (the model's coefficients overflow); "
                       'give bounds nearer the run\'s values')
    values = {n: float(v) for n, v in zip(spec.names, x)}
    result = FitResult(spec=spec, values=values, intervals=intervals,
                       jacobian_intervals=jac_iv, profile_interval=piv,
                       residual=window_res if spec.controller is not None else res,
                       horizon_residual=res, window_residual=window_res,
                       reproduces=bool(reproduced), horizon_end=t_end,
                       window=(problem.window[0], float(data.t[problem.index[-1]])),
                       stages=stages, profile=profile, identifiable=identifiable,
                       fitted_states=fitted, data_states=data.states, t=data.t,
                       params=params,
                       settings={'model': 'fractional', 'solver': params.solver,
                                 'step': params.step, 'planing_form': params.planing_form,
                                 'control_period': data.control_period,
                                 'loop': _loop_text(problem),
                                 'initial_state': list(data.initial_state),
                                 'verdict': verdict, 'window_verdict': window_verdict,
                                 'horizon_verdict': horizon_verdict,
                                 'effective_fraction': frac, 'blind_reason': blind_reason,
                                 'fisher_std': None if fisher is None else
                                 {n: float(v) if math.isfinite(v) else None
                                                    for n, v in zip(spec.names, fisher)},
                                 'noise': problem.noise.to_dict() if problem.noise else None,
                                 'dof': dof, 's2': s2, 'population_points': ev.points,
                                 'step_check': check,
                                 'source': data.source})
    if spec.objective == 'cycle':
        sel = problem.index
        result.cycle = {'data': problem.features,
                        'fitted': cycle_features(data.t[sel], fitted[sel, 1])
                        if np.isfinite(fitted[sel, 1]).all() else None}
    result.message = summary_line(result)
    return result


def _next_horizon(problem: Problem, ok: bool, upto: int, best: tuple | None,
                  failed: tuple | None, span: np.ndarray, min_step: int) -> int | None:
    """The samples of the next stage after one of ``upto`` samples (``ok``: reproduced), or
    None to stop. Reproduced: doubled, or the whole window when less than half a horizon
    would be left; but a horizon already not reproduced (``failed``: horizon, warm start)
    from the same warm start (to 1e-3 of the bounds' ``span``) would not be now: bisected
    towards it instead. Not reproduced (growing only): halved while no horizon was, else
    bisected back towards the last reproduced one (``best``: x, r, samples); stopped where
    the step would be below ``min_step``."""
    m = problem.index.size
    if ok:
        if upto >= m:
            return None
        nxt = m if m - 2 * upto < upto // 2 else 2 * upto
        if failed is None or nxt < failed[0] or np.any(
                np.abs(best[0] - failed[1]) > 1e-3 * span):
            return nxt
        nxt = (upto + failed[0]) // 2
        return nxt if nxt - upto >= min_step else None
    if problem.mode != 'grow':
        return None
    if best is None:                     # not even the first horizon: halve it
        return None if upto <= min(m, 20) else max(min(m, 20), upto // 2)
    nxt = (best[2] + upto) // 2          # bisect towards the last reproduced horizon
    return nxt if nxt - best[2] >= min_step else None


def _fitted_states(problem: Problem, x: np.ndarray) -> np.ndarray:
    """The states of the estimate ``x`` at every sample of the run (the overlay), run over the
    whole window; NaN after it (not run) or where the model cannot run."""
    fitted = np.full_like(problem.data.states, np.nan)
    sim, _ = problem.simulate([x], problem.index.size)
    if sim is not None:
        fitted[:sim.states.shape[1]] = sim.states[0]
    return fitted


def _verdicts(problem: Problem, x: np.ndarray, r: np.ndarray, upto: int,
              check: dict[str, Any] | None) -> tuple[dict, dict, dict]:
    """(over the horizon, over the whole window, the one that decides) of the estimate ``x``
    (``r`` its residual row over the horizon). A closed loop is judged over the whole window:
    unlike an open-loop replay (which departs from any error), a fitted closed loop that
    leaves the run after the reproduced horizon is the model's misfit. Where the step check
    ran and reproduces the run at half the step, that verdict decides: the FOM is the
    continuous model, and a misfit at the step alone is the discretisation's (data from a
    finer or exact solver)."""
    horizon = problem.judge(r)
    window = (horizon if upto >= problem.index.size
              else problem.judge(problem.residuals([x])[0]))
    verdict = window if problem.spec.controller is not None else horizon
    if check is not None and not verdict['reproduced'] and check['verdict']['reproduced']:
        verdict = check['verdict']
    return horizon, window, verdict


def _loop_text(problem: Problem) -> str:
    """How the fitted model is driven (fit.json's settings, the figures' captions)."""
    if problem.spec.controller is None:
        if problem.mode == 'filter':
            return ('open (recorded commands, held; the prediction errors of an extended '
                    f'Kalman filter of the model, process noise {PROCESS_NOISE:g} of each '
                    "state's spread per period)")
        return 'open (recorded commands, held)'
    how = ('compiled' if problem.law is not None
           else 'not affine: point by point through the plant')
    return f'closed ({problem.spec.controller}, held per control period, {how})'


def _step_check(problem: Problem, spec: FitSpec, data: FitData, bounds: np.ndarray,
                x: np.ndarray, upto: int, say: Callable[[str], None], threads: int = 1
                ) -> dict[str, Any] | None:
    """Refit at half the step from ``x`` (same horizon): the shift of the estimate is the
    discretisation's share of its uncertainty (the intervals are widened by twice it, a
    Richardson bound for a scheme of order >= 1). None when half the step does not divide the
    control period."""
    half = problem.base.step / 2
    hold = data.control_period / half
    if abs(hold - round(hold)) > 1e-9 * hold:
        return None
    try:
        base = problem.base.replace(step=half)
    except ParameterError:
        return None
    started, cpu = time.monotonic(), time.process_time()
    sub = Problem(dataclasses.replace(spec, base=base.to_dict()), data)
    local = Local(sub, bounds, upto, threads)
    sol = local.solve(x, max(5, spec.max_nfev // 2))
    shift = np.abs(sol.x - x)
    r = local.fun(sol.x)
    res = sub.norm(r)
    # the verdict at half the step, over what the main verdict covers
    verdict = sub.judge(r)
    if spec.controller is not None and upto < sub.index.size:
        verdict = sub.judge(sub.residuals([sol.x])[0])
    say(f'  step check at h = {half:g} s: ' + ', '.join(
        f'{n}={v:.8g} (shift {d:.2g})' for n, v, d in zip(spec.names, sol.x, shift))
        + f', residual {res:.3g}, in {time.monotonic() - started:.1f} s (CPU '
        f'{time.process_time() - cpu:.1f} s)')
    return {'half_step': half, 'values': sol.x.tolist(), 'shift': shift.tolist(),
            'residual': res, 'widening': 'intervals widened by 2 x shift',
            'verdict': {**verdict, 'step': half}}


#: Rounds of refinement of the global profile, and the minima refined in each.
REFINE_ROUNDS, REFINE_MINIMA = 3, 8


def local_minima(cost: np.ndarray) -> np.ndarray:
    """Indices of the grid points lower than both neighbours (an end: than its one)."""
    c = np.asarray(cost, dtype=float)
    c = np.where(np.isfinite(c), c, np.inf)
    if c.size < 2:
        return np.arange(c.size)
    left = np.concatenate([[True], c[1:] < c[:-1]])
    right = np.concatenate([c[:-1] <= c[1:], [True]])
    return np.flatnonzero(left & right & np.isfinite(c))


def _global_profile(ev: Evaluator, x: np.ndarray, j: int, bounds: np.ndarray, n: int,
                    upto: int) -> tuple[np.ndarray, np.ndarray]:
    """The residual over name ``j`` (the others at ``x``) on ``n`` points over its bounds,
    refined REFINE_ROUNDS times around the REFINE_MINIMA lowest local minima (each side
    halved): a basin narrower than the first spacing is resolved where it matters, and the
    minima are counted on the refined grid."""
    grid = np.linspace(bounds[j, 0], bounds[j, 1], n)

    def costs(name: str, g: np.ndarray) -> np.ndarray:
        pts = np.repeat(x[None], g.size, axis=0)
        pts[:, j] = g
        return ev.costs(name, pts, upto)

    cost = costs('profile_coarse', grid)
    for k in range(REFINE_ROUNDS):
        mins = local_minima(cost)
        mins = mins[np.argsort(cost[mins], kind='stable')][:REFINE_MINIMA]
        new = set()
        for i in mins.tolist():
            for nb in (i - 1, i + 1):
                if 0 <= nb < grid.size:
                    new.add(0.5 * (grid[i] + grid[nb]))
        new_g = np.array(sorted(new - set(grid.tolist())))
        if new_g.size == 0:
            break
        grid = np.concatenate([grid, new_g])
        cost = np.concatenate([cost, costs(f'profile_refine{k + 1}', new_g)])
        order = np.argsort(grid, kind='stable')
        grid, cost = grid[order], cost[order]
    return grid, cost


def _profile(problem: Problem, ev: Evaluator, local: Local, spec: FitSpec,
             bounds: np.ndarray, x: np.ndarray, half: np.ndarray, s2: float, upto: int,
             coarse: np.ndarray, coarse_cost: np.ndarray) -> dict[str, Any]:
    """The coarse (others fixed, given) and fine (others re-optimised) profiles over
    alpha, and the profile interval."""
    from scipy.stats import chi2

    j = spec.names.index('fractional_order') if 'fractional_order' in spec.names else 0
    lo, hi = bounds[j]
    width = half[j] if math.isfinite(half[j]) and half[j] > 0 else 0.01 * (hi - lo)
    width = max(4.0 * width, 1e-9 * (hi - lo))
    fine = np.unique(np.clip(np.linspace(x[j] - width, x[j] + width, spec.fine_points), lo, hi))
    if len(spec.names) == 1:
        fine_cost = ev.costs('profile_fine', fine[:, None], upto)
    else:
        fine_cost = []
        for v in fine:
            sol = local.solve(x, max(3, spec.max_nfev // 4), fixed={j: float(v)})
            fine_cost.append(float(sol.cost))
        fine_cost = np.array(fine_cost)
    r = local.fun(x)
    ssr_min = min(float(r @ r), 2.0 * float(np.nanmin(fine_cost)))
    level = ssr_min + s2 * float(chi2.ppf(0.95, 1))
    interval = _profile_interval(fine, 2 * fine_cost, level)
    # every alpha of either profile within the level (the coarse one an upper bound: others
    # held): their hull, and how many separate pieces of the grid it takes
    grid = np.concatenate([coarse, fine])
    ssr = 2 * np.concatenate([coarse_cost, fine_cost])
    order = np.argsort(grid, kind='stable')
    inside = ssr[order] <= level
    pieces = int(np.sum(inside[1:] & ~inside[:-1]) + inside[0]) if inside.size else 0
    if inside.any():
        g = grid[order][inside]
        interval = [min(float(g[0]), *(interval or [g[0]])),
                    max(float(g[-1]), *(interval or [g[-1]]))]
    scale = 4 * upto if spec.objective == 'trajectory' else 4   # entries of a residual row
    return {'name': spec.names[j], 'index': j, 'coarse': coarse.tolist(),
            'coarse_residual': np.sqrt(2 * coarse_cost / scale).tolist(),
            'fine': fine.tolist(), 'fine_residual': np.sqrt(2 * fine_cost / scale).tolist(),
            'level_residual': math.sqrt(level / scale), 'interval': interval,
            'local_minima': int(local_minima(coarse_cost).size), 'pieces': pieces,
            'others': 'held at the estimate (coarse); re-optimised (fine)'}
