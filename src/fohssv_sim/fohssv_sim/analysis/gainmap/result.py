"""A whole gain map: its chunks run (or resumed), read back and summarised."""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..orbits import METHOD
from ..sweep import ChunkedResult, check_half_step, read_chunk_rows, run_chunks
from .evaluate import _decode, run_points
from .spec import (
    METRIC_TEXT,
    OUTCOME_RANK,
    OUTCOMES,
    ROW_FIELDS,
    GainMapError,
    GainMapSpec,
)


# -- the map -----------------------------------------------------------------------------
class GainMapResult(ChunkedResult):
    """All rows of a gain map (sorted by point) and its sidecar."""

    @property
    def spec(self) -> GainMapSpec:
        return GainMapSpec.from_dict(self.sidecar['spec'])

    def scenario_rows(self, alpha: float, speed: float) -> list[dict[str, Any]]:
        """The rows of one scenario, in pair order."""
        return [r for r in self.rows
                if abs(r['alpha'] - alpha) < 1e-9 and abs(r['speed'] - speed) < 1e-9]

    def worst(self) -> list[dict[str, Any]]:
        """Per gain pair (pair order), the worst case over the scenarios: highest-ranked
        outcome, largest metrics, ``alpha_margin`` = min (alpha_c - alpha); also the
        scenario of the worst outcome (``worst_alpha``, ``worst_speed``)."""
        by_pair: dict[int, list[dict[str, Any]]] = {}
        for r in self.rows:
            by_pair.setdefault(r['pair'], []).append(r)
        out = []
        for pair in sorted(by_pair):
            rs = by_pair[pair]
            w = max(rs, key=lambda r: OUTCOME_RANK[r['outcome']])
            row = {k: rs[0][k] for k in ('pair', 'ix', 'iy', 'x', 'y')}
            row.update(outcome=w['outcome'], label=w['label'], worst_alpha=w['alpha'],
                       worst_speed=w['speed'], n_scenarios=len(rs))
            for m in ('peak_fp', 'settle_time', 'effort_rms'):
                row[m] = float(np.max([r[m] for r in rs]))
            row['alpha_margin'] = float(np.min([r['alpha_c'] - r['alpha'] for r in rs]))
            out.append(row)
        return out

    def grid(self, rows: Sequence[dict[str, Any]], name: str) -> np.ndarray:
        """Column ``name`` of ``rows`` (one per pair) as an (ny, nx) array."""
        s = self.spec
        g = np.full((len(s.y_values), len(s.x_values)), np.nan, dtype=object
                    if name in ('outcome', 'label') else float)
        for r in rows:
            g[r['iy'], r['ix']] = r[name]
        return g


def summary_lines(result: GainMapResult) -> list[str]:
    """What a map shows, as text: per scenario shown (the nominal one, and the worst case
    over an envelope) the outcome counts, how many pairs the linearisation and the
    simulation agree on (Matignon-stable iff steady), and the steady pair that settles
    first."""
    s, side = result.spec, result.sidecar
    lines = [f"step {side['step']:g} s, solver {side['solver']}, model {side['model']}, "
             f"samples every {side['sample_every']} steps; {result.computed_chunks} chunks "
             f'computed, {result.reused_chunks} reused']
    views = []
    if s.has_scenario(s.alpha, s.speed):
        rows = result.scenario_rows(s.alpha, s.speed)
        for r in rows:
            r['alpha_margin'] = r['alpha_c'] - r['alpha']
        views.append((f'alpha = {s.alpha:g}, V = {s.speed:g} m/s', rows))
    if s.envelope:
        views.append((f'worst case over {len(s.scenarios())} scenarios', result.worst()))
    checked = [r for r in result.rows if r.get('step_check')]
    if checked:
        changed = [r for r in checked if r['step_check'] != 'same']
        lines.append(f'step check: {len(checked)} points re-run at half step, {len(changed)} '
                     'changed outcome' + ''.join(
                         f"\n  {s.gain_x}={r['x']:g}, {s.gain_y}={r['y']:g}, alpha={r['alpha']:g},"
                         f" V={r['speed']:g}: {r['outcome']} {r['step_check']}"
                         for r in changed[:10]))
    for title, rows in views:
        counts = {o: sum(r['outcome'] == o for r in rows) for o in OUTCOMES}
        lines.append(f'{title}: ' + ', '.join(f'{o} {n}' for o, n in counts.items() if n))
        known = [r for r in rows if not math.isnan(r['alpha_margin'])]
        if known:
            agree = sum((r['alpha_margin'] > 0) == (r['outcome'] == 'steady') for r in known)
            lines.append(f'  Matignon (alpha_c > alpha) vs simulated steady: agree at '
                         f'{agree}/{len(known)} pairs')
        else:
            lines.append('  Matignon boundary: not available (no linearisation)')
        steady = [r for r in rows if r['outcome'] == 'steady' and math.isfinite(
            r['settle_time'])]
        if steady:
            b = min(steady, key=lambda r: r['settle_time'])
            lines.append(f"  settles first: {s.gain_x}={b['x']:g}, {s.gain_y}={b['y']:g} in "
                         f"{b['settle_time']:.3g} s (peak |Fp| {b['peak_fp']:.3g} m^2/s^2, RMS "
                         f"delta_c {b['effort_rms']:.3g} rad)")
    return lines


