"""Robust controller synthesis over a V-alpha envelope: ``fohssv tune`` (issue 24;
docs/tune.md).

A global search over numeric parameters of a controller plugin (each between bounds, linear
or log-scaled) for the best **worst case over an envelope** of scenarios (the grid of V and
alpha). The optimiser is :func:`scipy.optimize.differential_evolution` (already a pinned
dependency; why it and not CMA-ES: docs/tune.md), run with ``vectorized=True,
updating='deferred'``: it asks for a whole generation at once, and each generation runs as one
chunked Dask job of batched solver calls (the gain map's evaluation,
:func:`.gainmap.evaluate_points`, through the sweeps' chunk machinery,
:func:`.sweep.run_chunks`: chunk files, resume, progress per point).

A candidate's **score** is lexicographic over its scenarios (:func:`score`):

1. every scenario steady first: the worst outcome (steady < drifting < periodic < chaotic <
   diverged), then the number of scenarios that are not steady;
2. then, for affine laws (the linearised closed loop is the 4-state commensurate system of
   eq. 30), the Matignon margin ``min(alpha_c(V) - alpha)`` over the envelope, as its
   shortfall below ``min_margin`` (a margin at or above it ties);
3. then the objective: the worst ``peak_fp``, ``settle_time`` or ``effort_rms`` over the
   envelope (``peak-fp`` / ``settle`` / ``effort``).

The optimiser needs one number: :func:`score` maps the three levels to a scalar that orders
exactly as the tuple does (integer level x 4 plus a fraction in [0, 3)).

**Resume**: the search is deterministic for a seed (a Latin-hypercube first generation from
the seed, DE's own generator from it too), and each generation's rows are kept in
``OUT/generations/gen_NNNN/``; a rerun replays the search, reading back the generations that
are done (their scores come from the same CSV rows either way), so an interrupted search ends
with the same winner as an uninterrupted one. The budget is not part of a search's identity
(:meth:`TuneSpec.identity`): a rerun with a larger budget continues the same search.

**Step check** (``check_step``): the winner is re-run at half the step in every scenario;
scenarios whose outcome changes, or whose objective metric moves by more than
:data:`CHECK_RTOL`, are flagged as not converged and left out of the winner's reported score
(listed, not scored).

Pure: numpy, scipy, dask, matplotlib (Agg); never imports rclpy or the CLI.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..params import ModelParameters, ParameterError
from .gainmap import (
    OUTCOME_COLORS,
    OUTCOME_RANK,
    OUTCOMES,
    controller_parameters,
    decode_row,
    evaluate_points,
    scheduled_gains,
)
from .orbits import METHOD, STEADY_RTOL
from .sweep import chunk_path, read_chunk_rows, run_chunks

__all__ = ['OBJECTIVES', 'Bound', 'TuneSpec', 'TuneError', 'TuneResult', 'score',
           'run_tune', 'run_candidates', 'load_tune', 'plot_envelope', 'plot_history',
           'summary_lines', 'step_flags', 'ROW_FIELDS', 'MIN_POPULATION',
           'CHECK_RTOL']

#: ``--objective`` names and the row column each takes the worst (largest) of.
OBJECTIVES = {'peak-fp': 'peak_fp', 'settle': 'settle_time', 'effort': 'effort_rms'}
OBJECTIVE_TEXT = {'peak-fp': 'peak |Fp| (m²/s²)', 'settle': 'time to settle (s)',
                  'effort': 'RMS of δc (rad)'}
#: differential_evolution needs at least 5 members in a given initial population.
MIN_POPULATION = 5
def metric_column(spec: TuneSpec) -> str:
    """The row column the objective takes the worst of: ``peak_fp_window`` (after the
    transient) for peak-fp with ``peak_after_transient``, else :data:`OBJECTIVES`'."""
    if spec.objective == 'peak-fp' and spec.peak_after_transient:
        return 'peak_fp_window'
    return OBJECTIVES[spec.objective]


