"""``fohssv gainmap``: two gains of a controller over a grid (see
:mod:`fohssv_sim.analysis.gainmap`).

Thin: parses the options into a :class:`~fohssv_sim.analysis.gainmap.GainMapSpec`, runs it,
prints, draws. All logic is in :mod:`fohssv_sim.analysis.gainmap`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

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
    job_folder,
    job_name,
    model_params,
    out_given,
    output_dir,
    parameter_type,
    parse_range,
    refuse_both,
)
from .sweep import check_dask_options, dask_options, refuse_other_job, run_on_dask


def register(sub) -> None:
    p = sub.add_parser(
        'gainmap', help=command_help('gainmap'),
        description='Sweeps two gains of a controller over a grid (other gains fixed with '
        '--gain), runs every closed loop from x(0) = 0 (batched for affine laws), classifies it '
        '(steady / drifting / periodic / chaotic / diverged) and scores it (peak |Fp|, time to '
        'settle, RMS of delta_c); draws the maps with the linearisation\'s Matignon boundary '
        '(alpha_c = alpha). Runs on Dask: a local cluster by default, or --scheduler ADDRESS. '
        'Results stream to OUT/chunks/*.csv with OUT/gainmap.json; rerunning the same command '
        'resumes.')
    add_common_options(p)
    p.add_argument('--x', required=True, metavar='NAME=VALUES',
                   help='first gain and its values, start:stop:step or a,b,c, e.g. '
                   'pitch_rate_gain=-1:0:0.1')
    p.add_argument('--y', required=True, metavar='NAME=VALUES', help='second gain, as --x')
    p.add_argument('--model', help='model (default: the model parameter, fractional)')
    p.add_argument('--alpha', type=parameter_type('fractional_order', '--alpha'),
                   help='fractional order (default: the fractional_order parameter, 0.85)')
    p.add_argument('--speed', type=parameter_type('speed', '--speed'),
                   help='V in m/s (default: the speed parameter, 75)')
    p.add_argument('--duration', type=bounded('--duration', low=0, low_open=True, unit='s'),
                   default=2.0, help='s per run (default 2)')
    p.add_argument('--transient', type=bounded('--transient', low=0, unit='s'), default=1.5,
                   help='s before the classification window (default 1.5)')
    p.add_argument('--control-period', type=bounded('--control-period', low=0, unit='s'),
                   default=1e-4,
                   help='zero-order hold period in s (default 1e-4, the plant\'s); 0 = '
                   'continuous feedback (stateless controllers only)')
    p.add_argument('--settle-band', type=bounded('--settle-band', low=0, low_open=True,
                                                 high=1, meaning='relative band'),
                   default=0.02,
                   help='settled when |w - w*| <= band * max(|w*|, 0.1 m/s) (default 0.02)')
    p.add_argument('--envelope-speeds', metavar='VALUES',
                   help='worst case over these V (m/s), e.g. 60:120:20')
    p.add_argument('--envelope-alphas', metavar='VALUES',
                   help='worst case over these alpha, e.g. 0.7:1:0.1')
    dask_options(p, 128, 'one batched solver call; larger batches cost less per point')
    p.add_argument('--check-step', type=bounded('--check-step', low=0, integer=True,
                                                unit='points'), default=0, metavar='K',
                   help='re-run every K-th point at half the step; flag changed outcomes')
    p.set_defaults(func=cmd_gainmap, out=None)


def _axis(text: str, option: str) -> tuple[str, tuple[float, ...]]:
    if '=' not in text:
        raise CliError(f'{option} {text!r} must look like NAME=VALUES, e.g. '
                       'pitch_rate_gain=-1:0:0.1')
    name, values = text.split('=', 1)
    return name.strip(), tuple(round(float(v), 12) for v in parse_range(
        values, f'{option} {name.strip()}'))


def build_spec(args: argparse.Namespace):
    from ..analysis.gainmap import GainMapError, GainMapSpec

    refuse_both(args, 'fractional_order', '--alpha', args.alpha is not None)
    refuse_both(args, 'speed', '--speed', args.speed is not None)
    refuse_both(args, 'model', '--model', args.model is not None)
    over = {'model': args.model} if args.model is not None else {}
    base = model_params(args, **over)
    values = base.to_dict()
    alpha = values.pop('fractional_order') if args.alpha is None else args.alpha
    speed = values.pop('speed') if args.speed is None else args.speed
    values.pop('fractional_order', None)
    values.pop('speed', None)
    gx, xs = _axis(args.x, '--x')
    gy, ys = _axis(args.y, '--y')
    env_v = tuple(float(v) for v in parse_range(
        args.envelope_speeds, '--envelope-speeds', parameter='speed', unit='m/s')
    ) if args.envelope_speeds is not None else ()
    env_a = tuple(float(v) for v in parse_range(
        args.envelope_alphas, '--envelope-alphas', parameter='fractional_order')
    ) if args.envelope_alphas is not None else ()
    for v in (speed, *env_v):
        model_params(args, **over, speed=float(v))     # the coefficients exist at every V
    check_chunk_size(args.chunk_size)
    check_dask_options(args)
    if args.transient >= args.duration:
        raise CliError(f'--transient={args.transient:g} s must be shorter than --duration='
                       f'{args.duration:g} s')
    if args.control_period > args.duration:
        raise CliError(f'--control-period={args.control_period:g} s is longer than the run '
                       f'(--duration={args.duration:g} s)')
    steps = check_run_steps('--duration', args.duration, base.step)
    n_points = len(xs) * len(ys) * max(1, len(env_v) or 1) * max(1, len(env_a) or 1)
    check_grid('the gain map', n_points, steps)
    every = max(1, round(args.control_period / base.step)) if args.control_period else 5
    check_chunk_memory('--chunk-size', min(args.chunk_size, n_points), steps // every + 1)
    spec = GainMapSpec(
        controller=args.controller, gain_x=gx, x_values=xs, gain_y=gy, y_values=ys,
        gains=assignments(args.gain or [], '--gain'), base=values, alpha=float(alpha),
        speed=float(speed), envelope_speeds=env_v, envelope_alphas=env_a,
        duration=args.duration, transient=args.transient,
        control_period=args.control_period or None, settle_band=args.settle_band,
        chunk_size=args.chunk_size, check_step=max(0, args.check_step))
    try:
        spec.validate()
    except GainMapError as e:
        raise CliError(str(e)) from None
    return spec


def default_folder(spec) -> Path:
    """``reports/gainmap/<controller>_<gain x>_<gain y>-<hash of the spec>``."""
    slug = f'{spec.controller}_{spec.gain_x}_{spec.gain_y}'
    return job_folder('gainmap', job_name(slug, spec.to_dict()))


def cmd_gainmap(args: argparse.Namespace) -> int:
    from ..analysis.gainmap import plot_gain_map, run_gain_map, summary_lines

    spec = build_spec(args)
    out: Path = args.out if out_given(args) else default_folder(spec)
    refuse_other_job(out, 'gainmap.json', spec.to_dict())
    output_dir(out)
    print(f'gainmap {spec.controller}: {spec.gain_x} ({len(spec.x_values)}) x {spec.gain_y} '
          f'({len(spec.y_values)}), {len(spec.scenarios())} scenario(s), {spec.n_points} '
          f'points, {spec.duration:g} s each -> {out}', flush=True)
    result = run_on_dask(run_gain_map, spec, out, args)
    for line in summary_lines(result):
        print(line)
    written = []
    if spec.has_scenario(spec.alpha, spec.speed):
        written += plot_gain_map(result, out / 'gainmap')
    if spec.envelope:
        written += plot_gain_map(result, out / 'envelope', worst=True)
    print('figures: ' + ', '.join(str(p) for p in written if p.suffix == '.png'))
    return 0
