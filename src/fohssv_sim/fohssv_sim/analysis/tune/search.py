"""The search: each generation run as a chunked job and scored, resumable, the winner checked
at half the step."""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..gainmap.evaluate import decode_row, evaluate_points
from ..gainmap.spec import OUTCOME_RANK, OUTCOMES
from ..orbits import METHOD
from ..sweep import chunk_path, read_chunk_rows, run_chunks
from .spec import (
    _INT,
    _STR,
    CHECK_RTOL,
    ROW_FIELDS,
    SCORE_TEXT,
    TuneError,
    TuneSpec,
    _controller,
    metric_column,
)


# -- one chunk of a generation ---------------------------------------------------------------
def run_candidates(job: dict[str, Any], indices: Sequence[int], *,
                   progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """The rows of the points ``indices`` of one generation's job (one Dask task).

    ``job``: ``{'tune': spec dict, 'candidates': [values, ...], 'step_factor': f}``; point
    ``i`` is candidate ``i // S`` in scenario ``i % S`` (S scenarios). Deterministic.
    """
    spec = TuneSpec.from_dict(job['tune'])
    scenarios = spec.scenarios()
    n = len(scenarios)
    info = [(i, *divmod(i, n)) for i in indices]
    params = [spec.params_for(*scenarios[s], job['step_factor']) for _, _, s in info]
    ctls = [_controller(spec, job['candidates'][c], p) for (_, c, _), p in zip(info, params)]
    scored = evaluate_points(spec, params, ctls, [(c, scenarios[s][1]) for _, c, s in info],
                             settle_to_final=True, progress=progress)
    return [{'point': i, 'candidate': c, 'scenario': s, 'alpha': scenarios[s][0],
             'speed': scenarios[s][1], **row} for (i, c, s), row in zip(info, scored)]


def _decode(r: dict[str, str]) -> dict[str, Any]:
    return decode_row(r, _INT, _STR)


def _chunks(spec: TuneSpec, n_candidates: int, step_factor: float) -> list[list[int]]:
    """Points of a generation split into batchable chunks (candidate-major)."""
    from ...batch import group_points

    sc = spec.scenarios()
    params = [spec.params_for(*sc[i % len(sc)], step_factor)
              for i in range(n_candidates * len(sc))]
    chunks = []
    for idx in group_points(params).values():
        for s in range(0, len(idx), spec.chunk_size):
            chunks.append(idx[s:s + spec.chunk_size])
    return sorted(chunks, key=lambda c: c[0])


# -- the score -------------------------------------------------------------------------------
def score(rows: Sequence[dict[str, Any]], spec: TuneSpec, affine: bool) -> dict[str, Any]:
    """The lexicographic worst case of one candidate's ``rows`` (see the module docstring):
    ``outcome`` (worst), ``not_steady`` (count), ``margin`` (min alpha_c - alpha; None for a
    law without a linearisation), ``shortfall``, ``metric`` (worst objective value), ``key``
    (the tuple that orders) and ``value`` (the scalar the optimiser minimises)."""
    if not rows:
        return {'outcome': 'none', 'not_steady': 0, 'margin': None, 'shortfall': 0.0,
                'metric': math.nan, 'key': (0, 0.0, math.nan), 'value': math.nan,
                'scenarios': 0, 'linearised': affine}
    n = len(spec.scenarios())
    worst = max(rows, key=lambda r: OUTCOME_RANK[r['outcome']])['outcome']
    bad = sum(r['outcome'] != 'steady' for r in rows)
    level1 = OUTCOME_RANK[worst] * (n + 1) + bad
    margin = None
    shortfall = 0.0
    if affine:
        m = [r['alpha_c'] - r['alpha'] for r in rows]
        margin = math.nan if any(math.isnan(v) for v in m) else float(min(m))
        shortfall = math.inf if math.isnan(margin) else max(0.0, spec.min_margin - margin)
    values = [r[metric_column(spec)] for r in rows]
    metric = math.inf if any(math.isnan(v) for v in values) else float(max(values))
    if shortfall > 0:
        frac = 3.0 if math.isinf(shortfall) else 2.0 + shortfall / (1.0 + shortfall)
    else:
        frac = 1.0 if math.isinf(metric) else metric / (1.0 + metric)
    return {'outcome': worst, 'not_steady': bad, 'margin': margin, 'shortfall': shortfall,
            'metric': metric, 'key': (level1, shortfall, metric), 'value': 4.0 * level1 + frac,
            'scenarios': len(rows), 'linearised': affine}


def _invalid_value(spec: TuneSpec) -> float:
    """The score of a candidate that does not build (worse than any that runs)."""
    n = len(spec.scenarios())
    return 4.0 * (len(OUTCOMES) * (n + 1)) + 3.0


# -- the search ------------------------------------------------------------------------------
def _clean(v: Any) -> Any:
    """JSON-safe: NaN -> None, +-inf -> 'inf' / '-inf' (strict JSON has neither)."""
    if isinstance(v, float):
        if math.isnan(v):
            return None
        if math.isinf(v):
            return 'inf' if v > 0 else '-inf'
        return v
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    return v


def _write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_suffix('.tmp')
    tmp.write_text(json.dumps(_clean(data), indent=1, allow_nan=False) + '\n')
    os.replace(tmp, path)


class _Generations:
    """The objective function differential_evolution calls once per generation: runs (or
    reads back) the generation's chunked job, scores its candidates, records the history."""

    def __init__(self, spec: TuneSpec, out: Path, *, scheduler: str | None, workers: int,
                 client: Any, progress: Callable[[int, int, float], None] | None,
                 on_generation: Callable[[dict[str, Any]], None] | None,
                 record: dict[str, Any]) -> None:
        self.spec, self.out = spec, out
        self.scheduler, self.workers, self.client = scheduler, workers, client
        self.progress, self.on_generation, self.record = progress, on_generation, record
        self._cluster = None
        self._own_client = None
        self.generation = 0
        self.rows: dict[tuple[int, int], list[dict[str, Any]]] = {}
        self.affine: bool | None = None
        self.best: dict[str, Any] | None = None

    # a Dask client made only when some generation has work (a resumed search may have none)
    def _dask(self) -> Any:
        if self.client is not None:
            return self.client
        if self._own_client is None:
            from dask.distributed import Client

            from ..cluster import local_cluster

            if self.scheduler:
                self._own_client = Client(self.scheduler, timeout='20s')
            else:
                self._cluster = local_cluster(self.workers or os.cpu_count() or 1)
                self._own_client = Client(self._cluster)
        return self._own_client

    def close(self) -> None:
        if self._own_client is not None:
            self._own_client.close()
        if self._cluster is not None:
            self._cluster.close()

    def run_job(self, folder: Path, candidates: list[dict[str, float]], step_factor: float,
                what: dict[str, Any]) -> tuple[list[dict[str, Any]], int, int]:
        """Run (or resume) one chunked job of ``candidates`` x scenarios into ``folder``."""
        from ... import __version__

        spec = self.spec
        job = {'tune': spec.identity(), 'candidates': candidates, 'step_factor': step_factor,
               **what}
        chunks = _chunks(spec, len(candidates), step_factor)
        p0 = spec.params_for(*spec.scenarios()[0], step_factor)
        sidecar = {'spec': job, 'chunks': chunks, 'step': p0.step, 'solver': p0.solver,
                   'model': p0.model, 'classification': METHOD,
                   'fohssv_version': __version__, 'python': sys.version.split()[0]}
        done = (folder / 'job.json').exists() and all(
            chunk_path(folder, k).exists() for k in range(len(chunks)))
        try:
            computed, reused = run_chunks(
                folder, 'job.json', sidecar, chunks, run_candidates, (job,), ROW_FIELDS,
                progress=self.progress, client=None if done else self._dask())
        except ValueError as e:
            raise TuneError(str(e)) from None
        return read_chunk_rows(folder, len(chunks), _decode), computed, reused

    def _is_affine(self, values: dict[str, float]) -> bool:
        if self.affine is None:
            p = self.spec.params_for(*self.spec.scenarios()[0])
            self.affine = _controller(self.spec, values, p).affine() is not None
        return self.affine

    def __call__(self, x: np.ndarray) -> np.ndarray:
        spec, g = self.spec, self.generation
        X = np.atleast_2d(np.asarray(x, dtype=float).T)        # (P, d)
        values = [spec.values(row) for row in X]
        valid, errors = [], {}
        params = [spec.params_for(a, v) for a, v in spec.scenarios()]
        for c, v in enumerate(values):
            try:
                for p in params:
                    _controller(spec, v, p)
                valid.append(c)
            except TuneError as e:
                errors[c] = str(e)
        rows, computed, reused = [], 0, 0
        if valid:
            rows, computed, reused = self.run_job(
                self.out / 'generations' / f'gen_{g:04d}', [values[c] for c in valid], 1.0,
                {'generation': g})
        by_c: dict[int, list[dict[str, Any]]] = {}
        for r in rows:
            by_c.setdefault(valid[r['candidate']], []).append(r)
        entries, f = [], np.empty(len(values))
        for c, v in enumerate(values):
            if c in errors:
                f[c] = _invalid_value(spec)
                entries.append({'candidate': c, 'values': v, 'valid': False,
                                'error': errors[c], 'value': f[c]})
                continue
            rs = sorted(by_c.get(c, []), key=lambda r: r['scenario'])
            self.rows[g, c] = rs
            s = score(rs, spec, self._is_affine(v))
            f[c] = s['value']
            entries.append({'candidate': c, 'values': v, 'valid': True, **_public(s)})
            if self.best is None or s['value'] < self.best['score']['value']:
                self.best = {'generation': g, 'candidate': c, 'values': v, 'score': s}
        best = int(np.argmin(f))
        gen = {'generation': g, 'computed_chunks': computed, 'reused_chunks': reused,
               'best': best, 'best_value': float(f[best]),
               'best_so_far': _public(self.best['score']) if self.best else None,
               'candidates': entries}
        self.record['generations'].append(gen)
        _write_json(self.out / 'tune.json', self.record)
        if self.on_generation is not None:
            self.on_generation(gen)
        self.generation += 1
        return f


def _public(s: dict[str, Any]) -> dict[str, Any]:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in s.items()}


