"""``fohssv continue --vary NAME=START:END``: a branch of periodic orbits by continuation
(see :mod:`fohssv_sim.continuation`)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..params import PARAMETER_BY_NAME, ParameterError
from . import command_help
from .common import (
    CliError,
    add_common_options,
    assignments,
    bounded,
    figure_paths,
    load_controller,
    model_params,
    output_file,
    resolve_output,
)

BRANCH_FILE = 'branch.json'


def register(sub) -> None:
    p = sub.add_parser('continue', help=command_help('continue'),
                       description='Follow a branch of periodic orbits as one model parameter '
                       'varies, by pseudo-arclength continuation (folds are passed): the FOM '
                       'by harmonic balance from its Hopf point, the delay-free model by '
                       'shooting and the delayed model by harmonic balance of its DDE, both '
                       'from an orbit found by simulation. Writes OUT/branch.json '
                       'after every point and OUT/branch.png/.svg at the end; rerunning the '
                       'same command resumes an unfinished branch.')
    p.add_argument('--vary', required=True, metavar='NAME=START:END',
                   help='the varied model parameter or controller gain and its range, e.g. '
                   'fractional_order=0.7:1, speed=60:120 or pitch_rate_gain=-0.3:-0.1')
    add_common_options(p)
    p.add_argument('--points', type=bounded('--points', low=3, high=2000, integer=True,
                                            unit='points'), default=50,
                   help='about how many points along the range (default 50; more near folds)')
    p.add_argument('--harmonics', type=bounded('--harmonics', low=1, high=256, integer=True,
                                               unit='harmonics'), default=16,
                   help='harmonic count of harmonic balance (FOM; default 16, checked at the '
                   'last point by doubling)')
    p.add_argument('--sweep', type=Path, default=None, metavar='DIR',
                   help='a fohssv sweep output folder over the same parameter: its orbit '
                   'diagram is drawn beneath the branch')
    p.set_defaults(func=cmd_continue)


def parse_vary(text: str, gains: list[str] = ()) -> tuple[str, float, float]:
    """``NAME=START:END`` checked against the parameter table (numeric, in range), or NAME
    one of the controller's ``gains`` (its range is checked by building the controller).

    Raises:
        CliError: malformed, an unknown or non-numeric name, a bound out of range, or
            START == END.
    """
    if '=' not in text or ':' not in text.split('=', 1)[1]:
        raise CliError(f'--vary {text!r} must look like NAME=START:END, e.g. '
                       'fractional_order=0.7:1')
    name, rng = (s.strip() for s in text.split('=', 1))
    spec = PARAMETER_BY_NAME.get(name)
    if name not in gains and (spec is None or not spec.numeric):
        numeric = ', '.join([n for n, s in PARAMETER_BY_NAME.items() if s.numeric] +
                            list(gains))
        raise CliError(f'--vary {name!r} is not a numeric model parameter nor a gain of the '
                       f'controller; choose one of {numeric}')
    try:
        start, end = (float(v) for v in rng.split(':'))
    except ValueError:
        raise CliError(f'--vary {text!r}: START:END must be two numbers') from None
    for v in (start, end):
        if not math.isfinite(v):
            raise CliError(f'--vary {name}={v!r} must be finite')
        try:
            if spec is not None and name not in gains:
                spec.validate(v)
        except ParameterError as e:
            raise CliError(f'--vary: {e}') from None
    if start == end:
        raise CliError(f'--vary {text!r}: START and END must differ')
    return name, start, end


def cmd_continue(args: argparse.Namespace) -> int:
    from ..continuation.branch import load_branch, plot_branch
    from ..continuation.driver import ContinuationError
    from ..continuation.run import follow_orbits
    from ..continuation.vehicle import controller_gains

    gains = assignments(args.gain or [], '--gain')
    ctl = load_controller(args.controller, gains)
    name, start, end = parse_vary(args.vary, controller_gains(ctl))
    if name in assignments(args.set or [], '--set') or name in gains:
        raise CliError(f'--set/--gain {name}=... and --vary {name}=... both given; give it '
                       'once')
    if name in controller_gains(ctl):
        params = model_params(args)
        for v in (end, start):                          # valid at both ends
            ctl = load_controller(args.controller, {**gains, name: v})
    else:
        params = model_params(args, **{name: start})
        model_params(args, **{name: end})               # valid at both ends
    sweep = None
    if args.sweep is not None:
        from ..analysis.sweep import load_sweep
        try:
            sweep = load_sweep(args.sweep)
        except (OSError, ValueError, KeyError) as e:
            raise CliError(f'--sweep {args.sweep}: not a fohssv sweep folder ({e})') from None
    identity = {'vary': [name, start, end], 'model': params.to_dict(),
                'controller': args.controller, 'gains': gains, 'points': args.points,
                'harmonics': args.harmonics}
    out = resolve_output(args, 'continue', f'{params.model}_{name}{start:g}-{end:g}',
                         identity, files=(BRANCH_FILE,))
    path = output_file(out, BRANCH_FILE)
    old = load_branch(path) if path.exists() else None
    if old is not None and old.complete:
        print(f'{path} is complete; drawing it again')
        branch = old
    else:
        print(f'continue {params.model} over {name} = {start:g} -> {end:g} -> {out}',
              flush=True)
        try:
            branch = follow_orbits(params, ctl, name, start, end, points=args.points,
                                   harmonics=args.harmonics, checkpoint=path, resume=old,
                                   progress=lambda text: print(text, flush=True))
        except (ParameterError, ContinuationError) as e:
            raise CliError(str(e)) from None
    print(f"{len(branch.points)} points; bifurcations: " + (', '.join(
        f"{b['kind']} at {b['value']:.6g}" for b in branch.bifurcations) or 'none'))
    plot_branch(branch, figure_paths(out / 'branch'), sweep=sweep,
                axis_label='fractional order α' if name == 'fractional_order' else
                f"{name} ({PARAMETER_BY_NAME[name].unit})" if name in PARAMETER_BY_NAME else
                name)
    print(f'{path}; diagram {out}/branch.png/.svg')
    return 0
