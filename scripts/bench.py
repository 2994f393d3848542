"""Run every benchmark script bench/bench_*.py and collect their results.

Each benchmark measures its comparisons side by side in one run (the machine is shared and
noisy, so only ratios within a run mean anything), prints a table and writes JSON to
``<out-dir>/<name>.json``. This script runs them one after another, writes
``<out-dir>/summary.json`` listing what ran and whether it succeeded and, with ``--results``,
the figures with their targets (and a benchmark's ``figures`` table: a header row, then
rows), the machine and the bare DDS echo to one Markdown file
(``make bench``: bench/RESULTS.md, overwritten by each run; its history is in git).

``--quick`` is a smoke check: every benchmark starts and runs a tiny case (its figures mean
nothing); ``make bench-smoke`` runs it (tests/test_bench.py; CI after ``make test``).

    python scripts/bench.py [--out-dir bench/results] [--results bench/RESULTS.md]
                            [--quick] [--only simulate,ros]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def cpu_model() -> str:
    """The CPU's model name (Linux /proc/cpuinfo), else the platform's processor string."""
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _row(row: dict) -> tuple[str, str, str, str]:
    """(figure, measured, target, met) of a target row: benchutil's form (name, measured,
    op, goal, met) or bench_ros's (target, text, goal, pass)."""
    if 'name' in row:
        return (row['name'], f"{row['measured']:.3g}", f"{row['op']} {row['goal']:g}",
                'yes' if row['met'] else 'NO')
    return row['target'], row['text'], row['goal'], 'yes' if row['pass'] else 'NO'


def results_markdown(summary: dict, out_dir: Path, command: str, started: str,
                     load: tuple[float, float]) -> str:
    """The results file: the command, the machine, the date, the bare echo, then each
    benchmark's figures with their targets."""
    echo = None
    ros = out_dir / 'ros.json'
    if 'ros' in summary and ros.exists():
        echo = json.loads(ros.read_text()).get('echo', {}).get('round_trips_per_second')
    lines = ['# Benchmark results', '',
             'The latest figures of the benchmarks (`make bench` runs them all and overwrites '
             'this file; earlier runs: `git log -p bench/RESULTS.md`). Ratios within one run '
             'mean more than absolute figures: the machine may be shared.', '',
             f'- command: `{command}`',
             f'- date: {started}',
             f'- machine: {cpu_model()}, {os.cpu_count()} CPUs, {platform.system()} '
             f'{platform.release()}',
             f'- load average (1 min) at start {load[0]:.2f}, at end {load[1]:.2f}',
             '- bare DDS echo: ' + (f'{echo:.0f} round trips/s (bench_ros.py; scale the ROS '
                                    'figures by it for another machine)' if echo
                                    else 'not measured in this run')]
    for name, entry in summary.items():
        rc = entry['returncode']
        verdict = 'ok' if rc == 0 else f'FAILED, exit {rc}'
        lines += ['', f"## {name} (bench/bench_{name}.py: {verdict}, {entry['seconds']:g} s)",
                  '']
        path = out_dir / f'{name}.json'
        res = json.loads(path.read_text()) if path.exists() else {}
        if res.get('figures'):      # figures without a target of their own: a table each
            head, *body = res['figures']
            lines += ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
            lines += ['| ' + ' | '.join(str(v) for v in r) + ' |' for r in body] + ['']
        rows = res.get('targets', [])
        if not rows:
            lines.append('No targets (figures in its JSON output).')
            continue
        lines += ['| figure | measured | target | met |', '|---|---|---|---|']
        lines += ['| ' + ' | '.join(_row(r)) + ' |' for r in rows]
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out-dir', type=Path, default=ROOT / 'bench' / 'results')
    ap.add_argument('--results', type=Path, default=None,
                    help='write the figures and their targets to this Markdown file')
    ap.add_argument('--quick', action='store_true',
                    help='a smoke check: every benchmark runs a tiny case')
    ap.add_argument('--only', default='', help='comma-separated names (bench_<name>.py)')
    args = ap.parse_args(argv)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    scripts = sorted((ROOT / 'bench').glob('bench_*.py'))
    if args.only:
        wanted = {f'bench_{n.strip()}.py' for n in args.only.split(',')}
        unknown = wanted - {s.name for s in scripts}
        if unknown:
            print(f"error: --only names no benchmark: {', '.join(sorted(unknown))} (bench/ has "
                  f"{', '.join(s.stem.removeprefix('bench_') for s in scripts)})",
                  file=sys.stderr)
            return 2
        scripts = [s for s in scripts if s.name in wanted]
    started = datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    load_start = os.getloadavg()[0]
    summary = {}
    failed = 0
    for i, script in enumerate(scripts, 1):
        name = script.stem.removeprefix('bench_')
        out = args.out_dir / f'{name}.json'
        cmd = [sys.executable, str(script), '--out', str(out)] + (['--quick'] if args.quick
                                                                   else [])
        print(f'== [{i}/{len(scripts)}] {script.relative_to(ROOT)}', flush=True)
        start = time.perf_counter()
        rc = subprocess.call(cmd, cwd=ROOT)
        summary[name] = {'returncode': rc, 'seconds': round(time.perf_counter() - start, 1)}
        failed += rc != 0
        if rc != 0:
            print(f'== {script.relative_to(ROOT)} failed (exit {rc})', flush=True)
    (args.out_dir / 'summary.json').write_text(json.dumps(summary, indent=2) + '\n')
    if args.results is not None:
        command = ' '.join(['python scripts/bench.py', *(sys.argv[1:] if argv is None else argv)])
        args.results.write_text(results_markdown(summary, args.out_dir, command, started,
                                                 (load_start, os.getloadavg()[0])))
        print(f'figures in {args.results}')
    print(f'results in {args.out_dir}/ ({len(scripts) - failed} ok, {failed} failed)')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
