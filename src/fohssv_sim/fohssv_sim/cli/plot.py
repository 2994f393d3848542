"""``fohssv plot BAG...`` and ``fohssv repair|check BAG``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..analysis.plots import plot_phase_portrait, plot_time_responses, summary
from ..bag import BagError, load_run
from ..bag.__main__ import main as bag_main
from ..bag.run import TooLarge, state_count
from . import command_help
from .common import (
    BagInputError,
    CliError,
    bounded,
    claim_output,
    figure_paths,
    folder_arg,
    job_folder,
    job_name,
    out_given,
    output_dir,
    output_file,
    safe_name,
)


def register(sub) -> None:
    p = sub.add_parser('plot', help=command_help('plot'),
                       description='Time responses of z, w, theta, q, delta_c and Fp (Figs. '
                       '3-4) and the w-q phase portrait (Fig. 7); several bags overlay. '
                       'Writes PNG and SVG and a summary JSON per bag.')
    p.add_argument('bags', nargs='+', type=Path, help='rosbag2 folders (or .mcap files)')
    p.add_argument('--out', type=folder_arg, default=None, help='output folder (default: '
                   'reports/plot/<bag names>-<hash of the job>)')
    p.add_argument('--skip', type=bounded('--skip', low=0, unit='s'), default=0.0,
                   help='phase portrait from t >= SKIP s (default 0)')
    p.add_argument('--start', type=bounded('--start', low=0, unit='s'), default=None,
                   help='plot from t = START s (default: the first sample); with --end, a '
                   'long bag is read only where the window lies')
    p.add_argument('--end', type=bounded('--end', low=0, unit='s'), default=None,
                   help='plot up to t = END s (default: the last sample)')
    p.add_argument('--every', type=int, default=None, metavar='K',
                   help='plot every K-th sample (default: 1, or as many as keep a bag within '
                   f'{MAX_POINTS} points per curve)')
    p.add_argument('--name', default='run', help="figure file stem, a plain name (default "
                   "'run': run_time.png, run_phase.png, run_summary.json)")
    p.add_argument('--namespace', help="the vehicle's namespace (e.g. /vehicle1) when a bag "
                   'holds several; default: the only state topic, wherever it is')
    p.set_defaults(func=cmd_plot)

    r = sub.add_parser('repair', help=command_help('repair'),
                       description='Rebuild the MCAP index/summary and metadata.yaml of a bag '
                       'whose recorder was killed, from every complete chunk.')
    r.add_argument('bag', help='bag directory (or its .mcap file)')
    r.add_argument('--no-backup', action='store_true',
                   help='do not keep the original MCAP file as <name>.orig')
    r.add_argument('--force', action='store_true', help='rewrite even a complete bag')
    r.set_defaults(func=lambda a: bag_main(['repair', a.bag, *(['--no-backup'] * a.no_backup),
                                            *(['--force'] * a.force)]))
    c = sub.add_parser('check', help=command_help('check'),
                       description='Structural check (CRCs, indexes, summary, metadata.yaml); '
                       'exit 0 sound, 1 not (each problem on its own line), 2 usage.')
    c.add_argument('bag', help='bag directory (or its .mcap file)')
    c.set_defaults(func=lambda a: bag_main(['check', a.bag]))


def _output(args: argparse.Namespace) -> Path:
    """The output folder, claimed for this job (the bags, --skip, --namespace) under the
    key ``plot:<name>``; its figures are never silently overwritten by another job's."""
    name = safe_name(args.name)
    identity = {'bags': [str(Path(b).resolve()) for b in args.bags], 'skip': args.skip,
                'namespace': args.namespace, 'start': args.start, 'end': args.end,
                'every': args.every}
    folder = args.out if out_given(args) else job_folder('plot', job_name(
        '+'.join(Path(b).name.removesuffix('.mcap') for b in args.bags)[:60], identity))
    output_dir(folder)
    claim_output(folder, f'plot:{name}', identity,
                 [f'{name}_{k}' for k in ('time.png', 'time.svg', 'phase.png', 'phase.svg',
                                          'summary.json')])
    return folder


#: Most points per curve a plot draws by default (a figure shows no more; a 10-minute run has
#: six million states): longer runs are decimated, every K-th sample (--every).
MAX_POINTS = 200_000


def _every(args: argparse.Namespace, bag: Path) -> int:
    """``--every``, else the decimation that keeps the window within :data:`MAX_POINTS`
    states (from the summary's count, without reading the messages)."""
    if args.every is not None:
        if args.every < 1:
            raise CliError(f'--every={args.every} must be a whole number >= 1 (every K-th '
                           'sample)')
        return args.every
    try:
        n = state_count(bag, args.namespace)
    except BagError:
        return 1             # load_run says what is wrong with the bag
    return max(1, -(-n // MAX_POINTS)) if n else 1


def cmd_plot(args: argparse.Namespace) -> int:
    safe_name(args.name)
    if args.start is not None and args.end is not None and args.end <= args.start:
        raise CliError(f'--end={args.end:g} s must lie after --start={args.start:g} s')
    runs = []
    for bag in args.bags:
        every = _every(args, bag)
        try:
            runs.append(load_run(bag, namespace=args.namespace, start=args.start,
                                 end=args.end, every=every))
        except TooLarge as e:
            raise CliError(str(e)) from None
        except BagError as e:
            raise BagInputError(str(e)) from None
        if every > 1:
            print(f'{bag}: every {every}th sample plotted (--every {every}; --every 1 and a '
                  '--start/--end window for all of them)')
    for run in runs:
        if run.t.size == 0:
            where = f' in namespace {args.namespace}' if args.namespace else ''
            raise BagInputError(f'{run.path}: no state messages{where} to plot (topics: '
                                f"{', '.join(sorted(run.topics)) or 'none'})")
        if args.skip >= run.t[-1]:
            raise CliError(f'--skip={args.skip:g} s leaves nothing of {run.path} for the phase '
                           f'portrait (its states end at t = {run.t[-1]:.6g} s)')
        if run.recovery:
            print(f'{run.path}: {run.recovery}')
    out = _output(args)
    stem = out / args.name
    plot_time_responses(runs, figure_paths(stem.parent / f'{stem.name}_time'))
    plot_phase_portrait(runs, figure_paths(stem.parent / f'{stem.name}_phase'), args.skip)
    summaries = {str(r.path): summary(r) for r in runs}
    output_file(out, f'{args.name}_summary.json').write_text(
        json.dumps(summaries, indent=2) + '\n')
    for path, s in summaries.items():
        print(f'{path}: ' + ', '.join(f'{k}={v:.6g}' if isinstance(v, float) else f'{k}={v}'
                                      for k, v in s.items()))
    print(f'figures: {stem}_time.png/.svg, {stem}_phase.png/.svg')
    return 0