#: The step check flags a scenario whose objective metric moves by more than this (relative)
#: at half the step, as well as one whose outcome changes.
CHECK_RTOL = 0.01

ROW_FIELDS = ('point', 'candidate', 'scenario', 'alpha', 'speed', 'outcome', 'label', 'kind',
              'period', 'k01', 'amplitude', 'failed', 'peak_fp', 'peak_fp_window',
              'settle_time', 'effort_rms', 'alpha_c', 'eq_w', 'eq_dc', 'step', 'path')
_INT = ('point', 'candidate', 'scenario', 'period')
_STR = ('outcome', 'label', 'kind', 'path')

SCORE_TEXT = ('lexicographic worst case over the envelope: (1) worst outcome, then the number '
              'of scenarios not steady; (2) affine laws: shortfall of min(alpha_c - alpha) '
              'below min_margin; (3) the worst objective metric. score = 4 * level1 + '
              '(2 + s/(1+s) if the shortfall s > 0 else m/(1+m)), m the metric')


class TuneError(ValueError):
    """A search that cannot run as specified (the message names the value and what is
    allowed)."""


@dataclass(frozen=True)
class Bound:
    """A tuned parameter: ``name`` searched in [``low``, ``high``] (in log10 when ``log``)."""

    name: str
    low: float
    high: float
    log: bool = False

    def search(self) -> tuple[float, float]:
        """The interval the optimiser searches."""
        return (math.log10(self.low), math.log10(self.high)) if self.log else (
            self.low, self.high)

    def value(self, x: float) -> float:
        """The parameter value of search coordinate ``x``."""
        return float(10.0 ** x) if self.log else float(x)

    def text(self) -> str:
        return f"{self.name}={self.low:g}:{self.high:g}{':log' if self.log else ''}"