@dataclass
class TuneResult:
    """A finished search: its record (``tune.json``), the winner's per-scenario rows and,
    with the step check, the half-step rows."""

    record: dict[str, Any]
    winner_rows: list[dict[str, Any]]
    check_rows: list[dict[str, Any]] = field(default_factory=list)
    computed_chunks: int = 0
    reused_chunks: int = 0

    @property
    def spec(self) -> TuneSpec:
        return TuneSpec.from_dict(self.record['spec'])

    @property
    def winner(self) -> dict[str, Any]:
        return self.record['winner']


def _optimizer_text(spec: TuneSpec) -> dict[str, Any]:
    import scipy

    return {'name': 'scipy.optimize.differential_evolution', 'scipy': scipy.__version__,
            'strategy': 'best1bin', 'updating': 'deferred (one batched job per generation)',
            'init': 'Latin hypercube (scipy.stats.qmc, seeded)', 'polish': False,
            'tol': 0.0, 'population': spec.population_size, 'generations': spec.generations,
            'mutation': list(spec.mutation), 'recombination': spec.recombination,
            'seed': spec.seed}


def _start_record(spec: TuneSpec, out: Path) -> dict[str, Any]:
    path = out / 'tune.json'
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except ValueError:
            old = {}
        try:
            same = _clean(TuneSpec.from_dict(old['spec']).identity()) == _clean(
                spec.identity())
        except (KeyError, TypeError, ValueError):
            same = False
        if not same:
            raise TuneError(f'{out} holds a different search (see {path}); choose another '
                            '--out or delete that folder')
    p0 = spec.params_for(*spec.scenarios()[0])
    return {'spec': spec.to_dict(), 'status': 'running', 'optimizer': _optimizer_text(spec),
            'score': SCORE_TEXT, 'step': p0.step, 'solver': p0.solver, 'model': p0.model,
            'planing_form': p0.planing_form, 'sample_every': spec.every(p0.step),
            'classification': METHOD, 'generations': []}


