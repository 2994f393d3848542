"""Orbit-diagram sweeps over alpha, V or the alpha-V grid, on Dask.

A sweep is a list of points (alpha, V) sharing every other setting (:class:`SweepSpec`).
Points are split into chunks of batchable points (same step and solver; with the 'soe'
solver points of different alpha share a batch, see :func:`fohssv_sim.batch.group_points`);
each chunk is one Dask task that runs the batched
solver, takes the local maxima of the chosen state after the transient and classifies each
orbit (:mod:`.orbits`). The client writes each chunk's rows to ``<out>/chunks/`` as soon as the
chunk finishes (CSV, written atomically), so a sweep that is interrupted resumes where it
stopped: finished chunks are read back, not recomputed. ``<out>/sweep.json`` is the sidecar:
the full spec (step, solver, transient, window, method), versions, and the chunk list.

Scheduler: a local ``dask.distributed.LocalCluster`` (one single-threaded worker process per
core) unless ``scheduler`` names an existing cluster's address. Results do not depend on the
scheduler: each chunk's computation is deterministic.

``check_step``: re-runs every k-th point at half the step and flags the points whose
classification changes (column ``step_check``).

Progress is counted in points, not chunks: a chunk's task reports the fraction of its batch
steps done (every 1 %, or after each point for the models the batch runner steps point by
point) from whichever Dask worker runs it, as a Dask event on a topic the client subscribes
to; ``progress(done, total, elapsed)`` gets the number of points done (finished chunks plus
the finished share of running ones) each time it grows by one. The half-step check reports
the same way, in-process.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import functools
import json
import math
import os
import sys
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..control import make
from ..params import ModelParameters
from .orbits import METHOD, OSCILLATING, STEADY_RTOL, classify

__all__ = ['SweepSpec', 'SweepResult', 'ChunkedResult', 'run_chunks', 'check_half_step',
           'run_sweep', 'run_chunk', 'load_sweep', 'STATE_INDEX', 'ProgressPrinter',
           'state_scale', 'WorkersLost', 'LOST_AFTER', 'alpha_star']

STATE_INDEX = {'z': 0, 'w': 1, 'theta': 2, 'q': 3}
ROW_FIELDS = ('point', 'alpha', 'speed', 'label', 'kind', 'period', 'k01', 'amplitude',
              'n_maxima', 'failed', 'step_check', 'maxima')


@dataclass(frozen=True)
class SweepSpec:
    """Everything that defines a sweep's numbers (recorded in the sidecar).

    ``base`` holds the model parameters shared by every point (as a dict of the parameter
    table's names); ``alphas`` x ``speeds`` is the grid (a 1-D sweep has one value in the
    other). ``transient`` and ``window`` are in seconds; the orbit is sampled every
    ``sample_every`` steps in the window.
    """

    base: dict[str, Any]
    alphas: tuple[float, ...]
    speeds: tuple[float, ...]
    controller: str = 'state_feedback'
    gains: dict[str, Any] = field(default_factory=dict)
    transient: float = 1.5
    window: float = 0.5
    sample_every: int = 1
    state: str = 'w'
    control_period: float | None = None
    chunk_size: int = 64
    check_step: int = 0           # re-run every k-th point at half step (0 = off)
    steady_rtol: float = STEADY_RTOL   # steady tolerance, relative to the state's scale
    rel_tol: float = 1e-3

    def points(self) -> list[tuple[float, float]]:
        return [(a, v) for v in self.speeds for a in self.alphas]

    def params_for(self, alpha: float, speed: float, step_factor: float = 1.0
                   ) -> ModelParameters:
        p = ModelParameters.from_dict({**self.base, 'fractional_order': alpha, 'speed': speed})
        if step_factor != 1.0:
            p = p.replace(step=p.step * step_factor)
        return p

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d['alphas'] = list(self.alphas)
        d['speeds'] = list(self.speeds)
        return d


def _simulate(params: list[ModelParameters], ctl: Any, spec: SweepSpec, every: int,
              progress: Callable[[float], None] | None):
    """simulate_batch over ``params``, reporting progress as a fraction of the chunk."""
    from ..batch import simulate_batch

    return simulate_batch(params, [ctl], spec.transient + spec.window,
                          control_period=spec.control_period, sample_every=every,
                          record_from=spec.transient, progress=progress)


def state_scale(states: np.ndarray, k: int, length: float) -> float:
    """The scale of state ``k`` over the window that the steady tolerance is relative to: its
    largest |value|; for the pitch rate q, whose steady value is 0, the pitch rate that turns
    the nose's largest vertical velocity |w| over the body length (|w| / L, rad/s)."""
    if k == STATE_INDEX['q']:
        return float(np.max(np.abs(states[:, STATE_INDEX['w']]))) / length
    return float(np.max(np.abs(states[:, k])))


