"""Run every benchmark script bench/bench_*.py and collect their results.

Each benchmark measures its comparisons side by side in one run (the machine is shared and
noisy, so only ratios within a run mean anything), prints a table and writes JSON to
``<out-dir>/<name>.json``. This script runs them one after another and writes
``<out-dir>/summary.json`` listing what ran and whether it succeeded.

    python scripts/bench.py --out-dir bench/results [--quick] [--only fractional,ros]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out-dir', type=Path, default=ROOT / 'bench' / 'results')
    ap.add_argument('--quick', action='store_true', help='pass --quick to each benchmark')
    ap.add_argument('--only', default='', help='comma-separated names (bench_<name>.py)')
    args = ap.parse_args(argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    scripts = sorted((ROOT / 'bench').glob('bench_*.py'))
    if args.only:
        wanted = {f'bench_{n.strip()}.py' for n in args.only.split(',')}
        scripts = [s for s in scripts if s.name in wanted]
    if not scripts:
        print('no benchmarks found in bench/')
    summary = {}
    failed = 0
    for script in scripts:
        name = script.stem.removeprefix('bench_')
        out = args.out_dir / f'{name}.json'
        cmd = [sys.executable, str(script), '--out', str(out)] + (['--quick'] if args.quick
                                                                   else [])
        print(f'== {script.relative_to(ROOT)}', flush=True)
        start = time.perf_counter()
        rc = subprocess.call(cmd, cwd=ROOT)
        summary[name] = {'returncode': rc, 'seconds': round(time.perf_counter() - start, 1),
                         'results': str(out.relative_to(ROOT)) if out.is_relative_to(ROOT)
                         else str(out)}
        failed += rc != 0
    (args.out_dir / 'summary.json').write_text(json.dumps(summary, indent=2) + '\n')
    print(f'results in {args.out_dir}/ ({len(scripts) - failed} ok, {failed} failed)')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