def _sidecar(spec: GainMapSpec, chunks: list[list[int]]) -> dict[str, Any]:
    from ... import __version__

    p0 = spec.params_for(*spec.scenarios()[0])
    return {'spec': spec.to_dict(), 'step': p0.step, 'solver': p0.solver, 'model': p0.model,
            'planing_form': p0.planing_form, 'sample_every': spec.every(p0.step),
            'classification': METHOD, 'metrics': METRIC_TEXT, 'n_points': spec.n_points,
            'chunks': chunks, 'fohssv_version': __version__,
            'python': sys.version.split()[0], 'numpy': np.__version__}


def _chunks(spec: GainMapSpec) -> list[list[int]]:
    from ...batch import group_points

    params = [spec.params_for(a, v) for *_, a, v in map(spec.point, range(spec.n_points))]
    chunks = []
    for idx in group_points(params).values():
        for s in range(0, len(idx), spec.chunk_size):
            chunks.append(idx[s:s + spec.chunk_size])
    return sorted(chunks, key=lambda c: c[0])


def load_gain_map(out: Path) -> GainMapResult:
    """Read a (finished or partial) gain-map folder."""
    import json

    side = json.loads((out / 'gainmap.json').read_text())
    return GainMapResult(read_chunk_rows(out, len(side['chunks']), _decode), side)


def run_gain_map(spec: GainMapSpec, out: Path, *, scheduler: str | None = None,
                 workers: int = 0, progress: Callable[[int, int, float], None] | None = None,
                 client: Any = None,
                 check_progress: Callable[[int, int, float], None] | None = None
                 ) -> GainMapResult:
    """Run (or resume) the gain map ``spec`` into folder ``out`` on Dask (a local cluster
    with ``workers`` processes, default one per core, or the cluster at ``scheduler``, or
    ``client``). ``progress(done, total, elapsed)`` counts points. With ``spec.check_step``
    = k, every k-th point is re-run at half the step in this process (``check_progress``
    counts those) and its row's ``step_check`` says whether the outcome changed.

    Raises:
        GainMapError: an invalid spec (see :meth:`GainMapSpec.validate`), or ``out`` holds
            another job.
    """
    spec.validate()
    chunks = _chunks(spec)
    try:
        computed, reused = run_chunks(out, 'gainmap.json', _sidecar(spec, chunks), chunks,
                                      run_points, (spec.to_dict(),), ROW_FIELDS,
                                      scheduler=scheduler, workers=workers,
                                      progress=progress, client=client)
    except ValueError as e:
        if isinstance(e, GainMapError):
            raise
        raise GainMapError(str(e)) from None
    result = load_gain_map(out)
    result.computed_chunks, result.reused_chunks = computed, reused
    if spec.check_step:
        check_half_step(out, result.rows, spec.check_step,
                        lambda i: spec.params_for(*spec.point(i)[3:]),
                        functools.partial(run_points, spec.to_dict()), 'outcome',
                        check_progress)
    return result
