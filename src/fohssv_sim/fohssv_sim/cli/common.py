"""What the subcommands share: errors and exit codes, options, parsing, output folders."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..control import Controller, UnknownController, make
from ..params import ModelParameters, ParameterError

__all__ = ['EXIT_OK', 'EXIT_BAD_BAG', 'EXIT_USAGE', 'EXIT_INTERRUPTED', 'CliError',
           'BagInputError', 'output_dir', 'load_controller', 'assignments', 'model_params',
           'parse_range', 'figure_paths', 'add_common_options']


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


def load_controller(name: str, gains: dict[str, Any] | None = None) -> Controller:
    """Instantiate the controller plugin ``name`` (entry point group ``fohssv.controllers``,
    :func:`fohssv_sim.control.make`).

    Raises:
        CliError: unknown or broken plugin (the message lists the valid names, or says none
            is installed), bad gains.
    """
    try:
        return make(name, gains)
    except (UnknownController, ParameterError, TypeError, ValueError) as e:
        raise CliError(str(e)) from None


def assignments(items: Sequence[str], what: str) -> dict[str, Any]:
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
    values = assignments(args.set or [], '--set')
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


def figure_paths(stem: Path) -> list[Path]:
    """``stem``.png and ``stem``.svg (stem names may contain dots, e.g. alpha0.85)."""
    return [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']


def add_common_options(p: argparse.ArgumentParser, controller: bool = True) -> None:
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