def run_tune(spec: TuneSpec, out: Path, *, scheduler: str | None = None, workers: int = 0,
             client: Any = None, progress: Callable[[int, int, float], None] | None = None,
             on_generation: Callable[[dict[str, Any]], None] | None = None,
             check_progress: Callable[[int, int, float], None] | None = None) -> TuneResult:
    """Run (or resume) the search ``spec`` into folder ``out``; see the module docstring.

    ``progress(done, total, elapsed)`` counts the points of each generation;
    ``on_generation(entry)`` is called after each generation with its ``tune.json`` entry.

    Raises:
        TuneError: an invalid spec, or ``out`` holds another search.
    """
    from scipy.optimize import differential_evolution
    from scipy.stats import qmc

    spec.validate()
    out.mkdir(parents=True, exist_ok=True)
    record = _start_record(spec, out)
    gens = _Generations(spec, out, scheduler=scheduler, workers=workers, client=client,
                        progress=progress, on_generation=on_generation, record=record)
    lo = np.array([b.search()[0] for b in spec.bounds])
    hi = np.array([b.search()[1] for b in spec.bounds])
    init = qmc.scale(qmc.LatinHypercube(d=len(spec.bounds), seed=spec.seed).random(
        spec.population_size), lo, hi)
    try:
        try:
            res = differential_evolution(
                gens, list(zip(lo, hi)), strategy='best1bin', maxiter=spec.generations - 1,
                init=init, mutation=spec.mutation, recombination=spec.recombination,
                seed=spec.seed, tol=0.0, atol=0.0, polish=False, updating='deferred',
                vectorized=True)
        except RuntimeError as e:
            # scipy wraps a ValueError raised in a generation (TuneError is one: e.g. a
            # generation folder that holds another job) in a RuntimeError about the map-like
            # callable; hand back the TuneError itself (one line, exit 2 in the CLI)
            if isinstance(e.__cause__, TuneError):
                raise e.__cause__ from None
            raise
        best = gens.best
        if best is None:
            first = next(c for g in record['generations'] for c in g['candidates'])
            raise TuneError(f"no candidate builds the controller, e.g. {first['error']}")
        winner_rows = gens.rows[best['generation'], best['candidate']]
        record['winner'] = {**{k: best[k] for k in ('generation', 'candidate', 'values')},
                            'gains': {**spec.gains, **best['values']},
                            'score': _public(best['score']), 'scenarios': winner_rows}
        record['optimizer']['message'] = str(res.message)
        record['optimizer']['generations_run'] = len(record['generations'])
        record['optimizer']['evaluations'] = sum(len(g['candidates'])
                                                 for g in record['generations'])
        check_rows: list[dict[str, Any]] = []
        if spec.check_step:
            gens.progress = check_progress
            check_rows = _check_step(gens, best, winner_rows, record)
    finally:
        gens.close()
    record['status'] = 'done'
    _write_json(out / 'tune.json', record)
    computed = sum(g['computed_chunks'] for g in record['generations'])
    reused = sum(g['reused_chunks'] for g in record['generations'])
    return TuneResult(record, winner_rows, check_rows, computed, reused)