def run_chunk(spec_dict: dict[str, Any], indices: Sequence[int], step_factor: float = 1.0,
              progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """Compute the rows of the points ``indices`` of the sweep ``spec_dict`` (one Dask task).

    Pure function of its arguments (deterministic), so any scheduler gives the same rows.
    ``progress(fraction)`` is called as the chunk's batch steps (or points) complete.
    """
    spec = SweepSpec(**{**spec_dict, 'alphas': tuple(spec_dict['alphas']),
                        'speeds': tuple(spec_dict['speeds'])})
    pts = spec.points()
    params = [spec.params_for(*pts[i], step_factor=step_factor) for i in indices]
    ctl = make(spec.controller, spec.gains)
    h = params[0].step
    every = max(1, round(spec.sample_every / step_factor))
    res = _simulate(params, ctl, spec, every, progress)
    k = STATE_INDEX[spec.state]
    rows = []
    for j, i in enumerate(indices):
        alpha, speed = pts[i]
        if res.failed[j]:
            rows.append({'point': i, 'alpha': alpha, 'speed': speed, 'label': 'diverged',
                         'kind': 'diverged', 'period': 0, 'k01': math.nan,
                         'amplitude': math.nan, 'n_maxima': 0, 'failed': True,
                         'step_check': '', 'maxima': []})
            continue
        y = res.states[j, :, k]
        cls, peaks = classify(res.t, y, steady_rtol=spec.steady_rtol, rel_tol=spec.rel_tol,
                              scale=state_scale(res.states[j], k, params[j].length))
        if peaks.size == 0:
            peaks = y[-1:]   # a steady orbit is drawn at its last value
        rows.append({'point': i, 'alpha': alpha, 'speed': speed, 'label': cls.label,
                     'kind': cls.kind, 'period': cls.period, 'k01': cls.k01,
                     'amplitude': cls.amplitude, 'n_maxima': cls.n_maxima, 'failed': False,
                     'step_check': '', 'maxima': [float(v) for v in peaks[-64:]],
                     'step': h})
    return rows


def _run_task_reporting(task: Callable[..., list[dict[str, Any]]], args: tuple,
                        indices: Sequence[int], topic: str, chunk: int
                        ) -> list[dict[str, Any]]:
    """``task(*args, indices, progress=report)`` as a Dask task that reports its progress
    as events on ``topic`` (the chunk's fraction done)."""
    from dask.distributed import get_worker

    worker = get_worker()

    def report(fraction: float) -> None:
        worker.log_event(topic, {'chunk': chunk, 'fraction': float(fraction)})

    return task(*args, indices, progress=report)


class _PointProgress:
    """Points done across chunks (finished chunks plus running chunks' fractions); calls
    ``progress(done, total, elapsed)`` whenever the whole number of points done grows.
    Thread-safe: Dask events arrive on the client's event-loop thread."""

    def __init__(self, sizes: Sequence[int], done: int, total: int,
                 progress: Callable[[int, int, float], None] | None, start: float) -> None:
        self.sizes, self.total, self.progress, self.start = list(sizes), total, progress, start
        self.base = done
        self.fraction = [0.0] * len(self.sizes)
        self.reported = done
        self.lock = threading.Lock()

    def update(self, k: int, fraction: float) -> None:
        if self.progress is None:
            return
        with self.lock:
            self.fraction[k] = max(self.fraction[k], min(1.0, fraction))
            done = self.base + sum(f * n for f, n in zip(self.fraction, self.sizes))
            whole = min(self.total, int(done + 1e-9))
            if whole > self.reported:
                self.reported = whole
                self.progress(whole, self.total, time.monotonic() - self.start)


def _chunks(spec: SweepSpec) -> list[list[int]]:
    """Points split into batchable chunks (:func:`fohssv_sim.batch.group_points`)."""
    from ..batch import group_points

    pts = spec.points()
    params = [spec.params_for(a, v) for a, v in pts]
    chunks = []
    for idx in group_points(params).values():
        for s in range(0, len(idx), spec.chunk_size):
            chunks.append(idx[s:s + spec.chunk_size])
    return sorted(chunks, key=lambda c: c[0])


def chunk_path(out: Path, k: int) -> Path:
    """The CSV file of chunk ``k`` of the chunked job in folder ``out``."""
    return out / 'chunks' / f'chunk_{k:05d}.csv'


def write_rows(path: Path, rows: list[dict[str, Any]], fields: Sequence[str]) -> None:
    """Write ``rows`` (the columns ``fields``; list values joined with ';') atomically."""
    tmp = path.with_suffix('.tmp')
    with open(tmp, 'w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=list(fields), extrasaction='ignore')
        w.writeheader()
        for r in rows:
            w.writerow({k: ';'.join(repr(x) for x in v) if isinstance(v, list) else v
                        for k, v in r.items()})
    os.replace(tmp, path)


def read_chunk_rows(out: Path, n_chunks: int, decode: Callable[[dict[str, str]], dict[str, Any]]
                    ) -> list[dict[str, Any]]:
    """The rows of every finished chunk of the job in ``out`` (decoded), sorted by point."""
    rows = []
    for k in range(n_chunks):
        f = chunk_path(out, k)
        if f.exists():
            with open(f, newline='') as fh:
                rows.extend(decode(r) for r in csv.DictReader(fh))
    rows.sort(key=lambda r: r['point'])
    return rows


def _decode_sweep_row(r: dict[str, str]) -> dict[str, Any]:
    return {'point': int(r['point']), 'alpha': float(r['alpha']),
            'speed': float(r['speed']), 'label': r['label'], 'kind': r['kind'],
            'period': int(r['period']), 'k01': float(r['k01']),
            'amplitude': float(r['amplitude']), 'n_maxima': int(r['n_maxima']),
            'failed': r['failed'] == 'True', 'step_check': r['step_check'],
            'maxima': [float(v) for v in r['maxima'].split(';') if v]}


@dataclass
class ChunkedResult:
    """All rows of a chunked job (sorted by point index), its sidecar, and how many chunks
    this run computed and reused (:func:`run_chunks`)."""

    rows: list[dict[str, Any]]
    sidecar: dict[str, Any]
    computed_chunks: int = 0
    reused_chunks: int = 0

    def column(self, name: str) -> np.ndarray:
        return np.array([r[name] for r in self.rows])


class SweepResult(ChunkedResult):
    """All rows of a sweep (sorted by point index) and its sidecar."""


def _sidecar(spec: SweepSpec, chunks: list[list[int]]) -> dict[str, Any]:
    from .. import __version__

    p0 = spec.params_for(spec.alphas[0], spec.speeds[0])
    return {'spec': spec.to_dict(), 'step': p0.step, 'solver': p0.solver, 'model': p0.model,
            'classification': METHOD, 'n_points': len(spec.points()),
            'chunks': chunks, 'fohssv_version': __version__,
            'python': sys.version.split()[0], 'numpy': np.__version__}


def load_sweep(out: Path) -> SweepResult:
    """Read a (finished or partial) sweep folder."""
    side = json.loads((out / 'sweep.json').read_text())
    return SweepResult(read_chunk_rows(out, len(side['chunks']), _decode_sweep_row), side)


class WorkersLost(RuntimeError):
    """A chunked job whose Dask workers are gone: none left for ``lost_after`` s while chunks
    were unfinished, or a chunk that killed the worker running it as often as the scheduler
    allows (``KilledWorker``). The message is one line: what happened, how many chunks are
    finished and kept, and that rerunning the same command resumes from them (the CLI exits
    with :data:`fohssv_sim.cli.common.EXIT_WORKERS_LOST`, 3)."""


#: Seconds a chunked job waits with no Dask worker at all before :class:`WorkersLost` (a local
#: cluster's nanny restarts a killed worker within a few seconds; this is well above that).
LOST_AFTER = 30.0


class _WorkerWatch:
    """The watchdog of :func:`run_chunks`: polls the scheduler's worker count (at most once a
    second) while it waits, raises :class:`WorkersLost` when it stays 0 for ``lost_after`` s
    or a chunk's future failed with ``KilledWorker``."""

    def __init__(self, client: Any, out: Path, n_chunks: int, lost_after: float) -> None:
        self.client, self.out, self.n_chunks, self.lost_after = client, out, n_chunks, lost_after
        self.polled = 0.0
        self.since: float | None = None

    def _finished(self) -> int:
        return sum(chunk_path(self.out, k).exists() for k in range(self.n_chunks))

    def _lost(self, what: str) -> WorkersLost:
        return WorkersLost(f'{what}; {self._finished()} of {self.n_chunks} chunks are finished '
                           f'and kept in {self.out / "chunks"}: rerun the same command to '
                           'resume from them')

    def check(self, pending: int) -> None:
        now = time.monotonic()
        if now - self.polled < 1.0:
            return
        self.polled = now
        try:
            n = len(self.client.scheduler_info()['workers'])
        except Exception:   # noqa: BLE001 - the scheduler itself is gone: as no worker
            n = 0
        if n:
            self.since = None
            return
        self.since = self.since or now
        if now - self.since >= self.lost_after:
            raise self._lost(f'every Dask worker is gone (none for {now - self.since:.0f} s, '
                             f'{pending} chunk(s) unfinished)')

    def result(self, fut: Any, k: int) -> list[dict[str, Any]]:
        from distributed import KilledWorker

        try:
            return fut.result()
        except KilledWorker as e:
            raise self._lost(f'chunk {k} killed the Dask worker running it each time it ran '
                             f'({type(e).__name__}: a crash or out of memory in the task)'
                             ) from None


def run_chunks(out: Path, sidecar_name: str, sidecar: dict[str, Any],
               chunks: list[list[int]], task: Callable[..., list[dict[str, Any]]],
               args: tuple, fields: Sequence[str], *, scheduler: str | None = None,
               workers: int = 0, progress: Callable[[int, int, float], None] | None = None,
               client: Any = None, lost_after: float = LOST_AFTER) -> tuple[int, int]:
    """Run (or resume) a chunked job on Dask into folder ``out``: the machinery shared by the
    sweeps and the gain maps (:mod:`.gainmap`).

    ``sidecar`` (written to ``out/sidecar_name`` the first time) must have the keys 'spec'
    and 'chunks'; a folder holding another job (different spec or chunks) is refused. Each
    chunk ``k`` not yet in ``out/chunks`` runs as one task ``task(*args, chunks[k],
    progress=...)`` (a picklable module-level function returning the chunk's rows, each with
    a 'point' key), and its rows are written to :func:`chunk_path` (columns ``fields``) as
    soon as it finishes. ``progress(done, total, elapsed)`` counts points (see the module
    docstring). ``client``: an existing ``dask.distributed.Client`` (then ``scheduler`` and
    ``workers`` are ignored and the client is left open).

    ``lost_after``: seconds with no worker at all before the job ends (:class:`WorkersLost`)
    instead of waiting for workers that will not come back.

    Returns:
        (chunks computed, chunks reused).

    Raises:
        ValueError: ``out`` holds a different job (the message says how to proceed).
        WorkersLost: every worker gone for ``lost_after`` s, or a chunk that kills its
            worker; the finished chunks are kept (a rerun resumes).
    """
    out.mkdir(parents=True, exist_ok=True)
    side_path = out / sidecar_name
    if side_path.exists():
        old = json.loads(side_path.read_text())
        if old.get('spec') != sidecar['spec'] or old.get('chunks') != chunks:
            raise ValueError(f'{out} holds a different job (see {side_path}); choose another '
                             '--out or delete that folder')
    else:
        side_path.write_text(json.dumps(sidecar, indent=2) + '\n')
    (out / 'chunks').mkdir(exist_ok=True)

    todo = [k for k in range(len(chunks)) if not chunk_path(out, k).exists()]
    reused = len(chunks) - len(todo)
    start = time.monotonic()
    n_points = sum(len(c) for c in chunks)
    points = _PointProgress([len(chunks[k]) for k in todo], n_points - sum(
        len(chunks[k]) for k in todo), n_points, progress, start)
    if todo:
        from .cluster import dask_client

        with contextlib.ExitStack() as stack:
            if client is None:
                client = stack.enter_context(dask_client(scheduler,
                                                         workers or os.cpu_count() or 1))
            _run_todo(client, out, chunks, todo, task, args, fields, points, progress,
                      lost_after)
    return len(todo), reused


def _run_todo(client: Any, out: Path, chunks: list[list[int]], todo: list[int],
              task: Callable[..., list[dict[str, Any]]], args: tuple, fields: Sequence[str],
              points: _PointProgress, progress: Callable[[int, int, float], None] | None,
              lost_after: float) -> None:
    """Run the chunks ``todo`` of :func:`run_chunks` on ``client``, writing each as it ends."""
    from dask.distributed import wait

    topic = f'fohssv-chunks-{uuid.uuid4().hex}'
    slot = {k: i for i, k in enumerate(todo)}
    if progress is not None:
        client.subscribe_topic(
            topic, lambda event: points.update(slot[event[1]['chunk']],
                                               event[1]['fraction']))
    try:
        futures = {client.submit(_run_task_reporting, task, args, chunks[k], topic, k,
                                 pure=False): k for k in todo}
        watch = _WorkerWatch(client, out, len(chunks), lost_after)
        pending = set(futures)
        while pending:
            try:    # Dask's public wait, half a second at a time: the watchdog between
                finished, pending = wait(pending, timeout=0.5, return_when='FIRST_COMPLETED')
            except TimeoutError:
                watch.check(len(pending))
                continue
            for fut in finished:
                k = futures[fut]
                write_rows(chunk_path(out, k), watch.result(fut, k), fields)
                points.update(slot[k], 1.0)
    finally:
        if progress is not None:
            client.unsubscribe_topic(topic)


class ProgressPrinter:
    """``progress(done, total, elapsed)`` for :func:`.sweep.run_sweep`, on stderr: one line
    rewritten in place (``\\r``) on a terminal, one line per update otherwise (log files get
    no carriage returns)."""

    def __init__(self, what: str, stream=None) -> None:
        self.what = what
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, 'isatty', lambda: False)())
        self.open = False

    def __call__(self, done: int, total: int, elapsed: float) -> None:
        eta = elapsed / max(done, 1) * (total - done)
        text = (f'  {self.what} {done}/{total}  {elapsed:6.1f} s elapsed  '
                f'~{eta:6.1f} s left')
        if self.tty:
            print('\r' + text, end='', file=self.stream, flush=True)
            self.open = True
        else:
            print(text, file=self.stream, flush=True)

    def end(self) -> None:
        """End the in-place line (terminal only)."""
        if self.open:
            print(file=self.stream, flush=True)
            self.open = False


