"""Step convergence of a ``fohssv tune`` winner's metric in chosen scenarios (docs/tune.md).

    python scripts/tune_step.py OUT [--alphas 0.7] [--speeds 90,120]
                                [--steps 1e-5,5e-6,2.5e-6] [--every-step] [--json FILE]

Re-runs the winner recorded in ``OUT/tune.json`` in the scenarios ``--alphas`` x ``--speeds``
at each step of ``--steps``, with the tuner's own evaluation of a candidate
(:func:`fohssv_sim.analysis.tune.run_candidates`: the search's duration, transient, ZOH period,
solver, model and metric columns; only the step and the scenarios change), and prints per
scenario the outcome and the search's objective metric (e.g. peak |Fp| over the run) at each
step, with the relative change from each step to the next. ``--check-step`` compares one step
with its half; this shows whether the metric settles as the step keeps shrinking. The runs of
one step are one batched solver call for an affine law (point by point otherwise).

The tuner computes its metrics from the states sampled once per control period (ZOH
period); ``--every-step`` samples every integration step instead (a diagnostic, not the
tuner's metric: it shows how much of a change is the sampling of a sharp peak).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'src' / 'fohssv_sim'))
sys.path.insert(0, str(ROOT / 'src' / 'fohssv_controller'))

from fohssv_sim.analysis.tune import (  # noqa: E402
    OBJECTIVES,
    TuneSpec,
    load_tune,
    run_candidates,
)


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split(',') if v.strip()]


def _change(a: float, b: float) -> float:
    return abs(b - a) / abs(a) if a else float('inf')


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('out', type=Path, help='a fohssv tune output folder (with tune.json)')
    ap.add_argument('--alphas', default='0.7', help='fractional orders (comma-separated)')
    ap.add_argument('--speeds', default='90,120', help='speeds, m/s (comma-separated)')
    ap.add_argument('--steps', default='1e-5,5e-6,2.5e-6', help='steps, s (comma-separated)')
    ap.add_argument('--every-step', action='store_true',
                    help="sample every step (not the tuner's once per control period)")
    ap.add_argument('--json', type=Path, help='also write the rows and changes here')
    args = ap.parse_args(argv)
    record = load_tune(args.out)
    winner = record.get('winner')
    if not winner:
        print(f'tune_step: {args.out / "tune.json"} has no winner yet (the search is '
              'unfinished)', file=sys.stderr)
        return 2
    alphas, speeds, steps = _floats(args.alphas), _floats(args.speeds), _floats(args.steps)
    for name, vals in (('--alphas', alphas), ('--speeds', speeds), ('--steps', steps)):
        if not vals:
            print(f'tune_step: {name} is empty (give at least one value)', file=sys.stderr)
            return 2
    spec_d = dict(record['spec'])
    spec_d.update(envelope_alphas=alphas, envelope_speeds=speeds, check_step=False)
    if args.every_step:
        spec_d['sample_every'] = 1
    key = OBJECTIVES[spec_d['objective']]
    n = len(alphas) * len(speeds)
    table: list[dict] = []
    for h in steps:
        job_spec = {**spec_d, 'base': {**spec_d['base'], 'step': h}}
        TuneSpec.from_dict(job_spec).validate()
        job = {'tune': job_spec, 'candidates': [winner['values']], 'step_factor': 1.0}
        t0 = time.perf_counter()
        rows = run_candidates(job, range(n))
        wall = time.perf_counter() - t0
        for r in rows:
            table.append({'step': h, 'alpha': r['alpha'], 'speed': r['speed'],
                          'outcome': r['outcome'], key: r[key], 'wall_s': wall / n,
                          **({'peak_fp_window': r['peak_fp_window']}
                             if key == 'peak_fp' else {})})
    solver = spec_d['base'].get('solver', 'auto')     # 'auto' when the search kept it
    print(f"{record['spec']['controller']} winner of {args.out}: {key} by step "
          f"({record['spec']['duration']:g} s runs, transient {record['spec']['transient']:g} s,"
          f" ZOH {record['spec']['control_period']:g} s, solver {solver}, "
          + ('sampled every step)' if args.every_step else 'sampled every control period)'))
    summary = []
    for a in alphas:
        for v in speeds:
            rs = [r for r in table if r['alpha'] == a and r['speed'] == v]
            vals = [r[key] for r in rs]
            changes = [_change(x, y) for x, y in zip(vals, vals[1:])]
            summary.append({'alpha': a, 'speed': v, 'steps': steps, 'outcomes':
                            [r['outcome'] for r in rs], key: vals, 'changes': changes})
            cells = '  '.join(f"{r['step']:.3g} s: {r['outcome']} {r[key]:.4g}" for r in rs)
            moves = ', '.join(f'{100 * c:.2f} %' for c in changes)
            print(f'  alpha {a:g}, V {v:g} m/s: {cells}; changes {moves}')
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({'out': str(args.out), 'metric': key,
                                         'every_step': args.every_step,
                                         'winner': winner['values'], 'rows': table,
                                         'summary': summary}, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
