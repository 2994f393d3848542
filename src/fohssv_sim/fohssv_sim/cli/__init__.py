"""``fohssv``: the analysis command line (pure Python, no ROS needed).

    fohssv stability [--alpha A] [--speed V] [--speeds 75:90:0.5] [--out DIR]
    fohssv plot BAG... [--out DIR] [--namespace NS]
    fohssv sweep alpha|V|alpha-V [...]
    fohssv gainmap --x NAME=VALUES --y NAME=VALUES [...]
    fohssv report [--out DIR]
    fohssv continue --vary NAME=START:END [...]
    fohssv repair BAG

Model parameters are set with ``--set name=value`` (repeatable; names as in the README's
parameter table) and ``--preset paper-literal``; the controller with ``--controller NAME``
(a plugin of group ``fohssv.controllers``) and ``--gain name=value``. Errors print one line;
nothing prints a traceback for bad input. Exit status: 0 done, 1 a bag that is missing,
unreadable or not sound (every bag command alike), 2 any other bad input, 3 the Dask
workers of a chunked job (sweep, gainmap, tune, fit) all lost (finished chunks kept; rerun to
resume), 70 an internal
error (a defect: one line; ``FOHSSV_TRACEBACK=1`` shows the traceback), 130 interrupted.
Outputs go to ``reports/<command>/<job>`` unless ``--out`` names a folder.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence
from types import ModuleType

from .common import (
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_WORKERS_LOST,
    CliError,
    OneLineParser,
    load_controller,
    parse_range,
)

__all__ = ['main', 'build_parser', 'load_controller', 'parse_range', 'COMMANDS', 'command_help']

#: The subcommands in the order of ``fohssv --help``: name -> (its module in this package,
#: the one-line help). A module is imported only when its command is the one that runs (its
#: ``register(sub)`` adds its parsers, with these lines): ``fohssv --help`` lists them all
#: without importing matplotlib, Dask or scipy.optimize.
COMMANDS: dict[str, tuple[str, str]] = {
    'stability': ('stability', 'equilibria, eigenvalues, Matignon wedge (Fig. 5), alpha_c '
                  'over V'),
    'plot': ('plot', 'time responses and w-q phase portrait of recorded bags'),
    'repair': ('plot', 'rebuild the index, summary and metadata.yaml of a bag cut short '
               '(e.g. by SIGKILL)'),
    'check': ('plot', 'structural check of a bag (CRCs, indexes, metadata)'),
    'sweep': ('sweep', 'orbit diagrams over alpha, V or the alpha-V grid'),
    'gainmap': ('gainmap', 'map two gains of a controller: class, settling, peak planing '
                'force, effort, Matignon boundary; optionally the worst case over a V-alpha '
                'envelope'),
    'report': ('report', "reproduce the paper's claims (docs/model.md §8): figures and a "
               'Markdown claims table'),
    'tune': ('tune', 'search controller parameters for the best worst case over a V-alpha '
             'envelope (differential evolution on Dask); writes the winner as a --params-file'),
    'fit': ('fit', 'identify the fractional order (and other model parameters) from a '
            'recorded run, or the alpha that best reproduces the delayed model'),
    'continue': ('continue_', 'follow a branch of periodic orbits over one parameter by '
                 'continuation: stability and bifurcations'),
}


def command_help(name: str) -> str:
    """The one-line help of subcommand ``name`` (its module's parser uses it too)."""
    return COMMANDS[name][1]


def command_module(name: str) -> ModuleType:
    """The module of subcommand ``name`` (imported now if it was not)."""
    return importlib.import_module(f'{__name__}.{COMMANDS[name][0]}')


def _chosen(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` names: its first word that is not an option (``fohssv`` has
    no option taking a value), or None."""
    word = next((a for a in argv if not a.startswith('-')), None)
    return word if word in COMMANDS else None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``fohssv`` parser. With ``argv``: the full parser only of the subcommand it names
    (its module imported), every other one listed by name and help only; without: every
    subcommand's full parser (all modules imported)."""
    chosen = None if argv is None else _chosen(argv)
    ap = OneLineParser(prog='fohssv', description='FO-HSSV analysis: stability, '
                                 'orbit diagrams, plots of recorded runs, the paper report.')
    sub = ap.add_subparsers(dest='command', required=True)
    registered: set[str] = set()
    for name, (module, text) in COMMANDS.items():
        if name in registered:
            continue
        if argv is None or COMMANDS.get(chosen, ('',))[0] == module:
            command_module(name).register(sub)       # every parser of the module, in order
            registered |= {n for n, (m, _) in COMMANDS.items() if m == module}
        else:
            sub.add_parser(name, help=text, add_help=False)
            registered.add(name)
    return ap


def _workers_lost(e: BaseException) -> bool:
    """``e`` is :class:`..analysis.sweep.WorkersLost` (only a command that imported that
    module can raise it, so it is not imported here)."""
    sweep = sys.modules.get('fohssv_sim.analysis.sweep')
    return sweep is not None and isinstance(e, sweep.WorkersLost)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser(argv).parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CliError as e:
        print(f'fohssv {args.command}: error: {e}', file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print(f'fohssv {args.command}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    except MemoryError:
        print(f'fohssv {args.command}: error: out of memory (give smaller grids or shorter '
              'runs)', file=sys.stderr)
        return EXIT_INTERNAL
    except Exception as e:  # noqa: BLE001 - a defect still ends in one line
        if _workers_lost(e):
            print(f'fohssv {args.command}: error: {e}', file=sys.stderr)
            return EXIT_WORKERS_LOST
        if os.environ.get('FOHSSV_TRACEBACK'):
            raise
        text = ' '.join(str(e).split())[:300]
        print(f'fohssv {args.command}: internal error: {type(e).__name__}: {text} (a defect; '
              'FOHSSV_TRACEBACK=1 shows the traceback)', file=sys.stderr)
        return EXIT_INTERNAL
