"""The search: populations on Dask (:class:`Evaluator`), their points (Latin hypercube,
lines), and the local least-squares stage (:class:`Local`).

Pure: numpy, scipy, dask; never imports rclpy or the CLI.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .problem import Problem

# -- population on Dask ----------------------------------------------------------------------
POP_FIELDS = ('point', 'values', 'cost', 'residual')


def population_task(problem: Problem, values: list[list[float]], upto: int,
                    indices: Sequence[int], progress: Callable[[float], None] | None = None,
                    threads: int = 1) -> list[dict[str, Any]]:
    """The rows of the points ``indices`` of ``values`` (one Dask task, one batched call;
    ``threads`` > 1 splits it over threads, in-process only)."""
    pts = [values[i] for i in indices]
    R = problem.residuals(pts, upto, threads)
    if progress is not None:
        progress(1.0)
    return [{'point': i, 'values': list(map(float, pts[j])), 'cost': 0.5 * float(R[j] @ R[j]),
             'residual': problem.norm(R[j])} for j, i in enumerate(indices)]


def _decode_row(r: dict[str, str]) -> dict[str, Any]:
    return {'point': int(r['point']), 'values': [float(v) for v in r['values'].split(';')],
            'cost': float(r['cost']), 'residual': float(r['residual'])}


class Evaluator:
    """Costs of many points: on Dask through :func:`.sweep.run_chunks` (chunk files under
    ``out``, resumable) or, with ``client=None`` and ``workers < 0``, in this process."""

    def __init__(self, problem: Problem, out: Path, client: Any,
                 progress: Callable[[int, int, float], None] | None,
                 sidecar: dict[str, Any], threads: int = 1) -> None:
        self.problem, self.out, self.client, self.progress = problem, out, client, progress
        self.sidecar = sidecar
        self.threads = threads
        self.jobs = 0
        self.points = 0

    def costs(self, name: str, values: np.ndarray, upto: int) -> np.ndarray:
        from ..sweep import read_chunk_rows, run_chunks

        vals = [list(map(float, v)) for v in values]
        self.points += len(vals)
        if self.client is None:
            rows = population_task(self.problem, vals, upto, list(range(len(vals))),
                                   threads=self.threads)
        else:
            cs = self.problem.spec.chunk_size
            chunks = [list(range(s, min(s + cs, len(vals)))) for s in range(0, len(vals), cs)]
            folder = self.out / name
            side = {'spec': {**self.sidecar, 'job': name, 'upto': upto, 'values': vals},
                    'chunks': chunks}
            run_chunks(folder, 'population.json', side, chunks, population_task,
                       (self.problem, vals, upto), POP_FIELDS, client=self.client,
                       progress=self.progress)
            rows = read_chunk_rows(folder, len(chunks), _decode_row)
        self.jobs += 1
        rows.sort(key=lambda r: r['point'])
        return np.array([r['cost'] for r in rows])


def latin(bounds: np.ndarray, n: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    u = qmc.LatinHypercube(d=len(bounds), seed=seed).random(n)
    return np.column_stack([_spread(bounds[j], u[:, j]) for j in range(len(bounds))])


def _spread(b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Values in the bounds ``b`` at fractions ``u``: logarithmic when the bounds are positive
    and span a decade or more, else linear."""
    lo, hi = float(b[0]), float(b[1])
    if lo > 0 and hi / lo >= 10:
        return lo * (hi / lo) ** u
    return lo + u * (hi - lo)


def lines(bounds: np.ndarray, around: np.ndarray, n: int, seen: np.ndarray) -> np.ndarray:
    """``around`` and, per parameter the last stage could not see (a zero Jacobian column:
    e.g. the planing offset before the first contact), a line of n values over its bounds with
    the others fixed. A parameter it saw is not searched again over its bounds: at a doubled
    horizon its basin is narrower than any line's spacing, and the warm start is what keeps
    it (the coarse profile at the end is the last global check)."""
    p = len(bounds)
    pts = [around]
    for j in range(p):
        if seen[j]:
            continue
        for v in _spread(bounds[j], np.linspace(0.0, 1.0, max(2, n))):
            x = around.copy()
            x[j] = v
            pts.append(x)
    return np.array(pts)


