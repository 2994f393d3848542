"""``fohssv``: the analysis command line (pure Python, no ROS needed).

    fohssv stability [--alpha A] [--speed V] [--speeds 75:90:0.5] [--out DIR]
    fohssv plot BAG... [--out DIR] [--namespace NS]
    fohssv sweep alpha|V|alpha-V [...]
    fohssv gainmap --x NAME=VALUES --y NAME=VALUES [...]
    fohssv report [--out DIR]
    fohssv repair BAG

Model parameters are set with ``--set name=value`` (repeatable; names as in the README's
parameter table) and ``--preset paper-literal``; the controller with ``--controller NAME``
(a plugin of group ``fohssv.controllers``) and ``--gain name=value``. Errors print one line;
nothing prints a traceback for bad input. Exit status: 0 done, 1 a bag that is missing,
unreadable or not sound (every bag command alike), 2 any other bad input, 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .params import ModelParameters, ParameterError

__all__ = ['main', 'load_controller', 'parse_range']


#: Exit codes of every subcommand: 0 done; 1 a bag that is missing, unreadable or not sound
#: (``plot``, ``check``, ``repair``, ``info`` alike); 2 any other bad input (options, values,
#: an ``--out`` that is not a folder); 130 interrupted.
EXIT_OK, EXIT_BAD_BAG, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


class CliError(ValueError):
    """A user error: printed as one line, exit status ``exit_code`` (2)."""

    exit_code = EXIT_USAGE


class BagInputError(CliError):
    """A bag given on the command line is missing, unreadable or not a bag: exit status 1,
    as ``fohssv check`` gives for it."""

    exit_code = EXIT_BAD_BAG


def output_dir(path: Path, option: str = '--out') -> Path:
    """Create the output folder ``path`` (and its parents) if needed.

    Raises:
        CliError: ``path`` (or a parent) exists and is not a folder, or cannot be created.
    """
    if path.exists() and not path.is_dir():
        raise CliError(f'{option} {path}: exists and is not a folder; give a folder (the '
                       'figures and results are written into it)')
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f'{option} {path}: cannot create the folder ({exc.strerror or exc})'
                       ) from None
    return path


def load_controller(name: str, gains: dict[str, Any] | None = None) -> Any:
    """Instantiate the controller plugin ``name`` through
    :func:`fohssv_controller.registry.load` (entry point group ``fohssv.controllers``).

    Raises:
        CliError: unknown or broken plugin (the message lists the valid names), bad gains,
            or fohssv_controller not installed.
    """
    try:
        from fohssv_controller.registry import UnknownController, load
    except ModuleNotFoundError:
        raise CliError('controllers need the fohssv_controller package; build the workspace '
                       '(make setup) or install it') from None
    try:
        return load(name)(**(gains or {}))
    except (UnknownController, ParameterError, TypeError, ValueError) as e:
        raise CliError(str(e)) from None


def _assignments(items: Sequence[str], what: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        if '=' not in item:
            raise CliError(f'{what} {item!r} must look like name=value')
        k, v = item.split('=', 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            out[k.strip()] = v.strip()
    return out


def model_params(args: argparse.Namespace, **overrides: Any) -> ModelParameters:
    """ModelParameters from ``--preset`` and ``--set`` (then ``overrides``)."""
    values = _assignments(args.set or [], '--set')
    values.update(overrides)
    try:
        return ModelParameters.preset(args.preset, **values)
    except ParameterError as e:
        raise CliError(str(e)) from None


def parse_range(text: str, name: str) -> np.ndarray:
    """``a:b:step`` (inclusive of b within rounding), or comma-separated values."""
    try:
        if ':' in text:
            a, b, s = (float(x) for x in text.split(':'))
            if s <= 0 or b < a:
                raise ValueError
            n = int(math.floor((b - a) / s + 1e-9)) + 1
            return a + s * np.arange(n)
        return np.array([float(x) for x in text.split(',')])
    except ValueError:
        raise CliError(f'{name}={text!r} must be start:stop:step (stop >= start, step > 0) or '
                       'comma-separated numbers') from None


def _figure_paths(stem: Path) -> list[Path]:
    """``stem``.png and ``stem``.svg (stem names may contain dots, e.g. alpha0.85)."""
    return [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']


def _common(p: argparse.ArgumentParser, controller: bool = True) -> None:
    p.add_argument('--set', action='append', metavar='NAME=VALUE',
                   help='model parameter (repeatable), e.g. --set speed=84.5')
    p.add_argument('--preset', default='resolved', help="'resolved' (default) or "
                   "'paper-literal' (L = 1.18 m, w0 = 2.8 m/s, tau = 0.02069 s)")
    if controller:
        p.add_argument('--controller', default='state_feedback',
                       help='controller plugin name (default: state_feedback, eq. 31)')
        p.add_argument('--gain', action='append', metavar='NAME=VALUE',
                       help='controller parameter (repeatable), e.g. --gain depth_gain=12')
    p.add_argument('--out', type=Path, default=Path('reports'), help='output folder')


# -- stability --------------------------------------------------------------------------------
def cmd_stability(args: argparse.Namespace) -> int:
    from .analysis.stability import critical_order_curve, plot_critical_order, plot_wedge
    from .equilibria import find_equilibria

    params = model_params(args, speed=args.speed) if args.speed else model_params(args)
    controller = load_controller(args.controller, _assignments(args.gain or [], '--gain'))
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
        plot_wedge(e, alpha, _figure_paths(stem), speed=params.speed)
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
        plot_critical_order(points, _figure_paths(stem), alpha,
                            caption=f'{params.model} model, planing {params.planing_form}, '
                                    f'controller {args.controller}')
        result['critical_order_curve'] = [[p.speed, p.critical_order] for p in points]
        print(f'alpha_c(V) plot: {stem}.png/.svg')
    (args.out / 'stability.json').write_text(json.dumps(result, indent=2) + '\n')
    print(f"results: {args.out / 'stability.json'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='fohssv', description='FO-HSSV analysis: stability, '
                                 'orbit diagrams, plots of recorded runs, the paper report.')
    sub = ap.add_subparsers(dest='command', required=True)

    p = sub.add_parser('stability', help='equilibria, eigenvalues, Matignon wedge (Fig. 5), '
                       'alpha_c over V')
    _common(p)
    p.add_argument('--alpha', type=float, help='fractional order for the verdict and the '
                   'wedge (default: the fractional_order parameter, 0.85)')
    p.add_argument('--speed', type=float, help='forward speed V (m/s), default 75')
    p.add_argument('--speeds', help='also alpha_c over these speeds, e.g. 75:90:0.5')
    p.set_defaults(func=cmd_stability)

    for register in _EXTRA_COMMANDS:
        register(sub)
    return ap


#: Other modules add subcommands here: callables taking the subparsers object.
_EXTRA_COMMANDS: list = []


def main(argv: Sequence[str] | None = None) -> int:
    _load_extra_commands()
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CliError as e:
        print(f'fohssv {args.command}: error: {e}', file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print(f'fohssv {args.command}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


def _load_extra_commands() -> None:
    if _EXTRA_COMMANDS:
        return
    import importlib

    for mod in ('fohssv_sim.analysis.cli_plot', 'fohssv_sim.analysis.cli_sweep',
                'fohssv_sim.analysis.cli_report', 'fohssv_sim.analysis.cli_gainmap'):
        try:
            m = importlib.import_module(mod)
        except ModuleNotFoundError as e:
            if e.name != mod:
                raise
            continue
        _EXTRA_COMMANDS.append(m.register)


if __name__ == '__main__':
    sys.exit(main())
