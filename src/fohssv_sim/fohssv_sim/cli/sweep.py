"""``fohssv sweep alpha|V|alpha-V``: orbit diagrams on Dask (see
:mod:`fohssv_sim.analysis.sweep`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..analysis.diagrams import plot_alpha_v, plot_orbit_diagram
from ..analysis.stability import critical_order_curve
from ..analysis.sweep import ProgressPrinter, SweepSpec, run_sweep
from ..params import ParameterError
from .common import (
    CliError,
    add_common_options,
    assignments,
    figure_paths,
    load_controller,
    model_params,
    output_dir,
    parse_range,
)

DEFAULT_ALPHAS = '0.6:1.0:0.02'
DEFAULT_SPEEDS = '75:90:1'


def run_on_dask(run, spec, out: Path, args: argparse.Namespace):
    """``run(spec, out, ...)`` (:func:`.sweep.run_sweep` or :func:`.gainmap.run_gain_map`) on
    the scheduler / workers of ``args``, with progress lines for the points and for the
    half-step check; a ValueError (a bad spec, a folder holding another job) is a CliError."""
    progress = ProgressPrinter('points')
    check = ProgressPrinter('step check: points at half step')
    try:
        result = run(spec, out, scheduler=args.scheduler, workers=args.workers,
                     progress=progress, check_progress=check)
    except ValueError as e:
        raise CliError(str(e)) from None
    progress.end()
    check.end()
    return result


def dask_options(p: argparse.ArgumentParser, chunk_size: int, chunk_text: str) -> None:
    """--chunk-size, --scheduler and --workers of the commands that run on Dask."""
    p.add_argument('--chunk-size', type=int, default=chunk_size,
                   help=f'points per Dask task ({chunk_text})')
    p.add_argument('--scheduler', help='address of an existing Dask scheduler '
                   '(default: a local cluster)')
    p.add_argument('--workers', type=int, default=0, help='local workers (default: cores)')


def register(sub) -> None:
    p = sub.add_parser('sweep', help='orbit diagrams over alpha, V or the alpha-V grid',
                       description='Local maxima of a state after a transient, per parameter '
                       'value, each orbit classified (steady / drifting / periodic-p / '
                       'aperiodic with the 0-1 test K). Runs on Dask: a local cluster by '
                       'default, or --scheduler ADDRESS. Results stream to OUT/chunks/*.csv '
                       'with OUT/sweep.json; rerunning the same command resumes.')
    p.add_argument('kind', choices=('alpha', 'V', 'alpha-V'))
    add_common_options(p)
    p.add_argument('--alpha', help=f'alpha values, start:stop:step or a,b,c (default '
                   f'{DEFAULT_ALPHAS} for alpha sweeps, else the fractional_order parameter)')
    p.add_argument('--speed', help=f'V values in m/s (default {DEFAULT_SPEEDS} for V sweeps, '
                   'else the speed parameter)')
    p.add_argument('--transient', type=float, default=1.5, help='s discarded (default 1.5)')
    p.add_argument('--window', type=float, default=0.5, help='s sampled (default 0.5)')
    p.add_argument('--sample-every', type=int, default=1, help='keep every k-th step')
    p.add_argument('--state', default='w', choices=('z', 'w', 'theta', 'q'))
    p.add_argument('--control-period', type=float, default=None,
                   help='zero-order hold period in s (default: continuous feedback)')
    dask_options(p, 64, 'a batch step costs about the same for 50 or 100 points: prefer '
                 'large chunks')
    p.add_argument('--check-step', type=int, default=0, metavar='K',
                   help='re-run every K-th point at half the step; flag changed classes')
    p.set_defaults(func=cmd_sweep)


def build_spec(args: argparse.Namespace):
    base = model_params(args)   # validates --set / --preset
    if args.kind == 'alpha':
        alphas = parse_range(args.alpha or DEFAULT_ALPHAS, '--alpha')
        speeds = parse_range(args.speed, '--speed') if args.speed else [base.speed]
    elif args.kind == 'V':
        speeds = parse_range(args.speed or DEFAULT_SPEEDS, '--speed')
        alphas = parse_range(args.alpha, '--alpha') if args.alpha else [base.fractional_order]
    else:
        alphas = parse_range(args.alpha or DEFAULT_ALPHAS, '--alpha')
        speeds = parse_range(args.speed or DEFAULT_SPEEDS, '--speed')
    for a in alphas:
        if not 0 < a <= 1:
            raise CliError(f'--alpha value {a:g} is outside (0, 1]')
    for v in speeds:
        if v <= 0:
            raise CliError(f'--speed value {v:g} m/s must be > 0')
    for name in ('transient', 'window'):
        if getattr(args, name) < 0 or (name == 'window' and args.window <= 0):
            raise CliError(f'--{name}={getattr(args, name)} s must be positive')
    values = base.to_dict()
    values.pop('fractional_order')
    values.pop('speed')
    gains = assignments(args.gain or [], '--gain')
    load_controller(args.controller, gains)   # fail early on a bad name or gain
    try:
        return SweepSpec(base=values, alphas=tuple(float(a) for a in alphas),
                         speeds=tuple(float(v) for v in speeds), controller=args.controller,
                         gains=gains, transient=args.transient, window=args.window,
                         sample_every=args.sample_every, state=args.state,
                         control_period=args.control_period, chunk_size=args.chunk_size,
                         check_step=args.check_step)
    except ParameterError as e:
        raise CliError(str(e)) from None


def cmd_sweep(args: argparse.Namespace) -> int:
    spec = build_spec(args)
    out: Path = output_dir(args.out)
    n = len(spec.points())
    print(f'sweep {args.kind}: {n} points, {len(spec.alphas)} alpha x {len(spec.speeds)} V, '
          f'transient {spec.transient:g} s, window {spec.window:g} s -> {out}', flush=True)

    result = run_on_dask(run_sweep, spec, out, args)
    side = result.sidecar
    print(f"step {side['step']:g} s, solver {side['solver']}, model {side['model']}; "
          f'{result.computed_chunks} chunks computed, {result.reused_chunks} reused')
    counts: dict[str, int] = {}
    for r in result.rows:
        counts[r['label']] = counts.get(r['label'], 0) + 1
    print('classes: ' + ', '.join(f'{k} {v}' for k, v in sorted(counts.items())))
    changed = [r for r in result.rows if r['step_check'].startswith('changed')]
    if spec.check_step:
        checked = sum(1 for r in result.rows if r['step_check'])
        print(f'step check: {checked} points re-run at half step, {len(changed)} changed class')
    if args.kind == 'alpha-V':
        crit = critical_order_curve(model_params(args), load_controller(args.controller,
                                    spec.gains), spec.speeds)
        plot_alpha_v(result, figure_paths(out / 'alpha_v'),
                     [(p.speed, p.critical_order) for p in crit])
        print(f"alpha-V map: {out / 'alpha_v'}.png/.svg")
    else:
        axis = 'alpha' if args.kind == 'alpha' else 'speed'
        plot_orbit_diagram(result, axis, figure_paths(out / f'orbit_{args.kind}'))
        print(f'orbit diagram: {out}/orbit_{args.kind}.png/.svg')
    return 0
