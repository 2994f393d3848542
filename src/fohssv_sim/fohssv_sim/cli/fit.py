"""``fohssv fit BAG --fit NAME[,NAME...]`` and ``fohssv fit --reference delayed --speeds ...``:
identify model parameters from a run (see :mod:`fohssv_sim.analysis.fit`).

Thin: parses the options into a :class:`~fohssv_sim.analysis.fit.FitSpec`, runs it on Dask,
prints one line per stage and the result, writes fit.json, the params YAML and the figures.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from . import command_help
from .common import (
    LIMITS,
    BagInputError,
    CliError,
    assignments,
    bounded,
    check_chunk_size,
    check_grid,
    check_run_steps,
    folder_arg,
    job_folder,
    number,
    output_dir,
    parse_range,
    resolve_output,
)
from .sweep import check_dask_options, dask_options

#: The rule of :func:`fohssv_sim.analysis.fit.data.default_bounds`, for --help.
BOUNDS_RULE = ("default: fractional_order over its whole range (0, 1]; any other parameter a "
               "factor of 2 either side of its resolved value for the run's model and speed "
               "(planing_offset 'consistent' = R'RV/L), [-1, 1] where it is 0, clipped to "
               "its allowed range")

#: What a fit writes into its folder (claimed in job.json: a folder holding another fit's
#: outputs is refused, never overwritten).
FIT_FILES = ('fit.json', 'fit_params.yaml', 'fit_overlay.png', 'fit_profile.png')
REFERENCE_FILES = ('reference.json', 'reference.md', 'alpha_tau.png')


def register(sub) -> None:
    p = sub.add_parser(
        'fit', help=command_help('fit'),
        description='Estimates the named model parameters so that the FOM, driven by the '
        "bag's recorded commands (open loop, held at the recorded times) or closed by "
        '--controller, reproduces the recorded states: a population on Dask, then '
        'scipy.optimize.least_squares; intervals from the Jacobian and a profile over alpha; '
        'the residual against --threshold, or "no value of alpha in [a, b] reproduces this '
        'run". Writes fit.json, fit_params.yaml (plant --ros-args --params-file) and the '
        'figures. With --reference delayed: the alpha whose FOM closed loop best reproduces '
        'the delayed closed loop at each speed of --speeds.')
    p.add_argument('bag', nargs='?', type=Path, help='rosbag2 folder (or .mcap file)')
    p.add_argument('--fit', dest='names', metavar='NAME[,NAME...]',
                   help='model parameters to estimate (default with --reference: '
                   'fractional_order)')
    p.add_argument('--bounds', action='append', metavar='NAME=LO:HI',
                   help=f'search range of a fitted parameter (repeatable; {BOUNDS_RULE})')
    p.add_argument('--objective', default='trajectory', choices=('trajectory', 'cycle'),
                   help='trajectory: weighted least squares on z, w, theta, q; cycle: '
                   'frequency, amplitude, mean and class of w (periodic or chaotic runs)')
    p.add_argument('--window', metavar='T0:T1', help='time window in s (default: the whole '
                   'run; the second half for --objective cycle)')
    p.add_argument('--horizon', choices=('auto', 'filter', 'grow', 'full'), default=None,
                   help='filter: the prediction errors of the model\'s Kalman filter over the '
                   'whole window (an open-loop replay); grow: the fitted horizon grown from '
                   '1/16 of the window, doubling, bisected where the model departs; full: one '
                   'trajectory over the whole window (default with --reference); auto (default '
                   'for bags): filter open loop, grow with --controller')
    p.add_argument('--controller', help='close the loop with this controller plugin instead '
                   'of replaying the recorded commands (an affine law runs compiled, any other '
                   'point by point; the fit is then judged over the whole window; default with '
                   '--reference: state_feedback, eq. 31)')
    p.add_argument('--gain', action='append', metavar='NAME=VALUE',
                   help='controller parameter (repeatable)')
    p.add_argument('--set', action='append', metavar='NAME=VALUE',
                   help="model parameter overriding the bag's (repeatable)")
    p.add_argument('--preset', default='resolved', help="'resolved' (default) or "
                   "'paper-literal'")
    p.add_argument('--weights', metavar='z=1,w=1,theta=1,q=1',
                   help='weights of the states in the trajectory objective (default all 1; '
                   '0: not compared)')
    p.add_argument('--measure', metavar='STATE[,STATE...]',
                   help='the measured states, any of z, w, theta, q (default all four): the '
                   'others are never read (any number in the bag); each fitted '
                   'parameter the measured states cannot fix is reported as not identifiable')
    p.add_argument('--noise', metavar='STATE=SIGMA[,...]',
                   help='measurement noise (standard deviation, in the state\'s unit: m, m/s, '
                   'rad, rad/s) of the named states; default: estimated from the data (second '
                   'differences); "reproduces" is a test of the residual against it (99 %%)')
    p.add_argument('--noise-floor', type=bounded('--noise-floor', low=0, high=1, low_open=True,
                                                 high_open=True),
                   help='the smallest noise assumed, a fraction of each state\'s standard '
                   'deviation over the window (default 1e-3: clean data '
                   'are judged at the model\'s precision)')
    p.add_argument('--threshold', type=bounded('--threshold', low=0, low_open=True),
                   default=0.05,
                   help='--objective cycle: acceptance threshold of the relative feature '
                   'errors (default 0.05); the trajectory objective is judged against the '
                   'noise')
    p.add_argument('--population', type=int, default=64,
                   help='points of the global stage (default 64)')
    p.add_argument('--starts', type=int, default=2,
                   help='best population points that start least_squares (default 2)')
    p.add_argument('--seed', type=bounded('--seed', low=0, high=2**32 - 1, integer=True),
                   default=0, help='seed of the Latin hypercube')
    p.add_argument('--profile-points', type=int, default=41,
                   help='alpha values of the coarse profile over the bounds (default 41)')
    p.add_argument('--no-step-check', dest='step_check', action='store_false',
                   help='skip the refit at half the step (whose shift widens the intervals)')
    p.add_argument('--control-period', type=bounded('--control-period', low=0, low_open=True,
                                                    unit='s'),
                   help='s (default: the bag\'s recorded plant parameter; 1e-4 with '
                   '--reference)')
    p.add_argument('--namespace', help="the vehicle's namespace when the bag holds several")
    p.add_argument('--reference', choices=('delayed',), help='fit the FOM to the delayed '
                   'model\'s closed loop instead of a bag')
    p.add_argument('--speeds', metavar='VALUES', help='with --reference: V in m/s, '
                   'start:stop:step or a,b,c (e.g. 70:90:2.5)')
    p.add_argument('--duration', type=bounded('--duration', low=0, low_open=True, unit='s'),
                   default=None,
                   help='with --reference: s per run from x(0) = 0 (default 1)')
    p.add_argument('--out', type=folder_arg, help='output folder (default '
                   f"{job_folder('fit', 'BAG-HASH')}, or "
                   f"{job_folder('fit', 'reference-delayed_VLOW-HIGH-HASH')}: named after the "
                   'job, so rerunning the same fit resumes there; job.json records it)')
    dask_options(p, 16, 'one batched compiled call')
    p.add_argument('--processes', action='store_true',
                   help='local Dask workers as processes (default: threads of this process; '
                   'the compiled kernel runs outside the GIL)')
    p.set_defaults(func=cmd_fit)


def _check_sizes(args: argparse.Namespace) -> None:
    """The search's counts within their limits, before any simulation, file or worker (a
    --population of 1e9 ran for minutes; a --starts above it was silently cut to it)."""
    number('--population', args.population, low=2, high=LIMITS['points'], integer=True,
           unit='points', meaning='points of the global stage')
    number('--starts', args.starts, low=1, high=args.population, integer=True,
           unit='points', meaning='best population points that start least_squares: at most '
           '--population')
    number('--profile-points', args.profile_points, low=3, high=LIMITS['range_values'],
           integer=True, unit='points', meaning='alpha values of the coarse profile')
    check_chunk_size(args.chunk_size)


def _whole_steps(period: float, step: float, name: str = '--control-period') -> int:
    """Integration steps per control period; a period that is not a whole multiple of the
    step is refused (it was rounded: 3e-5 s ran as 4e-5 s at the 2e-5 s step)."""
    from ..params import steps_per_period

    try:
        return steps_per_period(period, step, name)
    except ValueError as e:
        raise CliError(str(e)) from None


def _names(text: str | None) -> tuple[str, ...]:
    from ..analysis.fit import FitError, check_names

    names = tuple(n.strip() for n in (text or '').split(',') if n.strip())
    try:
        return check_names(names)
    except FitError as e:
        raise CliError(str(e)) from None


def _bounds(items: list[str] | None) -> dict[str, tuple[float, float]]:
    out = {}
    for item in items or []:
        if '=' not in item or ':' not in item.split('=', 1)[1]:
            raise CliError(f'--bounds {item!r} must look like NAME=LO:HI, e.g. '
                           'fractional_order=0.6:1')
        name, rng = item.split('=', 1)
        try:
            lo, hi = (float(v) for v in rng.split(':'))
        except ValueError:
            raise CliError(f'--bounds {item!r}: LO and HI must be numbers') from None
        out[name.strip()] = (lo, hi)
    return out


def _window(text: str | None) -> tuple[float, float] | None:
    if not text:
        return None
    try:
        a, b = (float(v) for v in text.split(':'))
    except ValueError:
        raise CliError(f'--window {text!r} must look like T0:T1 (seconds)') from None
    if not (0 <= a < b):
        raise CliError(f'--window {text!r}: need 0 <= T0 < T1 (seconds)')
    return a, b


def _weights(text: str | None) -> tuple[float, float, float, float]:
    if not text:
        return (1.0, 1.0, 1.0, 1.0)
    w = assignments(text.split(','), '--weights')
    bad = sorted(set(w) - {'z', 'w', 'theta', 'q'})
    if bad or any(not isinstance(v, float) for v in w.values()):
        raise CliError(f'--weights {text!r}: give z=, w=, theta=, q= numbers')
    return tuple(float(w.get(n, 1.0)) for n in ('z', 'w', 'theta', 'q'))


STATES = ('z', 'w', 'theta', 'q')


def _measured_weights(args: argparse.Namespace) -> tuple[float, float, float, float]:
    """--weights with the states --measure leaves out set to 0."""
    w = _weights(args.weights)
    if not args.measure:
        return w
    names = [n.strip() for n in args.measure.split(',') if n.strip()]
    bad = [n for n in names if n not in STATES]
    if bad or not names:
        raise CliError(f'--measure {args.measure!r}: give states among z, w, theta, q '
                       '(e.g. z,theta)')
    return tuple(v if n in names else 0.0 for n, v in zip(STATES, w))


def _noise(text: str | None) -> tuple[float | None, ...]:
    if not text:
        return (None,) * 4
    given = assignments(text.split(','), '--noise')
    bad = sorted(set(given) - set(STATES))
    if bad:
        raise CliError(f'--noise {bad[0]}: not a state; give z=, w=, theta=, q= '
                       'standard deviations in the state\'s unit')
    for n, v in given.items():
        if not isinstance(v, float) or not (0 < v < float('inf')):
            raise CliError(f'--noise {n}={v}: need a finite number > 0 (the standard '
                           f'deviation of {n} in its unit)')
    return tuple(given.get(n) for n in STATES)


def _spec(args: argparse.Namespace, names, base, window, controller, horizon):
    from ..analysis.fit import FitError, FitSpec, resolve_bounds

    try:
        bounds = resolve_bounds(names, _bounds(args.bounds), base)
        gains = assignments(args.gain or [], '--gain')
        spec = FitSpec(names=names, bounds=bounds, base=base.to_dict(),
                       objective=args.objective, window=window, controller=controller,
                       gains=gains, weights=_measured_weights(args),
                       noise=_noise(args.noise),
                       **({} if args.noise_floor is None else {'noise_floor': args.noise_floor}),
                       threshold=args.threshold,
                       horizon=horizon, population=args.population, starts=args.starts,
                       seed=args.seed, profile_points=args.profile_points,
                       chunk_size=args.chunk_size, step_check=args.step_check)
        spec.validate()
    except FitError as e:
        raise CliError(str(e)) from None
    return spec


class _Dask:
    """One Dask client for every population job of the command (a local cluster unless
    --scheduler), closed at the end."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.client = self.cluster = None

    def __enter__(self):
        import os

        from dask.distributed import Client

        from ..analysis.cluster import local_cluster

        if self.args.scheduler:
            self.client = Client(self.args.scheduler, timeout='20s')
        else:
            # worker threads in this process: the compiled kernel releases the GIL, and
            # threads need no start-up, imports or numba cache loads of their own, nor the
            # problem pickled to them (measured: bench/bench_fit.py --processes-too)
            n = self.args.workers or os.cpu_count() or 1
            self.cluster = local_cluster(n, processes=self.args.processes)
            self.client = Client(self.cluster)
        return self.client

    def __exit__(self, *exc: Any) -> None:
        import logging

        # the nanny's 'still alive after 4 s, killing' at close is not news to the user
        logging.getLogger('distributed').setLevel(logging.ERROR)
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _run(spec, data, out: Path, client, sidecar: dict[str, Any], threads: int):
    """run_fit, its local stage on ``threads`` threads (--workers: 0, one per core)."""
    from ..analysis.fit import FitError, run_fit
    from ..analysis.sweep import ProgressPrinter

    progress = ProgressPrinter('points')
    try:
        result = run_fit(spec, data, out, client=client, progress=progress,
                         log=lambda s: (progress.end(), print(s, flush=True)),
                         sidecar=sidecar, threads=threads)
    except FitError as e:
        raise CliError(str(e)) from None
    except ValueError as e:          # a folder holding another job (run_chunks)
        raise CliError(str(e)) from None
    progress.end()
    return result


