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
unreadable or not sound (every bag command alike), 2 any other bad input, 3 the Dask
workers of a chunked job (sweep, gainmap, tune, fit) all lost (finished chunks kept; rerun to
resume), 70 an internal
error (a defect: one line; ``FOHSSV_TRACEBACK=1`` shows the traceback), 130 interrupted.
Outputs go to ``reports/<command>/<job>`` unless ``--out`` names a folder.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from ..analysis.sweep import WorkersLost
from . import fit, gainmap, plot, report, stability, sweep, tune
from .common import (
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
    EXIT_WORKERS_LOST,
    CliError,
    OneLineParser,
    load_controller,
    parse_range,
)

__all__ = ['main', 'build_parser', 'load_controller', 'parse_range']

#: The subcommand modules, in the order of ``fohssv --help``; each has ``register(sub)``.
COMMANDS = (stability, plot, sweep, gainmap, report, tune, fit)


def build_parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog='fohssv', description='FO-HSSV analysis: stability, '
                                 'orbit diagrams, plots of recorded runs, the paper report.')
    sub = ap.add_subparsers(dest='command', required=True)
    for command in COMMANDS:
        command.register(sub)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CliError as e:
        print(f'fohssv {args.command}: error: {e}', file=sys.stderr)
        return e.exit_code
    except WorkersLost as e:
        print(f'fohssv {args.command}: error: {e}', file=sys.stderr)
        return EXIT_WORKERS_LOST
    except KeyboardInterrupt:
        print(f'fohssv {args.command}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    except MemoryError:
        print(f'fohssv {args.command}: error: out of memory (give smaller grids or shorter '
              'runs)', file=sys.stderr)
        return EXIT_INTERNAL
    except Exception as e:  # noqa: BLE001 - a defect still ends in one line
        if os.environ.get('FOHSSV_TRACEBACK'):
            raise
        text = ' '.join(str(e).split())[:300]
        print(f'fohssv {args.command}: internal error: {type(e).__name__}: {text} (a defect; '
              'FOHSSV_TRACEBACK=1 shows the traceback)', file=sys.stderr)
        return EXIT_INTERNAL
