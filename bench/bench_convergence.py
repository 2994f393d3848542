"""Step-halving figures behind the default steps (README "Numerics and defaults").

    python bench/bench_convergence.py --out bench/results/convergence.json [--quick]

V = 75 m/s, x(0) = 0, eq. 31 continuous, 2 s: for each model, max |x(h) - x(h/2)| over the
last 0.5 s divided by the peak-to-peak range there, per state component, and the wall time.
Exit status 1 when a model's change exceeds its stated tolerance (below; at 2 s, not with
--quick): the study that chose the default steps, moved here from ``make test`` (the test
suite keeps a short observed-order check, ``src/fohssv_sim/test/test_convergence.py``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for pkg in ('fohssv_sim', 'fohssv_controller'):
    sys.path.insert(0, str(ROOT / 'src' / pkg))

from fohssv_controller.state_feedback import StateFeedback  # noqa: E402
from fohssv_sim.analysis.convergence import halving_change  # noqa: E402
from fohssv_sim.params import ModelParameters  # noqa: E402

#: Largest allowed change from halving the default step, relative to the peak-to-peak range.
#: Measured when the defaults were chosen (1e-5 s vs 5e-6 s): delay-free 1.7e-5, delayed
#: 3.2e-6. The FOM's limit cycle at V = 75 runs at about 130 Hz, so over 2 s a small frequency
#: error becomes a phase error: halving 2e-5 s changed the last 0.5 s by 1.3 %; stated 2 %.
TOLERANCES = {'delay-free': 1e-4, 'delayed': 1e-4, 'fractional (soe)': 0.02}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=ROOT / 'bench' / 'results' / 'convergence.json')
    ap.add_argument('--quick', action='store_true', help='a smoke check: 0.02 s runs')
    args = ap.parse_args()
    duration = 0.02 if args.quick else 2.0
    cases = {'delay-free': ModelParameters(model='delay-free'),
             'delayed': ModelParameters(model='delayed'),
             'fractional (soe)': ModelParameters(solver='soe')}
    results = {}
    print(f'step halving, V = 75 m/s, {duration:g} s, last 0.5 s; '
          'max |x(h) - x(h/2)| / peak-to-peak per component')
    print(f"{'model':18} {'h (s)':>8} {'z':>9} {'w':>9} {'theta':>9} {'q':>9} {'wall s':>7}")
    for name, p in cases.items():
        start = time.perf_counter()
        rel, _ = halving_change(p, StateFeedback(), duration)
        wall = time.perf_counter() - start
        ok = bool(rel.max() < TOLERANCES[name])
        results[name] = {'step': p.step, 'relative_change': rel.tolist(), 'wall_s': wall,
                         'tolerance': TOLERANCES[name], 'within_tolerance': ok}
        print(f'{name:18} {p.step:8.0e} ' + ' '.join(f'{v:9.2e}' for v in rel)
              + f' {wall:7.1f}' + ('' if ok else f'  > tolerance {TOLERANCES[name]:g}'))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({'duration_s': duration, 'results': results}, indent=2))
    print(f'wrote {args.out}')
    failed = [n for n, r in results.items() if not r['within_tolerance']]
    if failed and not args.quick:
        print(f"halving the default step changed {', '.join(failed)} by more than the "
              'tolerance', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
