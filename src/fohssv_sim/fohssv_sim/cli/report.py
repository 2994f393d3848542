"""``fohssv report``: run the paper's experiments and write the claims table."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from ..analysis.report import ReportSettings, make_report
from . import command_help
from .common import check_scheduler, check_workers, claim_output, output_dir


def register(sub) -> None:
    p = sub.add_parser('report', help=command_help('report'),
                       description='Runs Figs. 3-10 of the paper at the stated settings, '
                       'each with a half-step check, and writes OUT/report.md, OUT/claims.json '
                       'and the figures. Takes tens of minutes on 2 cores at the default '
                       'settings; sweeps resume if interrupted.')
    p.add_argument('--out', type=Path, default=None, help='output folder (default: '
                   'reports/paper, with --quick reports/paper-quick)')
    p.add_argument('--quick', action='store_true', help='tiny grid and short runs: a smoke '
                   'test of the pipeline, NOT converged results')
    p.add_argument('--workers', type=int, default=0, help='local Dask workers (default 0: one '
                   'per core; at most 4 per core)')
    p.add_argument('--scheduler', help='address of an existing Dask scheduler')
    p.set_defaults(func=cmd_report)


def cmd_report(args: argparse.Namespace) -> int:
    check_workers(args.workers)
    check_scheduler(args.scheduler)
    if args.out is None:
        args.out = Path('reports/paper-quick' if args.quick else 'reports/paper')
    output_dir(args.out)
    claim_output(args.out, 'report', {'quick': args.quick}, ['report.md', 'claims.json'])

    s = ReportSettings.quick() if args.quick else ReportSettings()
    s = dataclasses.replace(s, workers=args.workers, scheduler=args.scheduler)
    if args.quick:
        print('quick mode: short runs on a tiny grid; the verdicts are not converged results')
    path = make_report(args.out, s, log=lambda m: print(m, file=sys.stderr, flush=True))
    print(f'report: {path}')
    print(path.read_text().split('## Figures')[0])
    return 0