def _num(v: Any) -> float:
    """A record's number (None, as JSON writes NaN, is NaN)."""
    return math.nan if v is None else float(v)


def _relative_change(a: float, b: float) -> float:
    """|b - a| / |a| (0 when both are equal, infinities included; inf when only one is
    finite or a is 0 and b is not)."""
    a, b = _num(a), _num(b)
    if a == b or (math.isnan(a) and math.isnan(b)):
        return 0.0
    if not (math.isfinite(a) and math.isfinite(b)) or a == 0.0:
        return math.inf
    return abs(b - a) / abs(a)


def step_flags(rows: Sequence[dict[str, Any]], half: Sequence[dict[str, Any]], key: str,
               rtol: float = CHECK_RTOL) -> tuple[list[dict[str, Any]], list[float]]:
    """The scenarios not converged in step: ``rows`` at the step and ``half`` at half of it
    (the same scenarios, in order); flagged where the outcome changes or the metric column
    ``key`` moves by more than ``rtol`` (relative). Returns (flags, each scenario's
    relative metric change)."""
    flagged, changes = [], []
    for r, h in zip(rows, half):
        change = _relative_change(r[key], h[key])
        changes.append(change)
        if r['outcome'] != h['outcome'] or change > rtol:
            flagged.append({'scenario': r['scenario'], 'alpha': r['alpha'],
                            'speed': r['speed'], 'outcome': r['outcome'],
                            'half_step_outcome': h['outcome'], 'metric': r[key],
                            'half_step_metric': h[key], 'metric_change': change})
    return flagged, changes


def _check_step(gens: _Generations, best: dict[str, Any], rows: list[dict[str, Any]],
                record: dict[str, Any]) -> list[dict[str, Any]]:
    """Re-run the winner at half the step; flag the scenarios whose outcome changes or whose
    objective metric moves by more than :data:`CHECK_RTOL` (:func:`step_flags`), and score
    it over the others."""
    spec = gens.spec
    key = metric_column(spec)
    # a folder per winner: a search continued with a larger budget may have a new winner
    # (the old one's check stays, and is reused if it wins again)
    folder = gens.out / 'check_step' / f"gen_{best['generation']:04d}_{best['candidate']:03d}"
    half, _, _ = gens.run_job(folder, [best['values']], 0.5,
                              {'check': 'winner at half step'})
    half.sort(key=lambda r: r['scenario'])
    flagged, changes = step_flags(rows, half, key)
    out = {f['scenario'] for f in flagged}
    keep = [r for r in rows if r['scenario'] not in out]
    record['check_step'] = {
        'step': half[0]['step'] if half else None, 'metric': key, 'metric_rtol': CHECK_RTOL,
        'flagged': flagged, 'converged_scenarios': len(keep),
        'max_metric_change': max(changes, default=0.0),
        'score_converged': _public(score(keep, spec, gens._is_affine(best['values']))),
        'half_step': half}
    return half


def load_tune(out: Path) -> dict[str, Any]:
    """The record of a (finished or partial) search folder."""
    return json.loads((out / 'tune.json').read_text())