def run_sweep(spec: SweepSpec, out: Path, *, scheduler: str | None = None, workers: int = 0,
              progress: Callable[[int, int, float], None] | None = None,
              client: Any = None,
              check_progress: Callable[[int, int, float], None] | None = None
              ) -> SweepResult:
    """Run (or resume) the sweep ``spec`` into folder ``out``; see the module docstring.

    ``progress(done, total, elapsed)`` / ``check_progress``: points of the sweep / of the
    half-step check done, each time one more is (see the module docstring).

    ``client``: an existing ``dask.distributed.Client`` to use (then ``scheduler`` and
    ``workers`` are ignored and the client is left open).

    Raises:
        ValueError: ``out`` holds a different sweep (the message says how to proceed).
    """
    chunks = _chunks(spec)
    computed, reused = run_chunks(out, 'sweep.json', _sidecar(spec, chunks), chunks, run_chunk,
                                  (spec.to_dict(),), ROW_FIELDS, scheduler=scheduler,
                                  workers=workers, progress=progress, client=client)
    result = load_sweep(out)
    result.computed_chunks, result.reused_chunks = computed, reused
    if spec.check_step:
        _check_step(spec, out, result, check_progress)
    if len(spec.alphas) > 1:
        write_alpha_star(out, result)
    return result


