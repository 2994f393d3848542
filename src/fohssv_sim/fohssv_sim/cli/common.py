"""What the subcommands share: errors and exit codes, options, parsing, output folders.

Validation helpers (every subcommand uses them; each refusal is one line naming the option,
the value given, the allowed range and the unit, exit 2):

* :class:`OneLineParser`: argparse whose usage errors are one line.
* :func:`number` / :func:`bounded` (an argparse ``type=``): a finite number within a range;
  :func:`parameter_type`: a value checked against the model parameter table's row.
* :func:`parse_range`: ``a:b:step`` or ``a,b,c`` with bounds and a value-count limit checked
  before anything is allocated.
* :func:`check_size`, :func:`check_run_steps`, :func:`check_grid`, :func:`check_chunk_memory`,
  :func:`check_workers`, :func:`check_chunk_size`, :func:`check_scheduler`: the limits
  (:data:`LIMITS`) on sizes, simulated time, processes and the scheduler address.
* :func:`refuse_both`: a value given by ``--set`` and by its own option is refused.
* :func:`computing`: arithmetic failures on the user's values become one-line errors.
* :func:`resolve_output` (``--out`` or ``reports/<command>/<job>``; :func:`out_given`,
  :func:`job_name`, :func:`job_folder`), :func:`claim_output` (``job.json``),
  :func:`output_file`, :func:`safe_name`: output folders named after the command and its job,
  never writing outside the folder or over a different job's output.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import re
import socket
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..control import Controller, UnknownController, make
from ..params import PARAMETERS, ModelParameters, ParameterError

__all__ = ['EXIT_OK', 'EXIT_BAD_BAG', 'EXIT_USAGE', 'EXIT_INTERRUPTED', 'EXIT_INTERNAL',
           'EXIT_WORKERS_LOST', 'CliError',
           'BagInputError', 'folder_arg', 'output_dir', 'load_controller', 'assignments',
           'model_params',
           'parse_range', 'figure_paths', 'add_common_options', 'OneLineParser', 'LIMITS',
           'number', 'bounded', 'parameter_type', 'check_size', 'check_run_steps',
           'check_grid', 'check_chunk_memory', 'check_workers', 'check_chunk_size',
           'check_scheduler', 'computing', 'safe_name', 'job_name', 'job_folder',
           'claim_output', 'output_file', 'REPORTS', 'JOB_FILE', 'out_given',
           'resolve_output', 'refuse_both']


#: Exit codes of every subcommand: 0 done; 1 a bag that is missing, unreadable or not sound
#: (``plot``, ``check``, ``repair``, ``info`` alike); 2 any other bad input (options, values,
#: an ``--out`` that is not a folder); 3 the Dask workers of a chunked job lost; 130
#: interrupted.
EXIT_OK, EXIT_BAD_BAG, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
#: An internal error (a defect, not bad input): one line, ``FOHSSV_TRACEBACK=1`` re-raises.
EXIT_INTERNAL = 70
#: A chunked Dask job whose workers are all gone (or a chunk that kills its worker each time):
#: one line with the chunks kept; rerunning the same command resumes
#: (:class:`fohssv_sim.analysis.sweep.WorkersLost`).
EXIT_WORKERS_LOST = 3


class CliError(ValueError):
    """A user error: printed as one line, exit status ``exit_code`` (2)."""

    exit_code = EXIT_USAGE


class BagInputError(CliError):
    """A bag given on the command line is missing, unreadable or not a bag: exit status 1,
    as ``fohssv check`` gives for it."""

    exit_code = EXIT_BAD_BAG


def folder_arg(text: str) -> Path:
    """The ``--out`` folder as given on the command line (argparse ``type``): an empty or blank
    text is refused (``Path('')`` is the current folder, which nobody means by it).

    Raises:
        argparse.ArgumentTypeError: an empty text (argparse prints it as one line, exit 2).
    """
    if not text.strip():
        raise argparse.ArgumentTypeError(
            f'{text!r} is no folder: give a folder name (use . for the current folder)')
    return Path(text)


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
    """``name=value`` items (numbers as float, other values as text).

    Raises:
        CliError: an item without ``=`` or a name, or a name given twice (an explicit value
            is never silently replaced by a later one).
    """
    out: dict[str, Any] = {}
    for item in items:
        if '=' not in item:
            raise CliError(f'{what} {item!r} must look like name=value')
        k, v = item.split('=', 1)
        k = k.strip()
        if not k:
            raise CliError(f'{what} {item!r} has no name; it must look like name=value')
        if k in out:
            raise CliError(f'{what} {k} is given twice ({k}={out[k]!r} and {item!r}); give '
                           'it once')
        try:
            out[k] = float(v)
        except ValueError:
            out[k] = v.strip()
    return out


def model_params(args: argparse.Namespace, **overrides: Any) -> ModelParameters:
    """ModelParameters from ``--preset`` and ``--set`` (then ``overrides``).

    Raises:
        CliError: a bad name or value (the table's words), or values at which the model's
            coefficients overflow (e.g. ``speed=1e308``: the table has no upper bound there,
            floating point has).
    """
    values = assignments(args.set or [], '--set')
    values.update(overrides)
    try:
        params = ModelParameters.preset(args.preset, **values)
    except ParameterError as e:
        raise CliError(str(e)) from None
    _check_coefficients(params, values)
    return params


def _check_coefficients(params: ModelParameters, given: dict[str, Any]) -> None:
    from ..coefficients import coefficients

    shown = ', '.join(f'{k}={v!r}' for k, v in given.items()) or 'the defaults'
    try:
        coefficients(params)
    except ParameterError as e:          # coefficients() names the values that overflow
        raise CliError(f'the model cannot be evaluated at {shown}: {e}') from None


def refuse_both(args: argparse.Namespace, parameter: str, option: str, given: bool,
                why: str = '') -> None:
    """Refuse ``--set <parameter>=...`` together with ``option`` (``given``: the option was
    given, or the command sweeps that parameter anyway): one of the two explicit values
    would be silently dropped.

    Raises:
        CliError: both given.
    """
    values = assignments(args.set or [], '--set')
    if given and parameter in values:
        raise CliError(f'--set {parameter}={values[parameter]!r} and {option} both set '
                       f"{parameter}{why}; give it once")


# -- numbers and ranges -----------------------------------------------------------------
#: The limits of the command line: a bigger job is refused with its size and the limit.
#: ``range_values``: values of one range option (``a:b:step``); ``points``: points of a
#: sweep or gain map; ``run_steps``: integration steps of one simulated run (duration /
#: step); ``total_steps``: point-steps of a whole job (points x steps; about two core-days
#: of the batched solver); ``chunk_bytes``: the samples one Dask task keeps in memory;
#: ``chunk_size``: points per Dask task; ``workers_per_core``: local Dask workers per core.
LIMITS: dict[str, int] = {
    'range_values': 100_000,
    'points': 1_000_000,
    'run_steps': 1_000_000_000,
    'total_steps': 1_000_000_000_000,
    'chunk_bytes': 2 * 2**30,
    'chunk_size': 100_000,
    'workers_per_core': 4,
}


def _range_text(low: float | None, high: float | None, low_open: bool, high_open: bool
                ) -> str:
    lo = '-inf' if low is None else f'{low:g}'
    hi = 'inf' if high is None else f'{high:g}'
    lb = '(' if low is None or low_open else '['
    hb = ')' if high is None or high_open else ']'
    return f'{lb}{lo}, {hi}{hb}'


def number(option: str, value: Any, *, unit: str = '', low: float | None = None,
           high: float | None = None, low_open: bool = False, high_open: bool = False,
           integer: bool = False, meaning: str = '') -> Any:
    """``value`` as a finite float (an int if ``integer``) within [low, high] (open ends as
    told; ``None`` = unbounded).

    Raises:
        CliError: ``<option>=<value> is outside the allowed range <range> <unit>
            (<meaning>)``, or ``is not a number`` / ``is not a whole number``.
    """
    tail = (f' {unit}' if unit and unit != '-' else '') + (f' ({meaning})' if meaning else '')
    allowed = _range_text(low, high, low_open, high_open)
    shown = value if isinstance(value, str) else repr(value)
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise CliError(f'{option}={shown} is not a number; allowed: {allowed}{tail}') from None
    if integer:
        if not (math.isfinite(x) and x == int(x)):
            raise CliError(f'{option}={shown} is not a whole number; allowed: whole numbers '
                           f'in {allowed}{tail}')
        x = int(x)
    ok = math.isfinite(x)
    if ok and low is not None:
        ok = x > low if low_open else x >= low
    if ok and high is not None:
        ok = x < high if high_open else x <= high
    if not ok:
        raise CliError(f'{option}={shown} is outside the allowed range {allowed}{tail}')
    return x


def bounded(option: str, **limits: Any) -> Callable[[str], Any]:
    """An argparse ``type=`` running :func:`number` (same keywords), e.g.
    ``type=bounded('--window', unit='s', low=0, low_open=True)``; a refusal is argparse's
    one line (:class:`OneLineParser`)."""

    def convert(text: str) -> Any:
        try:
            return number(option, text, **limits)
        except CliError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    convert.__name__ = option.lstrip('-').replace('-', '_')
    return convert


def parameter_type(name: str, option: str | None = None) -> Callable[[str], float]:
    """An argparse ``type=`` checking a value against the model parameter table's row
    ``name`` (its range and unit), e.g. ``type=parameter_type('speed', '--speed')``."""
    spec = _PARAMETER_SPECS[name]

    def convert(text: str) -> float:
        try:
            return float(spec.validate(text))
        except (ParameterError, ValueError) as e:
            raise argparse.ArgumentTypeError(f'{option or name}: {e}') from None

    convert.__name__ = name
    return convert


_PARAMETER_SPECS = {s.name: s for s in PARAMETERS}


def parse_range(text: str, name: str, *, low: float | None = None,
                high: float | None = None, low_open: bool = False, high_open: bool = False,
                unit: str = '', parameter: str | None = None,
                max_values: int | None = None) -> np.ndarray:
    """``a:b:step`` (inclusive of b within rounding), or comma-separated values.

    Every value must be finite and within [low, high] and, with ``parameter``, within that
    model parameter's range; the values are counted before anything is allocated and there
    may be at most ``max_values`` (default ``LIMITS['range_values']``).

    Raises:
        CliError: malformed text, a value out of range (name, value, range, unit), or too many
            values (their number and the limit).
    """
    limit = LIMITS['range_values'] if max_values is None else max_values
    form = (f'{name}={text!r} must be start:stop:step (stop >= start, step > 0) or '
            'comma-separated numbers')
    try:
        if ':' in text:
            a, b, s = (float(x) for x in text.split(':'))
            if not all(map(math.isfinite, (a, b, s))) or s <= 0 or b < a:
                raise ValueError
            count = math.floor((b - a) / s + 1e-9) + 1
            check_size(f'{name}={text!r}', count, limit, 'values',
                       'give a coarser step or a shorter range')
            values = a + s * np.arange(int(count))
        else:
            items = text.split(',')
            check_size(f'{name}={text!r}', len(items), limit, 'values')
            values = np.array([float(x) for x in items])
    except (ValueError, OverflowError) as e:
        if isinstance(e, CliError):
            raise
        raise CliError(form) from None
    for v in values:
        if parameter is not None:
            try:
                _PARAMETER_SPECS[parameter].validate(float(v))
            except ParameterError as e:
                raise CliError(f'{name}: {_rounded_refusal(parameter, float(v)) or e}'
                               ) from None
        number(f'{name} value', float(f'{v:.12g}') if math.isfinite(v) else float(v),
               unit=unit, low=low, high=high, low_open=low_open, high_open=high_open)
    return values


def _rounded_refusal(parameter: str, v: float) -> str:
    """The table's refusal of ``v`` shown to 12 digits (a grid's 1.2000000000000002 as
    1.2), or '' if the rounded value would pass."""
    try:
        _PARAMETER_SPECS[parameter].validate(float(f'{v:.12g}'))
    except ParameterError as e:
        return str(e)
    return ''


# -- sizes, processes, schedulers ---------------------------------------------------------
def check_size(what: str, size: float, limit: float, unit: str, hint: str = '') -> None:
    """Refuse ``size`` above ``limit``: ``<what> has <size> <unit>; the limit is <limit>``.

    Raises:
        CliError: too big.
    """
    if size > limit:
        raise CliError(f'{what} has {size:.6g} {unit}; the limit is {limit:.6g}'
                       + (f' ({hint})' if hint else ''))


def check_run_steps(what: str, duration: float, step: float) -> int:
    """The integration steps of one run of ``duration`` s at ``step`` s, refused above
    ``LIMITS['run_steps']`` (e.g. ``--transient 1e9``).

    Raises:
        CliError: too many steps (their number, the limit and the simulated time).
    """
    steps = duration / step
    check_size(f'{what} ({duration:g} s simulated at step {step:g} s)', steps,
               LIMITS['run_steps'], 'integration steps per run',
               'give a shorter time or a larger step')
    return int(math.ceil(steps - 1e-9))


def check_grid(what: str, points: int, steps_per_point: int) -> None:
    """A job of ``points`` runs of ``steps_per_point`` steps each: refused above
    ``LIMITS['points']`` points or ``LIMITS['total_steps']`` point-steps.

    Raises:
        CliError: too many points or too much work (the sizes and the limits).
    """
    check_size(what, points, LIMITS['points'], 'points', 'give coarser grids')
    check_size(f'{what} ({points} points x {steps_per_point} steps)',
               points * steps_per_point, LIMITS['total_steps'], 'point-steps',
               'give coarser grids or shorter runs')


def check_chunk_memory(option: str, chunk_size: int, samples_per_point: int,
                       bytes_per_sample: int = 40) -> None:
    """The samples one Dask task keeps (``chunk_size`` points x ``samples_per_point`` x
    ``bytes_per_sample``), refused above ``LIMITS['chunk_bytes']``.

    Raises:
        CliError: the bytes a task would hold and the limit.
    """
    size = chunk_size * samples_per_point * bytes_per_sample
    if size > LIMITS['chunk_bytes']:
        raise CliError(f'{option}={chunk_size} with {samples_per_point} samples per point '
                       f'needs {size / 2**30:.3g} GiB per task; the limit is '
                       f"{LIMITS['chunk_bytes'] / 2**30:g} GiB (give a smaller {option}, a "
                       'shorter window or a larger --sample-every)')


def check_chunk_size(value: int, option: str = '--chunk-size') -> int:
    """Points per Dask task: a whole number in [1, ``LIMITS['chunk_size']``].

    Raises:
        CliError: out of range.
    """
    return number(option, value, low=1, high=LIMITS['chunk_size'], integer=True,
                  unit='points', meaning='points per Dask task')


def check_workers(value: int, option: str = '--workers') -> int:
    """Local Dask worker processes: 0 (one per core) or 1 .. ``workers_per_core`` x cores.

    Raises:
        CliError: out of range (e.g. -1 or 1000).
    """
    cores = os.cpu_count() or 1
    limit = LIMITS['workers_per_core'] * cores
    return number(option, value, low=0, high=limit, integer=True, unit='processes',
                  meaning=f'0 = one per core; at most {LIMITS["workers_per_core"]} per core, '
                  f'{cores} cores here')


def check_scheduler(address: str | None, option: str = '--scheduler',
                    timeout: float = 3.0) -> str | None:
    """A Dask scheduler address (``tcp://HOST:PORT`` or ``HOST:PORT``) where something
    accepts a TCP connection within ``timeout`` s; ``None`` passes (a local cluster).

    Raises:
        CliError: malformed, or nothing listens there (one line, within ``timeout``).
    """
    if address is None:
        return None
    m = re.fullmatch(r'(?:(tcp|tls)://)?(\[[^\]]+\]|[^:/\s]+):(\d{1,5})/?', address.strip())
    if not m or not 0 < int(m.group(3)) < 65536:
        raise CliError(f'{option}={address!r} is not a scheduler address; give '
                       'tcp://HOST:PORT (port 1-65535), as `dask scheduler` prints it')
    host, port = m.group(2).strip('[]'), int(m.group(3))
    try:
        with socket.create_connection((host, port), timeout=timeout):
            pass
    except OSError as e:
        why = 'timed out' if isinstance(e, TimeoutError) else (e.strerror or str(e))
        raise CliError(f'{option}={address}: no Dask scheduler answers there ({why} after '
                       f'at most {timeout:g} s); start one with `dask scheduler` or omit '
                       f'{option} for a local cluster') from None
    return address.strip()


class computing:  # noqa: N801 - used as a context manager, reads as a phrase
    """``with computing('the equilibria', given):`` turns arithmetic failures of a
    computation on the user's values (overflow, a non-finite command, a singular matrix)
    into one-line :class:`CliError` s naming ``what`` and the values ``given``."""

    def __init__(self, what: str, given: str) -> None:
        self.what, self.given = what, given

    def __enter__(self) -> computing:
        return self

    def __exit__(self, kind: Any, exc: Any, tb: Any) -> bool:
        if exc is None or not isinstance(exc, (ArithmeticError, np.linalg.LinAlgError)):
            return False
        raise CliError(f'{self.what} failed at {self.given}: {type(exc).__name__}: '
                       f'{exc}') from None


# -- output folders -----------------------------------------------------------------------
#: The root of the default output folders: ``reports/<command>/<job>``.
REPORTS = Path('reports')
#: In every output folder: which job wrote which outputs (command -> the job's inputs).
JOB_FILE = 'job.json'
_DEFAULT_OUT = Path('reports')   # the --out default object: "not given"
_NAME = re.compile(r'[A-Za-z0-9][A-Za-z0-9._+=,@-]{0,119}')


def safe_name(text: str, option: str = '--name') -> str:
    """``text`` as one plain file-name part: letters, digits and ``._+=,@-``, not starting
    with a dot or dash, at most 120 characters; never ``..``, a slash or a drive.

    Raises:
        CliError: anything else (it could write outside the output folder).
    """
    if not _NAME.fullmatch(text or '') or '..' in text:
        raise CliError(f'{option}={text!r} must be a plain name (letters, digits and ._+=,@-, '
                       'up to 120, not starting with . or -, no / or ..): outputs are '
                       'written only inside the output folder')
    return text


def job_name(slug: str, identity: Any) -> str:
    """A folder name for a job: a readable ``slug`` (made safe) and 8 hex digits of a hash
    of ``identity`` (JSON of everything that defines the job), so that the same job always
    gets the same folder (rerunning resumes) and a different job a different one."""
    digest = hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()
                            ).hexdigest()[:8]
    clean = re.sub(r'[^A-Za-z0-9._+=,@-]+', '_', slug).strip('._-')[:100]
    return f'{clean}-{digest}' if clean else digest


def job_folder(command: str, name: str) -> Path:
    """``reports/<command>/<name>``: the default output folder of a command's job."""
    return REPORTS / command / safe_name(name, 'job name')


def out_given(args: argparse.Namespace) -> bool:
    """True when ``--out`` was given on the command line (not its default)."""
    return getattr(args, 'out', None) is not None and args.out is not _DEFAULT_OUT


def resolve_output(args: argparse.Namespace, command: str, slug: str, identity: Any, *,
                   key: str | None = None, files: Sequence[str] = ()) -> Path:
    """The output folder of a job: ``--out`` if given, else ``reports/<command>/<job>``
    (:func:`job_name` of ``slug`` and ``identity``); created, and claimed for the job with
    :func:`claim_output` (``key`` default ``command``; ``files`` the outputs it writes)."""
    folder = args.out if out_given(args) else job_folder(command, job_name(slug, identity))
    output_dir(folder)
    claim_output(folder, key or command, identity, files)
    return folder


def claim_output(folder: Path, key: str, identity: Any, files: Sequence[str] = ()) -> None:
    """Record in ``folder/job.json`` that ``key``'s outputs there belong to the job
    ``identity``; refuse a folder where ``key`` belongs to a different job, or where one of
    ``files`` exists with no record of its job (it is not silently overwritten).

    Raises:
        CliError: the folder holds a different job (says which file records it).
    """
    path = folder / JOB_FILE
    ident = json.loads(json.dumps(identity, sort_keys=True, default=str))
    data: dict[str, Any] = {}
    if path.exists():
        try:
            data = json.loads(path.read_text())
            if not isinstance(data, dict):
                raise ValueError
        except (OSError, ValueError):
            raise CliError(f'{path} is not a job record this version wrote; choose another '
                           '--out or delete that file') from None
    if key in data and data[key] != ident:
        diff = sorted(k for k in set(data[key]) | set(ident)
                      if data[key].get(k) != ident.get(k)) if isinstance(
            data[key], dict) and isinstance(ident, dict) else []
        what = f" (differs in {', '.join(diff[:4])})" if diff else ''
        raise CliError(f'{folder} holds a different {key} job{what} (see {path}); choose '
                       'another --out, or delete that folder')
    if key not in data:
        for name in files:
            if (folder / name).exists():
                raise CliError(f'{folder / name} exists and {path} does not say this job '
                               'wrote it; choose another --out, or delete it')
    data[key] = ident
    output_file(folder, JOB_FILE).write_text(json.dumps(data, indent=2, sort_keys=True) + '\n')


def output_file(folder: Path, name: str) -> Path:
    """``folder/name`` for writing: ``name`` one plain part (:func:`safe_name`), and the path
    not a symbolic link (writing through it could land outside the folder).

    Raises:
        CliError: an unsafe name or a link.
    """
    path = folder / safe_name(name, 'output file name')
    if path.is_symlink():
        raise CliError(f'{path} is a symbolic link; fohssv writes only regular files inside '
                       'the output folder (remove the link)')
    return path


def figure_paths(stem: Path) -> list[Path]:
    """``stem``.png and ``stem``.svg (stem names may contain dots, e.g. alpha0.85); each
    refused if it is a symbolic link (:func:`output_file`)."""
    return [output_file(stem.parent, f'{stem.name}.png'),
            output_file(stem.parent, f'{stem.name}.svg')]


class OneLineParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line on stderr (``<prog>: error: <message>; see
    <prog> --help``), exit 2, instead of the usage block."""

    def error(self, message: str) -> None:  # type: ignore[override]
        message = re.sub(r'^argument (\S+?)(?:/\S+)?: (\1)', r'\2', message)
        self.exit(2, f'{self.prog}: error: {message}; see {self.prog} --help\n')


def add_common_options(p: argparse.ArgumentParser, controller: bool = True) -> None:
    """--set, --preset, --controller, --gain and --out (default: ``reports/<command>/<job>``:
    resolve it with :func:`resolve_output`)."""
    p.add_argument('--set', action='append', metavar='NAME=VALUE',
                   help='model parameter (repeatable), e.g. --set speed=84.5')
    p.add_argument('--preset', default='resolved', help="'resolved' (default) or "
                   "'paper-literal' (L = 1.18 m, w0 = 2.8 m/s, tau = 0.02069 s)")
    if controller:
        p.add_argument('--controller', default='state_feedback',
                       help='controller plugin name (default: state_feedback, eq. 31)')
        p.add_argument('--gain', action='append', metavar='NAME=VALUE',
                       help='controller parameter (repeatable), e.g. --gain depth_gain=12')
    p.add_argument('--out', type=folder_arg, default=_DEFAULT_OUT,
                   help='output folder (default: reports/COMMAND/JOB, named after the job)')