def cmd_fit(args: argparse.Namespace) -> int:
    if args.reference:
        return _cmd_reference(args)
    if args.bag is None:
        raise CliError('give a BAG to fit, or --reference delayed --speeds VALUES')
    for option, value in (('--speeds', args.speeds), ('--duration', args.duration)):
        if value is not None:     # never silently ignored
            raise CliError(f'{option} {value} is for --reference: a bag fit takes the run '
                           'from the bag; drop it')
    _check_sizes(args)
    from ..analysis.fit import (
        FitError,
        Problem,
        bag_sha256,
        base_from_run,
        data_from_run,
        write_outputs,
    )
    from ..bag import BagError, load_run

    names = _names(args.names)
    window = _window(args.window)
    try:
        run = load_run(args.bag, namespace=args.namespace)
    except BagError as e:
        raise BagInputError(str(e)) from None
    if run.t.size == 0:
        raise BagInputError(f'{args.bag}: no state messages to fit')
    try:
        base = base_from_run(run, assignments(args.set or [], '--set'), args.preset)
        data = data_from_run(run, base, args.control_period)
    except FitError as e:
        raise CliError(str(e)) from None
    if args.controller is None and data.inputs is None:
        raise CliError(f'{args.bag}: no command messages, so the recorded commands cannot '
                       'drive the model; give --controller NAME to close the loop with a '
                       'plugin')
    if window is None and args.objective == 'cycle':
        window = (float(data.t[-1]) / 2, float(data.t[-1]))
    hold = _whole_steps(data.control_period, base.step,
                        '--control-period' if args.control_period else 'control_period')
    check_grid('the global stage (--population)', args.population, data.n_periods * hold)
    spec = _spec(args, names, base, window, args.controller, args.horizon or 'auto')
    try:
        Problem(spec, data)     # an empty window, no drive: refused before any file or Dask
    except FitError as e:
        raise CliError(str(e)) from None
    check_dask_options(args)    # --workers in range, a scheduler that answers
    sha = bag_sha256(args.bag)
    data.source['sha256'] = sha
    identity = {'bag_sha256': sha, 'namespace': args.namespace,
                'control_period': data.control_period, 'fit': spec.to_dict()}
    out = resolve_output(args, 'fit', Path(args.bag).resolve().name, identity,
                         files=FIT_FILES)
    print(f"fit {','.join(names)} of {args.bag} ({data.n_periods} control periods of "
          f'{data.control_period:g} s, step {base.step:g} s, '
          f"{'closed loop: ' + args.controller if args.controller else 'open loop'}, "
          f'{spec.objective} objective) -> {out}', flush=True)
    with _Dask(args) as client:
        result = _run(spec, data, out, client, {'bag_sha256': sha}, args.workers)
    paths = write_outputs(result, out, {'bag': str(args.bag), 'bag_sha256': sha})
    print(result.message)
    print('wrote ' + ', '.join(str(p) for p in paths if p.suffix != '.svg'))
    return 0