def alpha_star(result: SweepResult) -> list[tuple[float, float]]:
    """alpha*(V), the stability boundary: per speed, scanning alpha upward, the first change
    between ``steady`` and an oscillating class (periodic or aperiodic), as the midpoint of
    the two grid values (``drifting`` and ``diverged`` points are neither and are skipped);
    NaN when the grid shows no such change."""
    out = []
    speeds = sorted({r['speed'] for r in result.rows})
    for v in speeds:
        rows = sorted((r for r in result.rows if r['speed'] == v and (
            r['kind'] == 'steady' or r['kind'] in OSCILLATING)), key=lambda r: r['alpha'])
        a = math.nan
        for lo, hi in zip(rows, rows[1:]):
            if (lo['kind'] == 'steady') != (hi['kind'] == 'steady'):
                a = 0.5 * (lo['alpha'] + hi['alpha'])
                break
        out.append((v, a))
    return out


def write_alpha_star(out: Path, result: SweepResult) -> None:
    """Add ``alpha_star`` to ``out/sweep.json``: per V of the sweep, alpha*(V), the boundary
    between steady and oscillating orbits (:func:`alpha_star`; null where the grid
    shows none), as ``[{"speed": V, "alpha_star": a}, ...]``."""

    side_path = out / 'sweep.json'
    side = json.loads(side_path.read_text())
    side['alpha_star'] = [{'speed': v, 'alpha_star': None if math.isnan(a) else a}
                          for v, a in alpha_star(result)]
    side['alpha_star_rule'] = ('per V, the midpoint of the first two alpha grid values '
                               '(upward) whose orbits are steady and oscillating (periodic or '
                               'aperiodic)')
    tmp = side_path.with_suffix('.tmp')
    tmp.write_text(json.dumps(side, indent=2) + '\n')
    os.replace(tmp, side_path)
    result.sidecar = side


