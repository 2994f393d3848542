"""``fohssv stability``: equilibria, eigenvalues, the Matignon wedge, alpha_c over V."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from ..analysis.stability import critical_order_curve, plot_critical_order, plot_wedge
from ..equilibria import find_equilibria
from . import command_help
from .common import (
    CliError,
    add_common_options,
    assignments,
    bounded,
    computing,
    figure_paths,
    load_controller,
    model_params,
    output_file,
    parameter_type,
    parse_range,
    refuse_both,
    resolve_output,
)

#: Most speeds of ``--speeds`` (an equilibrium search each, about 0.1 s).
MAX_SPEEDS = 10_000


def register(sub) -> None:
    p = sub.add_parser('stability', help=command_help('stability'))
    add_common_options(p)
    p.add_argument('--alpha', type=bounded('--alpha', low=0, low_open=True, high=1,
                                           meaning='fractional order'),
                   help='fractional order for the verdict and the wedge (default: the '
                   'fractional_order parameter, 0.85)')
    p.add_argument('--speed', type=parameter_type('speed', '--speed'),
                   help='forward speed V (m/s), default: the speed parameter, 75')
    p.add_argument('--speeds', help='also alpha_c over these speeds (m/s), e.g. 75:90:0.5 '
                   f'(at most {MAX_SPEEDS})')
    p.set_defaults(func=cmd_stability)


def _inputs(args: argparse.Namespace):
    """Parameters, controller, alpha and the --speeds values, all checked before any work."""
    refuse_both(args, 'speed', '--speed', args.speed is not None)
    refuse_both(args, 'fractional_order', '--alpha', args.alpha is not None)
    params = model_params(args, speed=args.speed) if args.speed is not None else \
        model_params(args)
    gains = assignments(args.gain or [], '--gain')
    controller = load_controller(args.controller, gains)
    if not getattr(controller, 'stateless', True):
        raise CliError(f'--controller {args.controller} keeps internal state (it is not a '
                       'static law of the state): the equilibria and the Matignon test need '
                       'one; use a static law such as state_feedback or lqr')
    alpha = args.alpha if args.alpha is not None else params.fractional_order
    speeds = None
    if args.speeds is not None:
        speeds = parse_range(args.speeds, '--speeds', parameter='speed', unit='m/s',
                             max_values=MAX_SPEEDS)
        for v in speeds:
            model_params(args, speed=float(v))    # the coefficients exist at every V
    return params, controller, gains, alpha, speeds


def cmd_stability(args: argparse.Namespace) -> int:
    params, controller, gains, alpha, speeds = _inputs(args)
    given = f'V = {params.speed:g} m/s with {controller.describe()}'
    identity = {'params': params.to_dict(), 'alpha': alpha, 'controller': args.controller,
                'gains': gains, 'speeds': None if speeds is None else
                [float(v) for v in speeds]}
    slug = f"V{params.speed:g}_alpha{alpha:g}{'_speeds' if speeds is not None else ''}"
    with computing('the equilibrium search', given):
        eqs = find_equilibria(params, controller)
    args.out = resolve_output(args, 'stability', slug, identity, files=['stability.json'])
    result: dict[str, Any] = {'speed': params.speed, 'alpha': alpha,
                              'planing_form': params.planing_form,
                              'controller': controller.describe(), 'equilibria': []}
    print(f'closed loop, V = {params.speed:g} m/s, {controller.describe()}, planing '
          f'{params.planing_form}')
    if not eqs:
        print('no equilibrium found')
    for i, e in enumerate(eqs):
        verdict = 'stable' if e.stable(alpha) else 'unstable'
        print(f'equilibrium {i}: z = {e.state[0]:.6g} m, w = {e.state[1]:.6g} m/s, theta = '
              f'{e.state[2]:.6g} rad, q = {e.state[3]:.3g} rad/s, delta_c = {e.inputs[1]:.6g}')
        for lam in e.eigenvalues:
            arg = abs(math.atan2(lam.imag, lam.real)) / (math.pi / 2)
            print(f'  lambda = {lam.real:+.6g} {lam.imag:+.6g}j   |arg|/(pi/2) = {arg:.5f}')
        print(f'  alpha_c = {e.critical_order:.5f}: Matignon {verdict} at alpha = {alpha:g}')
        stem = args.out / f'wedge_V{params.speed:g}_alpha{alpha:g}_eq{i}'
        plot_wedge(e, alpha, figure_paths(stem), speed=params.speed)
        print(f'  wedge plot: {stem}.png/.svg')
        result['equilibria'].append({
            'state': e.state.tolist(), 'inputs': list(e.inputs),
            'eigenvalues': [[v.real, v.imag] for v in e.eigenvalues],
            'critical_order': e.critical_order, 'stable': e.stable(alpha)})
    if speeds is not None:
        with computing('alpha_c over --speeds', f'{args.speeds} m/s'):
            points = critical_order_curve(params, controller, speeds)
        print('\n     V (m/s)   alpha_c')
        for p in points:
            print(f'  {p.speed:10.4g}   {p.critical_order:.5f}')
        stem = args.out / 'critical_order'
        plot_critical_order(points, figure_paths(stem), alpha,
                            caption=f'{params.model} model, planing {params.planing_form}, '
                                    f'controller {args.controller}')
        result['critical_order_curve'] = [[p.speed, p.critical_order] for p in points]
        print(f'alpha_c(V) plot: {stem}.png/.svg')
    output_file(args.out, 'stability.json').write_text(json.dumps(result, indent=2) + '\n')
    print(f"results: {args.out / 'stability.json'}")
    return 0
