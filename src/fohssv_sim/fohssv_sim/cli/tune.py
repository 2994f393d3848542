"""``fohssv tune``: the best worst case of a controller over a V-alpha envelope (see
:mod:`fohssv_sim.analysis.tune`).

Thin: parses the options into a :class:`~fohssv_sim.analysis.tune.TuneSpec`, runs it, prints,
draws, writes the winner's parameters file. All logic is in :mod:`fohssv_sim.analysis.tune`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import Any

from . import command_help
from .common import (
    CliError,
    add_common_options,
    assignments,
    bounded,
    check_chunk_size,
    check_grid,
    check_run_steps,
    job_folder,
    job_name,
    model_params,
    out_given,
    output_dir,
    parse_range,
)
from .sweep import ProgressPrinter, check_dask_options, dask_options


def register(sub) -> None:
    p = sub.add_parser(
        'tune', help=command_help('tune'),
        description='Global search (scipy differential evolution) over numeric parameters of '
        'a controller for the best worst case over the envelope --envelope-speeds x '
        '--envelope-alphas. Score, lexicographic: every scenario steady first, then (affine '
        'laws) the Matignon margin min(alpha_c - alpha), then the --objective metric. Each '
        'generation runs as batched solver calls on Dask (chunks in OUT/generations/, '
        'rerunning the same command resumes). Writes OUT/winner.yaml (ros2 run '
        'fohssv_controller controller --ros-args --params-file OUT/winner.yaml), '
        'OUT/envelope.png/.svg, OUT/history.png/.svg and OUT/tune.json.')
    add_common_options(p)
    p.add_argument('--tune', action='append', metavar='NAME=LOW:HIGH[:log][,...]',
                   help='tuned parameter and its bounds (repeatable or comma-separated); '
                   ':log searches log10 of the value, e.g. depth_weight=1e2:1e6:log')
    p.add_argument('--envelope-speeds', metavar='VALUES', help='V of the envelope in m/s, '
                   'start:stop:step or a,b,c, e.g. 60:120:20')
    p.add_argument('--envelope-alphas', metavar='VALUES', help='alpha of the envelope, e.g. '
                   '0.7:1:0.1')
    p.add_argument('--objective', default='peak-fp', metavar='NAME',
                   help='last level of the score: peak-fp (default), settle or effort')
    p.add_argument('--budget', type=int, default=60,
                   help='candidate evaluations at most (default 60)')
    p.add_argument('--population', type=int, default=0, help='candidates per generation '
                   '(default: 5 per tuned parameter, at most budget/4, at least 5)')
    p.add_argument('--seed', type=bounded('--seed', low=0, high=2**32 - 1, integer=True),
                   default=1, help='seed of the search (default 1)')
    p.add_argument('--min-margin', type=float, default=0.02, help='Matignon margin '
                   'min(alpha_c - alpha) counted as enough (default 0.02)')
    p.add_argument('--model', help='model (default: the model parameter, fractional)')
    p.add_argument('--duration', type=bounded('--duration', low=0, low_open=True, unit='s'),
                   default=2.0, help='s per run (default 2)')
    p.add_argument('--transient', type=bounded('--transient', low=0, unit='s'), default=1.5,
                   help='s before the classification window (default 1.5)')
    p.add_argument('--peak-after-transient', action='store_true',
                   help='peak-fp: the worst peak |Fp| after --transient only (default: over '
                   'the whole run, the start-up transient included)')
    p.add_argument('--control-period', type=bounded('--control-period', low=0, unit='s'),
                   default=1e-4,
                   help='zero-order hold period in s (default 1e-4, the plant\'s)')
    p.add_argument('--settle-band', type=bounded('--settle-band', low=0, low_open=True,
                                                 high=1, meaning='relative band'),
                   default=0.02,
                   help='settled when |w - w*| <= band * max(|w*|, 0.1 m/s) (default 0.02)')
    dask_options(p, 128, 'one batched solver call')
    p.add_argument('--check-step', action='store_true',
                   help='re-run the winner at half the step; flag (and do not score) the '
                   'scenarios whose outcome changes')
    p.set_defaults(func=cmd_tune, out=None)


def parse_bounds(items: list[str]) -> tuple[Any, ...]:
    """``NAME=LOW:HIGH[:log]`` items (each possibly comma-separated) as Bounds."""
    from ..analysis.tune import Bound

    out = []
    for text in ','.join(items).split(','):
        text = text.strip()
        if '=' not in text:
            raise CliError(f'--tune {text!r} must look like NAME=LOW:HIGH or '
                           'NAME=LOW:HIGH:log')
        name, rng = (s.strip() for s in text.split('=', 1))
        parts = rng.split(':')
        log = len(parts) == 3 and parts[2].strip() == 'log'
        try:
            if len(parts) != 2 + log:
                raise ValueError
            low, high = float(parts[0]), float(parts[1])
        except ValueError:
            raise CliError(f'--tune {text!r} must look like NAME=LOW:HIGH or '
                           'NAME=LOW:HIGH:log') from None
        out.append(Bound(name, low, high, log))
    return tuple(out)


def _envelope(text: str | None, option: str) -> tuple[float, ...]:
    if text is None or not text.strip():
        return ()
    return tuple(round(float(v), 12) for v in parse_range(text, option))


def build_spec(args: argparse.Namespace):
    from ..analysis.tune import TuneError, TuneSpec

    if not args.tune:
        raise CliError('nothing to tune: give --tune NAME=LOW:HIGH[,NAME=LOW:HIGH...]')
    check_chunk_size(args.chunk_size)
    over = {'model': args.model} if args.model else {}
    base = model_params(args, **over)
    values = base.to_dict()
    values.pop('fractional_order', None)
    values.pop('speed', None)
    if args.control_period > args.duration:
        raise CliError(f'--control-period={args.control_period:g} s is longer than the run '
                       f'(--duration={args.duration:g} s)')
    spec = TuneSpec(
        controller=args.controller, bounds=parse_bounds(args.tune),
        envelope_speeds=_envelope(args.envelope_speeds, '--envelope-speeds'),
        envelope_alphas=_envelope(args.envelope_alphas, '--envelope-alphas'),
        gains=assignments(args.gain or [], '--gain'), base=values, objective=args.objective,
        budget=args.budget, population=args.population, seed=args.seed,
        min_margin=args.min_margin, duration=args.duration, transient=args.transient,
        peak_after_transient=args.peak_after_transient,
        control_period=args.control_period or None, settle_band=args.settle_band,
        chunk_size=args.chunk_size, check_step=args.check_step)
    try:
        spec.validate()
    except TuneError as e:
        raise CliError(str(e)) from None
    # the sizes and the Dask options, as sweep and gainmap refuse them: before any folder
    # or worker (a --duration of 1e9 s, --workers 1000, a scheduler where nothing listens)
    steps = check_run_steps('--duration', args.duration, base.step)
    check_grid('one generation of the search (population x scenarios)',
               spec.population_size * len(spec.scenarios()), steps)
    check_dask_options(args)
    return spec


def winner_yaml(record: dict[str, Any], args: argparse.Namespace) -> str:
    """The winner's parameters as a ``--params-file`` of the generic controller node."""
    from ..analysis.tune import TuneSpec, describe_score
    from ..control import load
    from ..docs import parameters_yaml
    from ..params import field_specs

    spec = TuneSpec.from_dict(record['spec'])
    cls = load(spec.controller)
    base = model_params(args)
    gains = spec.gains_for(record['winner']['values'], base)
    params = cls.Parameters(**gains)
    follow = getattr(cls, 'scheduling', {})
    rows = [dataclasses.replace(s, default=getattr(params, s.name))
            for s in field_specs(cls.Parameters)]
    vals = ', '.join(f'{k}={v:.6g}' for k, v in record['winner']['values'].items())
    env = (f'V {list(spec.envelope_speeds)} m/s x alpha {list(spec.envelope_alphas)}')
    header = (f'Winner of fohssv tune --controller {spec.controller} over {env}: {vals}.\n'
              f"Score: {describe_score(record['winner']['score'], spec)}.\n"
              f'Run it: ros2 run fohssv_controller controller --ros-args --params-file '
              f'winner.yaml')
    for c, m in follow.items():
        header += (f'\n{c} follows the plant\'s {m} (here {getattr(base, m):g}); for another '
                   f'plant {m} add -p {c}:=VALUE after the --params-file.')
    text = parameters_yaml(header, rows)
    return text.replace('  ros__parameters:\n',
                        f"  ros__parameters:\n    controller: '{spec.controller}'\n", 1)