# -- local stage ------------------------------------------------------------------------------
#: Termination of the local stage (scipy's xtol, ftol, gtol): far below any interval, and
#: reached in a handful of iterations from a population's best point.
LOCAL_TOL = 1e-10


class Local:
    """least_squares with the forward-difference Jacobian: the p perturbed points in one
    batched call. With ``threads`` > 1 every new point is evaluated together with its p
    perturbed points (speculatively: least_squares asks for the Jacobian at each accepted
    point), split over the threads, so an iteration costs one simulation of wall time."""

    def __init__(self, problem: Problem, bounds: np.ndarray, upto: int, threads: int = 1
                 ) -> None:
        self.problem, self.bounds, self.upto = problem, bounds, upto
        self.threads = max(1, int(threads))
        rel = 1e-7 if problem.spec.objective == 'trajectory' else 1e-3
        self.h = rel * (bounds[:, 1] - bounds[:, 0])
        self.cache: dict[tuple, tuple[np.ndarray, np.ndarray | None]] = {}
        self.evaluations = 0

    def _batch(self, pts: list[np.ndarray]) -> np.ndarray:
        self.evaluations += len(pts)
        return self.problem.residuals(pts, self.upto, self.threads)

    def _perturbed(self, x: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        steps, pts = [], []
        for j in range(x.size):
            h = self.h[j] if x[j] + self.h[j] <= self.bounds[j, 1] else -self.h[j]
            e = x.copy()
            e[j] += h
            pts.append(e)
            steps.append(h)
        return pts, np.array(steps)

    def fun(self, x: np.ndarray) -> np.ndarray:
        key = tuple(x.tolist())
        if key not in self.cache:
            if self.threads > 1:
                pts, steps = self._perturbed(x)
                R = self._batch([x, *pts])
                self.cache = {key: (R[0], ((R[1:] - R[0]) / steps[:, None]).T)}
            else:
                self.cache = {key: (self._batch([x])[0], None)}
        return self.cache[key][0]

    def jac(self, x: np.ndarray) -> np.ndarray:
        r0 = self.fun(x)
        key = tuple(x.tolist())
        J = self.cache[key][1]
        if J is None:
            pts, steps = self._perturbed(x)
            R = self._batch(pts)
            J = ((R - r0) / steps[:, None]).T
            self.cache = {key: (r0, J)}
        return J

    def solve(self, x0: np.ndarray, max_nfev: int, fixed: dict[int, float] | None = None):
        from scipy.optimize import least_squares

        lo, hi = self.bounds[:, 0], self.bounds[:, 1]
        x0 = np.clip(x0, lo, hi)
        if fixed:
            free = np.array([j not in fixed for j in range(x0.size)])

            def full(y):
                x = x0.copy()
                x[free] = y
                for j, v in fixed.items():
                    x[j] = v
                return x

            r = least_squares(lambda y: self.fun(full(y)), x0[free],
                              jac=lambda y: self.jac(full(y))[:, free],
                              bounds=(lo[free], hi[free]), x_scale=hi[free] - lo[free],
                              method='trf', max_nfev=max_nfev, xtol=LOCAL_TOL,
                              ftol=LOCAL_TOL, gtol=LOCAL_TOL)
            r.x = full(r.x)
            return r
        return least_squares(self.fun, x0, jac=self.jac, bounds=(lo, hi), x_scale=hi - lo,
                             method='trf', max_nfev=max_nfev, xtol=LOCAL_TOL, ftol=LOCAL_TOL,
                             gtol=LOCAL_TOL)
