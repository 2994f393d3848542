"""``fohssv sweep alpha|V|alpha-V``: orbit diagrams on Dask (see
:mod:`fohssv_sim.analysis.sweep`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..analysis.sweep import ProgressPrinter, SweepSpec, run_sweep
from ..params import ParameterError, steps_per_period
from . import command_help
from .common import (
    CliError,
    add_common_options,
    assignments,
    bounded,
    check_chunk_memory,
    check_chunk_size,
    check_grid,
    check_run_steps,
    check_scheduler,
    check_workers,
    figure_paths,
    job_folder,
    job_name,
    load_controller,
    model_params,
    out_given,
    output_dir,
    parse_range,
    refuse_both,
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
    except OSError as e:   # the scheduler went away or timed out after the first check
        raise CliError(f'--scheduler {args.scheduler}: {type(e).__name__}: {e}') from None
    progress.end()
    check.end()
    return result


def refuse_other_job(out: Path, sidecar: str, spec_dict: dict) -> None:
    """Refuse (before anything is printed or started) a folder whose sidecar records a
    different job; :func:`.sweep.run_chunks` checks the same again."""
    import json

    path = out / sidecar
    try:
        old = json.loads(path.read_text()).get('spec') if path.exists() else spec_dict
    except (OSError, ValueError, AttributeError):
        old = None
    if old != json.loads(json.dumps(spec_dict)):
        raise CliError(f'{out} holds a different job (see {path}); choose another --out or '
                       'delete that folder')


def check_dask_options(args: argparse.Namespace) -> None:
    """--workers in range, and a scheduler that answers at --scheduler (before any work)."""
    check_workers(args.workers)
    check_scheduler(args.scheduler)


def dask_options(p: argparse.ArgumentParser, chunk_size: int, chunk_text: str) -> None:
    """--chunk-size, --scheduler and --workers of the commands that run on Dask."""
    p.add_argument('--chunk-size', type=int, default=chunk_size,
                   help=f'points per Dask task, >= 1 ({chunk_text})')
    p.add_argument('--scheduler', help='address of an existing Dask scheduler, '
                   'tcp://HOST:PORT (default: a local cluster)')
    p.add_argument('--workers', type=int, default=0, help='local workers (default 0: one '
                   'per core; at most 4 per core)')


def register(sub) -> None:
    p = sub.add_parser('sweep', help=command_help('sweep'),
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
    p.add_argument('--transient', type=bounded('--transient', low=0, unit='s'), default=1.5,
                   help='s discarded (default 1.5)')
    p.add_argument('--window', type=bounded('--window', low=0, low_open=True, unit='s'),
                   default=0.5, help='s sampled (default 0.5)')
    p.add_argument('--sample-every', type=bounded('--sample-every', low=1, integer=True,
                                                  unit='steps'),
                   default=1, help='keep every k-th step (default 1)')
    p.add_argument('--state', default='w', choices=('z', 'w', 'theta', 'q'))
    p.add_argument('--control-period', type=bounded('--control-period', low=0,
                                                    low_open=True, unit='s'), default=None,
                   help='zero-order hold period in s, a whole multiple of the step (default: '
                   'continuous feedback)')
    dask_options(p, 64, 'a batch step costs about the same for 50 or 100 points: prefer '
                 'large chunks')
    p.add_argument('--check-step', type=bounded('--check-step', low=0, integer=True,
                                                unit='points'), default=0, metavar='K',
                   help='re-run every K-th point at half the step; flag changed classes '
                   '(default 0: off)')
    p.set_defaults(func=cmd_sweep)


def _grids(args: argparse.Namespace, base) -> tuple[list[float], list[float]]:
    def alphas(default: str | None):
        text = args.alpha if args.alpha is not None else default
        if text is None:
            return [base.fractional_order]
        return list(parse_range(text, '--alpha', parameter='fractional_order'))

    def speeds(default: str | None):
        text = args.speed if args.speed is not None else default
        if text is None:
            return [base.speed]
        return list(parse_range(text, '--speed', parameter='speed', unit='m/s'))

    if args.kind == 'alpha':
        return alphas(DEFAULT_ALPHAS), speeds(None)
    if args.kind == 'V':
        return alphas(None), speeds(DEFAULT_SPEEDS)
    return alphas(DEFAULT_ALPHAS), speeds(DEFAULT_SPEEDS)


def _check_sizes(args: argparse.Namespace, base, n_points: int) -> None:
    """Steps per run, points and work, the memory of one task, the hold period."""
    steps = check_run_steps('--transient + --window', args.transient + args.window, base.step)
    check_grid(f'the sweep ({args.kind})', n_points, steps)
    window_samples = int(args.window / base.step) // args.sample_every + 1
    check_chunk_memory('--chunk-size', min(args.chunk_size, n_points), window_samples, 32)
    if args.control_period is not None:
        if args.control_period > args.transient + args.window:
            raise CliError(f'--control-period={args.control_period:g} s is longer than the run '
                           f'(--transient + --window = {args.transient + args.window:g} s)')
        try:
            steps_per_period(args.control_period, base.step, '--control-period')
        except ValueError as e:
            raise CliError(str(e)) from None


def build_spec(args: argparse.Namespace):
    refuse_both(args, 'fractional_order', '--alpha', args.alpha is not None or args.kind != 'V',
                f' (an {args.kind} sweep sets alpha from --alpha, default {DEFAULT_ALPHAS})'
                if args.kind != 'V' else '')
    refuse_both(args, 'speed', '--speed', args.speed is not None or args.kind != 'alpha',
                f' (a {args.kind} sweep sets V from --speed, default {DEFAULT_SPEEDS})'
                if args.kind != 'alpha' else '')
    base = model_params(args)   # validates --set / --preset
    check_chunk_size(args.chunk_size)
    check_dask_options(args)
    alphas, speeds = _grids(args, base)
    _check_sizes(args, base, len(alphas) * len(speeds))
    for v in speeds:
        model_params(args, speed=v)          # the coefficients exist at every V
    values = base.to_dict()
    values.pop('fractional_order')
    values.pop('speed')
    gains = assignments(args.gain or [], '--gain')
    ctl = load_controller(args.controller, gains)   # fail early on a bad name or gain
    if ctl.affine() is None:
        raise CliError(f'--controller {args.controller} is not an affine state feedback '
                       '(u = K x + u0): sweeps run batched and need one (state_feedback, '
                       'lqr); run other laws with simulate() or fohssv gainmap')
    try:
        return SweepSpec(base=values, alphas=tuple(float(a) for a in alphas),
                         speeds=tuple(float(v) for v in speeds), controller=args.controller,
                         gains=gains, transient=args.transient, window=args.window,
                         sample_every=args.sample_every, state=args.state,
                         control_period=args.control_period, chunk_size=args.chunk_size,
                         check_step=args.check_step)
    except ParameterError as e:
        raise CliError(str(e)) from None


def _span(values, unit: str = '') -> str:
    return f'{values[0]:g}{unit}' if len(values) == 1 else f'{values[0]:g}-{values[-1]:g}{unit}'


def default_folder(kind: str, spec) -> Path:
    """``reports/sweep/<kind>_V<speeds>_alpha<alphas>-<hash of the spec>``."""
    slug = f'{kind}_V{_span(spec.speeds)}_alpha{_span(spec.alphas)}'
    return job_folder('sweep', job_name(slug, spec.to_dict()))


def cmd_sweep(args: argparse.Namespace) -> int:
    spec = build_spec(args)
    out: Path = args.out if out_given(args) else default_folder(args.kind, spec)
    refuse_other_job(out, 'sweep.json', spec.to_dict())
    output_dir(out)
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
    # here, not at the top: fit, gainmap and tune take their Dask options from this module,
    # and the figures and the Matignon curve import matplotlib, scipy.optimize and numba
    from ..analysis.diagrams import plot_alpha_v, plot_orbit_diagram
    from ..analysis.stability import critical_order_curve

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