class _Clock:
    """Elapsed time and the ETA of the remaining generations, from the generations this run
    computed (those read back from a resumed folder take no time and are not counted)."""

    def __init__(self, generations: int) -> None:
        import time

        self.time = time.monotonic
        self.start = self.last = self.time()
        self.generations = generations
        self.done = self.computed = 0
        self.spent = 0.0

    def tick(self, computed: bool) -> tuple[float, float | None]:
        """(elapsed s, ETA s or None before any generation was computed)."""
        now = self.time()
        if computed:
            self.computed += 1
            self.spent += now - self.last
        self.last = now
        self.done += 1
        left = self.generations - self.done
        eta = None if not self.computed else self.spent / self.computed * left
        return now - self.start, eta


def generation_line(g: dict[str, Any], generations: int, n: int, clock: _Clock) -> str:
    """One line per generation: its number, the best so far (score value and its levels),
    elapsed time and the ETA of the search (the step check not counted)."""
    elapsed, eta = clock.tick(g['computed_chunks'] > 0)
    when = f'{elapsed:.0f} s elapsed, ' + ('ETA unknown' if eta is None else
                                           f'~{eta:.0f} s left')
    head = f"generation {g['generation'] + 1}/{generations}"
    b = g['best_so_far']
    if b is None:
        return f'{head}: no candidate built the controller ({when})'
    margin = b.get('margin')
    m = '' if margin is None or (isinstance(margin, float) and math.isnan(margin)) \
        else f', margin {margin:.4g}'
    metric = b['metric'] if isinstance(b['metric'], float) else float(b['metric'])
    return (f"{head}: best so far score {b['value']:.6g} (worst {b['outcome']}, "
            f"{b['not_steady']}/{n} not steady{m}, metric {metric:.4g}); "
            f"{g['computed_chunks']} chunks computed, {g['reused_chunks']} reused; {when}")