def check_half_step(out: Path, rows: list[dict[str, Any]], every: int,
                    params: Callable[[int], ModelParameters],
                    run: Callable[..., list[dict[str, Any]]], key: str,
                    progress: Callable[[int, int, float], None] | None = None) -> None:
    """Re-run every ``every``-th row's point at half the step; set the re-run rows'
    ``step_check`` to 'same' or 'changed to X at half step' (X: column ``key`` at half step).

    ``run(indices, step_factor=0.5, progress=...)`` computes the rows of points (one batch per
    group of batchable points, ``params(point)`` giving each point's parameters). The results
    are kept in ``out/step_check.json``: a resumed job reads them back.
    ``progress(done, total, elapsed)`` counts the re-run points as they complete.
    """
    path = out / 'step_check.json'
    if path.exists():
        checks = {int(k): v for k, v in json.loads(path.read_text()).items()}
    else:
        from ..batch import group_points

        sample = [rows[i]['point'] for i in range(0, len(rows), every)]
        checks = {}
        groups = list(group_points([params(i) for i in sample]).values())
        points = _PointProgress([len(g) for g in groups], 0, len(sample), progress,
                                time.monotonic())
        for k, idx in enumerate(groups):
            def report(fraction: float, k: int = k) -> None:
                points.update(k, fraction)

            for r in run([sample[i] for i in idx], step_factor=0.5, progress=report):
                checks[r['point']] = r[key]
            points.update(k, 1.0)
        path.write_text(json.dumps({str(k): v for k, v in checks.items()}, indent=2) + '\n')
    for r in rows:
        if r['point'] in checks:
            r['step_check'] = 'same' if checks[r['point']] == r[key] else (
                f"changed to {checks[r['point']]} at half step")


def _check_step(spec: SweepSpec, out: Path, result: SweepResult,
                progress: Callable[[int, int, float], None] | None = None) -> None:
    """Re-run every ``check_step``-th point at half the step; mark changed classifications."""
    pts = spec.points()
    check_half_step(out, result.rows, spec.check_step, lambda i: spec.params_for(*pts[i]),
                    functools.partial(run_chunk, spec.to_dict()), 'label', progress)