@dataclass(frozen=True)
class TuneSpec:
    """Everything that defines a search's numbers (recorded in ``tune.json``).

    ``bounds``: the tuned parameters; ``gains``: the controller's other parameters (defaults
    otherwise); ``base``: model parameters shared by every scenario, without fractional_order
    and speed; the scenarios are ``envelope_speeds`` x ``envelope_alphas``. ``budget``:
    candidate evaluations at most (``population`` per generation; 0 = automatic, see
    :attr:`population_size`). Run settings as :class:`.gainmap.GainMapSpec`.
    """

    controller: str
    bounds: tuple[Bound, ...]
    envelope_speeds: tuple[float, ...]
    envelope_alphas: tuple[float, ...]
    gains: dict[str, Any] = field(default_factory=dict)
    base: dict[str, Any] = field(default_factory=dict)
    objective: str = 'peak-fp'
    budget: int = 60
    population: int = 0
    seed: int = 1
    min_margin: float = 0.02
    duration: float = 2.0
    transient: float = 1.5
    #: the peak-fp objective over the window after ``transient`` only (default: the whole
    #: run, start-up transient included)
    peak_after_transient: bool = False
    control_period: float | None = 1e-4
    sample_every: int = 0
    settle_band: float = 0.02
    chunk_size: int = 128
    check_step: bool = False
    steady_rtol: float = STEADY_RTOL
    rel_tol: float = 1e-3
    mutation: tuple[float, float] = (0.5, 1.0)
    recombination: float = 0.7

    # -- the search --------------------------------------------------------------------
    @property
    def population_size(self) -> int:
        """``population``, or 5 per tuned parameter, at most a quarter of the budget (so
        at least four generations run), at least :data:`MIN_POPULATION`."""
        if self.population:
            return self.population
        return max(MIN_POPULATION, min(5 * len(self.bounds), self.budget // 4))

    @property
    def generations(self) -> int:
        """Generations the budget allows (the first is the initial population)."""
        return self.budget // self.population_size

    def scenarios(self) -> list[tuple[float, float]]:
        """(alpha, V) of each scenario, V outer."""
        return [(a, v) for v in self.envelope_speeds for a in self.envelope_alphas]

    def params_for(self, alpha: float, speed: float, step_factor: float = 1.0
                   ) -> ModelParameters:
        p = ModelParameters.from_dict({**self.base, 'fractional_order': alpha,
                                       'speed': speed})
        return p if step_factor == 1.0 else p.replace(step=p.step * step_factor)

    def every(self, step: float) -> int:
        if self.sample_every:
            return self.sample_every
        if self.control_period is None:
            return 5
        return max(1, round(self.control_period / step))

    def values(self, x: Sequence[float]) -> dict[str, float]:
        """The tuned parameters' values at search point ``x``."""
        return {b.name: b.value(xi) for b, xi in zip(self.bounds, x)}

    def gains_for(self, values: dict[str, float], params: ModelParameters) -> dict[str, Any]:
        """All overrides of one candidate in one scenario (scheduling parameters set)."""
        return scheduled_gains(self.controller, {**self.gains, **values}, params)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d['bounds'] = [dataclasses.asdict(b) for b in self.bounds]
        for k in ('envelope_speeds', 'envelope_alphas', 'mutation'):
            d[k] = list(d[k])
        return d

    def identity(self) -> dict[str, Any]:
        """What defines the search's sequence of generations: everything but the budget
        (with the population made explicit), so a rerun with a larger budget continues the
        same search from its recorded generations, and but ``check_step`` (it only re-runs
        the winner after the search), so a rerun with ``--check-step`` checks the winner of
        the search already run instead of being refused or starting another."""
        d = self.to_dict()
        d.pop('budget')
        d.pop('check_step')
        if not self.peak_after_transient:      # the searches run before the option
            d.pop('peak_after_transient')
        d['population'] = self.population_size
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TuneSpec:
        d = dict(d)
        d['bounds'] = tuple(Bound(**b) for b in d['bounds'])
        for k in ('envelope_speeds', 'envelope_alphas', 'mutation'):
            d[k] = tuple(d[k])
        return cls(**d)

    # -- validation --------------------------------------------------------------------
    def validate(self) -> None:
        """Check names, bounds, the envelope and the budget before anything runs.

        Raises:
            TuneError: unknown controller or parameter (lists the controller's parameters),
                a bound outside the parameter's range (name, value, range, unit), an empty
                envelope, a budget below one population, bad run settings.
        """
        from .gainmap import GainMapError

        try:
            specs = controller_parameters(self.controller)
        except GainMapError as e:
            raise TuneError(str(e)) from None
        self._validate_bounds(specs)
        self._validate_envelope()
        self._validate_search()
        self._validate_run()

    def _validate_bounds(self, specs: dict[str, Any]) -> None:
        from ..control import load

        names = ', '.join(sorted(specs))
        follow = getattr(load(self.controller), 'scheduling', {})
        if not self.bounds:
            raise TuneError('nothing to tune: give --tune NAME=LOW:HIGH')
        seen: set[str] = set()
        for b in self.bounds:
            if b.name not in specs:
                raise TuneError(f'{self.controller} has no parameter {b.name!r}; its '
                                f'parameters: {names}')
            s = specs[b.name]
            if not s.numeric:
                raise TuneError(f'{self.controller} parameter {b.name!r} is not numeric')
            if b.name in follow:
                raise TuneError(f'{self.controller} parameter {b.name!r} follows the model '
                                f'parameter {follow[b.name]!r} in each scenario; it cannot '
                                'be tuned')
            if b.name in seen:
                raise TuneError(f'{b.name} is given twice in --tune')
            if b.name in self.gains:
                raise TuneError(f'{b.name!r} is tuned; do not also fix it with --gain')
            seen.add(b.name)
            if not (math.isfinite(b.low) and math.isfinite(b.high) and b.low < b.high):
                raise TuneError(f'{b.text()}: need finite bounds LOW < HIGH')
            if b.log and not b.low > 0:
                raise TuneError(f'{b.text()}: a log-scaled bound needs LOW > 0')
            for v in (b.low, b.high):
                try:
                    s.validate(v)
                except ParameterError:
                    unit = '' if s.unit in ('', '-') else f' {s.unit}'
                    raise TuneError(
                        f'{self.controller} parameter {b.name}={v:g} is outside its allowed '
                        f'range {s.range_text()}{unit}') from None
        for name in self.gains:
            if name not in specs:
                raise TuneError(f'{self.controller} has no parameter {name!r}; its '
                                f'parameters: {names}')

    def _validate_envelope(self) -> None:
        if not self.envelope_speeds or not self.envelope_alphas:
            raise TuneError('the envelope is empty: give at least one value to each of '
                            '--envelope-speeds (m/s) and --envelope-alphas')
        for a in self.envelope_alphas:
            if not 0 < a <= 1:
                raise TuneError(f'envelope alpha={a:g} is outside (0, 1]')
        for v in self.envelope_speeds:
            if not v > 0:
                raise TuneError(f'envelope speed V={v:g} m/s must be > 0')
        try:
            for a, v in self.scenarios():
                self.params_for(a, v)
        except ParameterError as e:
            raise TuneError(str(e)) from None

    def _validate_search(self) -> None:
        if self.objective not in OBJECTIVES:
            raise TuneError(f'objective {self.objective!r} is not one of '
                            f"{', '.join(OBJECTIVES)}")
        if self.budget < 1:
            raise TuneError(f'budget={self.budget} must be >= 1 (candidate evaluations)')
        if self.population and self.population < MIN_POPULATION:
            raise TuneError(f'population={self.population} must be >= {MIN_POPULATION}')
        if self.budget < self.population_size:
            raise TuneError(f'budget={self.budget} is below one generation of '
                            f'{self.population_size} candidates (the population)')
        if not (math.isfinite(self.min_margin) and self.min_margin >= 0):
            raise TuneError(f'min_margin={self.min_margin:g} must be >= 0')
        if self.chunk_size < 1:
            raise TuneError(f'chunk_size={self.chunk_size} must be >= 1')

    def _validate_run(self) -> None:
        if not (self.duration > 0 and 0 <= self.transient < self.duration):
            raise TuneError(f'need duration > transient >= 0 (got duration '
                            f'{self.duration:g} s, transient {self.transient:g} s)')
        if not self.settle_band > 0:
            raise TuneError(f'settle_band={self.settle_band:g} must be > 0')
        p = self.params_for(*self.scenarios()[0])
        mid = {b.name: b.value(sum(b.search()) / 2) for b in self.bounds}
        try:
            ctl = _controller(self, mid, p)
        except TuneError as e:
            raise TuneError(f'the fixed parameters do not build the controller: {e}') from None
        if self.control_period is None:
            if not getattr(ctl, 'stateless', True):
                raise TuneError(f'{self.controller} keeps internal state: give a control '
                                'period')
        else:
            from ..simulate import steps_per_period

            try:
                steps_per_period(self.control_period, p.step)
            except ValueError as e:
                raise TuneError(str(e)) from None


def _controller(spec: TuneSpec, values: dict[str, float], params: ModelParameters) -> Any:
    from ..control import load

    try:
        return load(spec.controller)(**spec.gains_for(values, params))
    except (ParameterError, TypeError, ValueError) as e:
        raise TuneError(str(e)) from None


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
    from ..batch import group_points

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

            from .cluster import local_cluster

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
        from .. import __version__

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


# -- reporting -------------------------------------------------------------------------------
def _num(v: Any) -> float:
    if v is None:
        return math.nan
    if isinstance(v, str):
        return float(v)
    return float(v)


def describe_score(s: dict[str, Any], spec: TuneSpec) -> str:
    """One line: worst outcome, scenarios not steady, margin, worst metric."""
    if not s.get('linearised'):
        m = 'n/a (no linearisation)'
    elif math.isnan(_num(s['margin'])):
        m = 'unknown (no equilibrium)'
    else:
        m = f"{_num(s['margin']):.4g}"
    return (f"worst {s['outcome']}, {s['not_steady']}/{s['scenarios']} scenario(s) not steady, "
            f'Matignon margin min(α_c − α) {m}, worst {OBJECTIVE_TEXT[spec.objective]} '
            f"{_num(s['metric']):.4g}")


def summary_lines(result: TuneResult) -> list[str]:
    """What the search found, as text."""
    rec, spec = result.record, result.spec
    opt = rec['optimizer']
    w = rec['winner']
    lines = [f"differential evolution: {opt['generations_run']} generation(s) of "
             f"{opt['population']} ({opt['evaluations']} candidates, budget {spec.budget}), "
             f"seed {spec.seed}; step {rec['step']:g} s, solver {rec['solver']}, "
             f"{len(spec.scenarios())} scenarios; {result.computed_chunks} chunks computed, "
             f'{result.reused_chunks} reused']
    vals = ', '.join(f'{k}={v:.6g}' for k, v in w['values'].items())
    # generations are numbered from 1 where shown (tune.json and the folders count from 0)
    lines.append(f"winner (generation {w['generation'] + 1}, candidate {w['candidate']}): "
                 f'{vals}')
    lines.append('  ' + describe_score(w['score'], spec))
    chk = rec.get('check_step')
    if chk is not None:
        lines.extend(_check_lines(chk, spec))
    return lines


def _check_lines(chk: dict[str, Any], spec: TuneSpec) -> list[str]:
    """The step check's lines of :func:`summary_lines`."""
    head = (f"step check (half step {chk['step']:g} s; flagged: outcome changes, or "
            f"{chk.get('metric', 'the metric')} moves by more than "
            f"{100 * chk.get('metric_rtol', CHECK_RTOL):g} %)")
    worst = _num(chk.get('max_metric_change', math.nan))
    if not chk['flagged']:
        return [f'{head}: every scenario keeps its outcome; largest metric change '
                f'{100 * worst:.2g} %']

    def one(f: dict[str, Any]) -> str:
        change = _num(f.get('metric_change', math.nan))
        moved = '' if math.isnan(change) else f', metric {100 * change:.3g} %'
        return (f"V={f['speed']:g}, α={f['alpha']:g}: {f['outcome']} -> "
                f"{f['half_step_outcome']}{moved}")

    return [f"{head}: {len(chk['flagged'])} scenario(s) not converged, flagged and not "
            'scored: ' + '; '.join(one(f) for f in chk['flagged']),
            f"  over the {chk['converged_scenarios']} converged scenario(s): "
            + describe_score(chk['score_converged'], spec)]


def plot_envelope(record: dict[str, Any], stem: Path, label: str = '') -> list[Path]:
    """The winner's envelope map: class per V-alpha cell, annotated with alpha_c - alpha;
    cells flagged by the step check hatched. PNG and SVG ``<stem>.png/.svg``."""
    from .figures import pyplot, save, titled
    from .gainmap import _edges

    plt = pyplot()
    spec = TuneSpec.from_dict(record['spec'])
    w = record['winner']
    rows = w['scenarios']
    speeds, alphas = list(spec.envelope_speeds), list(spec.envelope_alphas)
    flagged = {(f['alpha'], f['speed']) for f in (record.get('check_step') or {}).get(
        'flagged', [])}
    fig, ax = plt.subplots(figsize=(7.5, 5.5))
    xe = _edges(speeds) if len(speeds) > 1 else np.array([speeds[0] - 5.0, speeds[0] + 5.0])
    ye = _edges(alphas) if len(alphas) > 1 else np.array([alphas[0] - 0.05, alphas[0] + 0.05])
    codes = np.full((len(alphas), len(speeds)), np.nan)
    from matplotlib.colors import BoundaryNorm, ListedColormap

    for r in rows:
        i, j = alphas.index(r['alpha']), speeds.index(r['speed'])
        codes[i, j] = OUTCOME_RANK[r['outcome']]
        m = _num(r['alpha_c']) - r['alpha']
        text = r['outcome'] + ('' if math.isnan(m) else f'\nα_c−α={m:+.3f}')
        ax.text(r['speed'], r['alpha'], text, ha='center', va='center', fontsize=7,
                color='w' if r['outcome'] in ('diverged', 'chaotic', 'periodic') else 'k')
        if (r['alpha'], r['speed']) in flagged:
            ax.add_patch(plt.Rectangle((xe[j], ye[i]), xe[j + 1] - xe[j], ye[i + 1] - ye[i],
                                       fill=False, hatch='//', ec='orange', lw=0))
    cmap = ListedColormap([OUTCOME_COLORS[o] for o in OUTCOMES])
    ax.pcolormesh(xe, ye, np.ma.masked_invalid(codes), cmap=cmap, alpha=0.85,
                  norm=BoundaryNorm(np.arange(len(OUTCOMES) + 1) - 0.5, len(OUTCOMES)))
    for o in OUTCOMES:
        if any(r['outcome'] == o for r in rows):
            ax.fill_between([], [], color=OUTCOME_COLORS[o], label=o)
    if flagged:
        ax.fill_between([], [], facecolor='none', hatch='//', edgecolor='orange',
                        label='outcome changes at half step (not scored)')
    ax.set_xlabel('V (m/s)')
    ax.set_ylabel('α')
    items = [f'{k}={v:.4g}' for k, v in w['values'].items()]
    vals = '\n'.join(', '.join(items[i:i + 3]) for i in range(0, len(items), 3))
    ax.set_title(titled(
        f'winner of fohssv tune {spec.controller} over the envelope\n{vals}\n'
        f"{record['model']} model, solver {record['solver']}, step {record['step']:g} s, "
        f'ZOH {spec.control_period or 0:g} s, {spec.duration:g} s runs (transient '
        f'{spec.transient:g} s), x(0) = 0', label), fontsize=7)
    ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.12), ncol=3)
    fig.tight_layout()
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=120)
    plt.close(fig)
    return paths