def _cmd_reference(args: argparse.Namespace) -> int:
    from ..analysis.fit import FitError, reference_data, write_reference
    from .common import model_params

    if args.bag is not None:
        raise CliError('--reference fits the delayed model, not a bag: drop BAG')
    if not args.speeds:
        raise CliError('--reference delayed needs --speeds VALUES (m/s), e.g. 70:90:2.5')
    speeds = [float(v) for v in parse_range(args.speeds, '--speeds')]
    if any(v <= 0 for v in speeds):
        raise CliError(f'--speeds {args.speeds}: every V must be > 0 m/s')
    names = _names(args.names or 'fractional_order')
    if args.duration is None:
        args.duration = 1.0
    _check_sizes(args)
    window = _window(args.window)
    if window is None and args.objective == 'cycle':
        window = (args.duration / 2, args.duration)
    controller = args.controller or 'state_feedback'
    cp = args.control_period or 1e-4
    if cp > args.duration:
        raise CliError(f'--control-period={cp:g} s is longer than the run '
                       f'(--duration={args.duration:g} s)')
    overrides = assignments(args.set or [], '--set')
    for name, why in (('model', 'the reference fits the FOM (fractional) to the delayed model'),
                      ('speed', 'the reference runs at each V of --speeds')):
        if name in overrides:     # never silently replaced
            raise CliError(f'--set {name}={overrides[name]} is not used with --reference: '
                           f'{why}; drop it')
    jobs = []
    for v in speeds:
        fom = model_params(args, **{**overrides, 'speed': v, 'model': 'fractional'})
        steps = check_run_steps('--duration', args.duration, fom.step)   # before any run
        _whole_steps(cp, fom.step)
        check_grid('the global stage (--population)', args.population, steps)
        spec = _spec(args, names, fom, window, controller, args.horizon or 'full')
        try:
            data = reference_data(fom, controller, spec.gains, args.duration, cp)
        except FitError as e:
            raise CliError(str(e)) from None
        jobs.append((v, spec, data))
    check_dask_options(args)    # --workers in range, a scheduler that answers
    identity = {'reference': 'delayed', 'speeds': speeds, 'duration': args.duration,
                'control_period': cp, 'fit': [spec.to_dict() for _v, spec, _d in jobs]}
    out = resolve_output(args, 'fit', f'reference-delayed_V{speeds[0]:g}-{speeds[-1]:g}',
                         identity, files=REFERENCE_FILES)
    print(f'fit {",".join(names)}: FOM vs delayed closed loop ({controller}, control period '
          f'{cp:g} s, {args.duration:g} s from x(0) = 0, {args.objective} objective) at '
          f'{len(speeds)} speeds -> {out}', flush=True)
    results = []
    with _Dask(args) as client:
        for v, spec, data in jobs:
            print(f'V = {v:g} m/s (tau = L/V = {data.source["tau"]:.6g} s)', flush=True)
            sub = output_dir(out / f'V{v:g}')
            result = _run(spec, data, sub, client, {'reference': 'delayed', 'speed': v},
                          args.workers)
            results.append((v, result, data))
            print('  ' + result.message, flush=True)
    paths = write_reference(results, out)
    print('wrote ' + ', '.join(str(p) for p in paths if p.suffix != '.svg'))
    return 0
