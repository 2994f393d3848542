"""``fohssv stability``: equilibria, eigenvalues, the Matignon wedge, alpha_c over V."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from ..analysis.stability import critical_order_curve, plot_critical_order, plot_wedge
from ..equilibria import find_equilibria
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


def register(sub) -> None:
    p = sub.add_parser('stability', help='equilibria, eigenvalues, Matignon wedge (Fig. 5), '
                       'alpha_c over V')
    add_common_options(p)
    p.add_argument('--alpha', type=float, help='fractional order for the verdict and the '
                   'wedge (default: the fractional_order parameter, 0.85)')
    p.add_argument('--speed', type=float, help='forward speed V (m/s), default 75')
    p.add_argument('--speeds', help='also alpha_c over these speeds, e.g. 75:90:0.5')
    p.set_defaults(func=cmd_stability)


def cmd_stability(args: argparse.Namespace) -> int:
    params = model_params(args, speed=args.speed) if args.speed else model_params(args)
    controller = load_controller(args.controller, assignments(args.gain or [], '--gain'))
    alpha = args.alpha if args.alpha is not None else params.fractional_order
    if not 0 < alpha <= 1:
        raise CliError(f'--alpha={alpha} is outside (0, 1]')
    output_dir(args.out)
    eqs = find_equilibria(params, controller)
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
    if args.speeds:
        speeds = parse_range(args.speeds, '--speeds')
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
    (args.out / 'stability.json').write_text(json.dumps(result, indent=2) + '\n')
    print(f"results: {args.out / 'stability.json'}")
    return 0