def cmd_tune(args: argparse.Namespace) -> int:
    from ..analysis.tune import TuneError, plot_envelope, plot_history, run_tune, summary_lines

    spec = build_spec(args)
    # reports/tune/<controller>-<hash of the search> unless --out: a rerun of the same search
    # (any budget) resumes there; a different search gets its own folder (tune.json refuses
    # a folder that holds another one)
    out: Path = output_dir(args.out if out_given(args) else job_folder(
        'tune', job_name(spec.controller, spec.identity())))
    n = len(spec.scenarios())
    print(f'tune {spec.controller}: {len(spec.bounds)} parameter(s) '
          f"({', '.join(b.text() for b in spec.bounds)}), {n} scenario(s), population "
          f'{spec.population_size} x {spec.generations} generation(s) (budget {spec.budget}), '
          f'objective {spec.objective}, {spec.duration:g} s runs -> {out}', flush=True)
    progress = ProgressPrinter('points')
    check = ProgressPrinter('step check: points at half step')
    clock = _Clock(spec.generations)

    def generation(g: dict[str, Any]) -> None:
        progress.end()
        print(generation_line(g, spec.generations, n, clock), flush=True)

    try:
        result = run_tune(spec, out, scheduler=args.scheduler, workers=args.workers,
                          progress=progress, on_generation=generation, check_progress=check)
    except TuneError as e:
        raise CliError(str(e)) from None
    progress.end()
    check.end()
    for line in summary_lines(result):
        print(line)
    (out / 'winner.yaml').write_text(winner_yaml(result.record, args))
    written = plot_envelope(result.record, out / 'envelope') + plot_history(
        result.record, out / 'history')
    print(f"winner: {out / 'winner.yaml'}; figures: "
          + ', '.join(str(p) for p in written if p.suffix == '.png')
          + f"; record: {out / 'tune.json'}")
    return 0