def plot_history(record: dict[str, Any], stem: Path, label: str = '') -> list[Path]:
    """The search history: per generation every candidate's level-1 rank (scenarios not
    steady), margin and metric, with the best so far. PNG and SVG ``<stem>.png/.svg``."""
    from .figures import pyplot, save, titled

    plt = pyplot()
    spec = TuneSpec.from_dict(record['spec'])
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 7.5), sharex=True)
    panels = (('not_steady', 'scenarios not steady'), ('margin', 'min(α_c − α)'),
              ('metric', f'worst {OBJECTIVE_TEXT[spec.objective]}'))
    for ax, (key, text) in zip(axes, panels):
        gx, gy, bx, by = [], [], [], []
        for g in record['generations']:
            for c in g['candidates']:
                if c.get('valid'):
                    gx.append(g['generation'])
                    gy.append(_num(c[key]))
            b = g.get('best_so_far')
            if b is not None:
                bx.append(g['generation'])
                by.append(_num(b[key]))
        ax.plot(gx, gy, '.', color='0.6', ms=4, label='candidates')
        ax.plot(bx, by, 'o-', color='tab:red', ms=4, label='best so far (lexicographic)')
        ax.set_ylabel(text)
        if key == 'margin':
            ax.axhline(spec.min_margin, color='m', lw=0.8, ls='--', label='min_margin')
    axes[-1].set_xlabel('generation')
    axes[-1].xaxis.get_major_locator().set_params(integer=True)
    axes[0].legend(fontsize=7)
    axes[1].legend(fontsize=7)
    opt = record['optimizer']
    axes[0].set_title(titled(
        f'fohssv tune {spec.controller}: differential evolution, population '
        f"{opt['population']}, {len(record['generations'])} generation(s), seed {spec.seed}\n"
        f'{len(spec.scenarios())} scenarios; score: worst outcome, then margin, then metric',
        label), fontsize=7)
    fig.tight_layout()
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=120)
    plt.close(fig)
    return paths
