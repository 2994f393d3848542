"""Start-up of every fohssv node: bad input gives one line and exit code 2, never a traceback.

Shared by the plant, the controller node, the recorder and the player (one implementation):

* :func:`init`: ``rclpy.init``; a missing or malformed ``--params-file`` or bad ``--ros-args``
  (rcl's ``RCLError``, a multi-line text with C source locations) becomes
  :class:`BadParameters` with one line. Discovery stays on this machine unless asked
  otherwise: when neither ``ROS_AUTOMATIC_DISCOVERY_RANGE`` nor the older
  ``ROS_LOCALHOST_ONLY`` is set, :func:`init` sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
  (ROS's own default is ``SUBNET``: every host on the network) and logs one line saying so;
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`` opens discovery on purpose.
  Transports stay on this machine too (:func:`default_transport`): unless the user set
  ``FASTDDS_DEFAULT_PROFILES_FILE`` (or the older ``FASTRTPS_DEFAULT_PROFILES_FILE``) or
  ``FOHSSV_DDS_NETWORK=open``, the package's Fast DDS profile ``config/fastdds_localhost.xml``
  is applied: shared memory and UDPv4 on 127.0.0.1 only, no socket on 0.0.0.0 or an external
  address. (rmw_fastrtps in LOCALHOST mode adds a UDP transport on every interface of its
  own, so with the profile a LOCALHOST range is handed to rcl as SUBNET: discovery then runs
  over the loopback-only transports, which no other host can reach.)
* params files (``--params-file``), read before rcl parses them: a file larger than
  :data:`MAX_PARAMS_BYTES` or with more than :data:`MAX_PARAMS_KEYS` keys is refused at once
  (rcl's parse and the unknown-name check of 200 000 keys took 6 minutes), and so is a key
  given twice in one mapping (YAML keeps the last silently). After the node is built,
  :func:`refuse_unknown` also refuses a file with no section for this node (a misspelt node
  name: the node would run on its defaults without a word); a section is the node's name
  (``plant``, ``/ns/plant``) or an rcl wildcard (``/**``, ``/*/plant``).
* :func:`precheck`: checks the overrides of a node's table rows (``--ros-args -p`` and params
  files) against the table *before* rclpy declares them, so a wrong type or a value out of
  range is reported by the table's own text (name, value, allowed range, unit, meaning)
  instead of rclpy's exception; its type check, :func:`typed`, also judges every change of a
  row at run time (:mod:`.ros_params` declares the rows dynamically typed for it).
* :func:`declare_rows`: declares plain rows ``(name, default, descriptor)`` (the controller
  node's plugin name; every other parameter is a table row, :mod:`.ros_params`)
  and turns rclpy's type errors into one line with the descriptor's allowed values.
* :func:`refuse_unknown`: an override no parameter of the node declares (``-p sped:=80.0``, a
  misspelt key in a params file, including keys under ``/**``) is refused with the close
  matches (``difflib``). rclpy itself ignores such overrides (``allow_undeclared_parameters``
  only governs ``set_parameters``), so the node checks ``Node._parameter_overrides`` (rclpy
  9.1.2 has no public accessor for the overrides) against what it declared, after its last
  declaration. Parameters rclpy declares itself (``use_sim_time``,
  ``start_type_description_service``) are declared, hence allowed.
* :func:`explain` and :func:`report`: the one line for any of these errors, and the exit code.
* :func:`destroy_on_error`: a node whose construction fails is destroyed at once when it was
  built in a process that goes on (a half-built node left for interpreter exit crashed or hung
  the process after the error line); in a node's own process (:func:`.nodekit.run_node`,
  which calls :func:`end_process_on_build_error`) it is left alone and the process ends with
  :func:`exit_now` after its line: tearing it down crashed the process too, now and then.

Every error here is a ``ValueError`` (:class:`BadParameters`, or the table's
:class:`~fohssv_sim.params.ParameterError`), which every node's ``main`` maps to exit code 2.
"""

from __future__ import annotations

import difflib
import functools
import math
import os
import re
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, NoReturn

import rclpy
import rclpy.logging
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from ..params import ParameterSpec

__all__ = ['EXIT_BAD_PARAMETERS', 'DEFAULT_DISCOVERY_RANGE', 'default_discovery',
           'default_transport', 'localhost_profile', 'NETWORK_VAR',
           'MAX_PARAMS_BYTES', 'MAX_PARAMS_KEYS', 'read_params_file', 'params_file_args',
           'BadParameters', 'init', 'precheck', 'typed', 'declare_rows',
           'refuse_unknown', 'explain', 'one_line', 'report', 'destroy_on_error',
           'end_process_on_build_error', 'exit_now']

#: Exit code of every node for invalid arguments or parameters at start.
EXIT_BAD_PARAMETERS = 2
#: Discovery range of the nodes when the environment does not choose one.
DEFAULT_DISCOVERY_RANGE = 'LOCALHOST'
_DISCOVERY_VARS = ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_LOCALHOST_ONLY')
_PROFILE_VARS = ('FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE')
#: The package's Fast DDS profile (installed with it): loopback and shared memory only.
PROFILE_NAME = 'fastdds_localhost.xml'
#: ``FOHSSV_DDS_NETWORK=open``: leave Fast DDS's transports at their defaults (every
#: interface), e.g. to reach other hosts together with ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET.
NETWORK_VAR = 'FOHSSV_DDS_NETWORK'
#: The largest params file a node reads (bytes); the plant's full file is about 6 KiB.
MAX_PARAMS_BYTES = 1 << 20
#: The most keys a params file may hold (all mappings together); the plant has about 60.
MAX_PARAMS_KEYS = 10_000
#: Params files of this process's arguments -> their node sections (set by :func:`init`).
_PARAMS_SECTIONS: dict[str, list[str]] = {}


def default_discovery(environ: dict[str, str] | None = None) -> bool:
    """Set ``ROS_AUTOMATIC_DISCOVERY_RANGE`` to :data:`DEFAULT_DISCOVERY_RANGE` in
    ``environ`` (``os.environ``, read by rcl at init) when the environment leaves discovery
    unset; True when it did."""
    env = os.environ if environ is None else environ
    if any(env.get(name, '').strip() for name in _DISCOVERY_VARS):
        return False
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = DEFAULT_DISCOVERY_RANGE
    return True


def localhost_profile() -> str | None:
    """The path of the package's Fast DDS profile (installed share, else the source tree)."""
    from pathlib import Path

    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory('fohssv_sim')) / 'config')
    except Exception:  # noqa: BLE001, S110 - not installed with colcon: the source tree
        pass
    candidates.append(Path(__file__).resolve().parents[2] / 'config')
    for folder in candidates:
        if (folder / PROFILE_NAME).is_file():
            return str(folder / PROFILE_NAME)
    return None


def _same_file(a: str, b: str) -> bool:
    """The same profile: one path, or the same content (env.sh names the source tree's copy,
    a node finds the installed one)."""
    try:
        return os.path.realpath(a) == os.path.realpath(b) or (
            open(a, 'rb').read() == open(b, 'rb').read())  # noqa: SIM115
    except OSError:
        return False


def default_transport(environ: dict[str, str] | None = None) -> str | None:
    """Apply the package's loopback-only Fast DDS profile in ``environ`` (``os.environ``,
    read by Fast DDS when rclpy starts) unless the user chose a profile or
    ``FOHSSV_DDS_NETWORK=open``; the profile path when it is in force (set here, or set to it
    already by env.sh), else None. With it in force a LOCALHOST discovery range becomes SUBNET
    for rcl (see the module docstring)."""
    env = os.environ if environ is None else environ
    if env.get(NETWORK_VAR, '').strip().lower() == 'open':
        return None
    ours = localhost_profile()
    if ours is None:
        return None
    given = [env.get(v, '').strip() for v in _PROFILE_VARS]
    given = [g for g in given if g]
    if given and not all(_same_file(g, ours) for g in given):
        return None                       # the user's own profile
    env['FASTDDS_DEFAULT_PROFILES_FILE'] = ours
    if env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip().upper() == 'LOCALHOST':
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'
    return ours


class BadParameters(ValueError):
    """Invalid arguments or parameters at start; the message is the one line to print."""


#: Set by :func:`end_process_on_build_error`: a failed construction ends the process.
_ENDS_PROCESS = False


def end_process_on_build_error() -> None:
    """Declare that in this process a node whose construction fails is never used again: the
    caller reports the error and ends the process with :func:`exit_now` (every node's
    :func:`.nodekit.run_node`), so :func:`destroy_on_error` leaves the half-built node alone."""
    global _ENDS_PROCESS
    _ENDS_PROCESS = True


def exit_now(code: int) -> NoReturn:
    """End the process at once with ``code`` (Python's buffers and the C library's streams,
    where rclpy's console logging may buffer, flushed first; no interpreter finalization, no
    teardown of a half-built node or of the DDS participant)."""
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):   # pragma: no cover - no C library to ask
        pass
    os._exit(code)


def destroy_on_error(init: Callable[..., None]) -> Callable[..., None]:
    """Decorate a node's ``__init__``: if it raises (a start-up error), the half-built node
    is destroyed before the error propagates. Otherwise the exception's traceback keeps it
    alive past ``rclpy.shutdown()``, and destroying it then, at interpreter exit, crashed the
    process (SIGSEGV after the error line) or hung it, in about one start in ten.

    In a node's own process (after :func:`end_process_on_build_error`) nothing is destroyed:
    the process ends with :func:`exit_now` after its error line. Destroying the half-built
    node there crashed as well, rarely (a plant refusing ``fractional_order:=1.5`` died with
    SIGSEGV inside rclpy's ``destroy_node``, ``destroy_when_not_in_use``, once in a
    ``make test`` that starts a few hundred refused nodes)."""

    @functools.wraps(init)
    def wrapper(self: Node, *args: Any, **kwargs: Any) -> None:
        try:
            init(self, *args, **kwargs)
        except BaseException:
            if not _ENDS_PROCESS:
                try:
                    self.destroy_node()
                except Exception:  # noqa: BLE001, S110 - Node.__init__ itself may have failed
                    pass
            raise

    return wrapper


def one_line(text: str) -> str:
    """``text`` on one line: rcl's C source locations (``, at ./src/x.c:12``) dropped, line
    breaks joined with ``; ``."""
    text = re.sub(r',? at [^\s,]+\.[ch](pp)?:\d+', '', str(text))
    parts = [p.strip() for p in text.splitlines() if p.strip()]
    return '; '.join(parts)


def params_file_args(args: Sequence[str]) -> list[str]:
    """The paths given with ``--params-file`` after ``--ros-args`` in ``args``."""
    out = []
    inside = False
    items = list(args)
    for i, a in enumerate(items):
        if a == '--ros-args':
            inside = True
        elif a == '--':
            inside = False
        elif inside and a == '--params-file' and i + 1 < len(items):
            out.append(items[i + 1])
    return out


def read_params_file(path: str) -> list[str] | None:
    """The node sections (names holding ``ros__parameters``) of the params file ``path``;
    None when it cannot be read or parsed (rcl then reports it, in its words).

    Raises:
        BadParameters: larger than :data:`MAX_PARAMS_BYTES`, more keys than
            :data:`MAX_PARAMS_KEYS`, or a key given twice in one mapping.
    """
    import yaml

    try:
        size = os.path.getsize(path)
        if size > MAX_PARAMS_BYTES:
            raise BadParameters(f'invalid arguments: params file {path} is {size} bytes, more '
                                f'than the {MAX_PARAMS_BYTES} a node reads')
        with open(path, encoding='utf-8') as f:
            text = f.read()
    except (OSError, UnicodeDecodeError):
        return None
    loader_cls = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
    keys = 0

    class _Loader(loader_cls):  # type: ignore[misc, valid-type]
        pass

    def mapping(loader: Any, node: Any) -> dict:
        nonlocal keys
        seen: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            key = loader.construct_object(key_node, deep=True)
            keys += 1
            if keys > MAX_PARAMS_KEYS:
                raise BadParameters(f'invalid arguments: params file {path} has more than '
                                    f'{MAX_PARAMS_KEYS} keys')
            if key in seen:
                raise BadParameters(
                    f'invalid arguments: params file {path} gives {key!r} twice (line '
                    f'{key_node.start_mark.line + 1}; YAML would keep the last silently)')
            seen[key] = loader.construct_object(value_node, deep=True)
        return seen

    _Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, mapping)
    try:
        data = yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError:
        return None
    if not isinstance(data, dict):
        return None
    return [str(k) for k, v in data.items() if isinstance(v, dict) and 'ros__parameters' in v]


def _section_matches(section: str, fqn: str) -> bool:
    """Whether the params-file section ``section`` applies to the node ``fqn`` (rcl's
    rules: a name without a leading slash is absolute, ``*`` is one name token, ``**`` any
    number of them)."""
    parts = [p for p in section.strip('/').split('/') if p] or ['']
    pattern = ''
    for p in parts:
        if p == '**':
            pattern += '(/[^/]+)*'
        elif p == '*':
            pattern += '/[^/]+'
        else:
            pattern += '/' + re.escape(p)
    return re.fullmatch(pattern, fqn) is not None


def init(args: Sequence[str] | None = None, **kwargs: Any) -> None:
    """``rclpy.init(args=args, **kwargs)``.

    Raises:
        BadParameters: rcl refused the arguments (a missing or malformed ``--params-file``,
            an unparsable ``-p``, an unknown ``--ros-args`` flag), or an argument outside
            ``--ros-args`` (``plant --speed 80``: rcl would ignore it and the node would run
            with the default).
    """

    # rcl logs its own 'Failed to parse global arguments' line before raising: silenced, the
    # one line below carries rcl's reason
    defaulted = default_discovery()
    profile = default_transport()
    _PARAMS_SECTIONS.clear()
    for path in params_file_args(sys.argv if args is None else args):
        sections = read_params_file(path)      # BadParameters: too large, duplicates
        if sections is not None:
            _PARAMS_SECTIONS[path] = sections
    rclpy.logging.set_logger_level('rcl', rclpy.logging.LoggingSeverity.FATAL)
    try:
        rclpy.init(args=args, **kwargs)
    except Exception as exc:  # noqa: BLE001 - rclpy raises _rclpy.RCLError, not exported
        raise BadParameters(f'invalid arguments: {one_line(str(exc))}') from None
    finally:
        rclpy.logging.set_logger_level('rcl', rclpy.logging.LoggingSeverity.UNSET)
    from rclpy.utilities import remove_ros_args

    stray = remove_ros_args(list(sys.argv if args is None else args))[1:]
    if stray:
        rclpy.try_shutdown()
        raise BadParameters(f"unexpected argument(s) {' '.join(stray)!r}: the nodes take only "
                            "ROS arguments, e.g. --ros-args -p speed:=80.0 (parameters) or "
                            '--params-file FILE after --ros-args')
    if defaulted:
        rclpy.logging.get_logger('fohssv').info(
            f'discovery: this machine only (ROS_AUTOMATIC_DISCOVERY_RANGE='
            f'{DEFAULT_DISCOVERY_RANGE}, the fohssv default'
            + (f'; transports: loopback and shared memory, {PROFILE_NAME}' if profile else '')
            + '); set ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET and FOHSSV_DDS_NETWORK=open to '
            'reach nodes on other hosts')


def _overrides(node: Node) -> dict[str, Any]:
    overrides = getattr(node, '_parameter_overrides', None)
    return overrides if isinstance(overrides, dict) else {}


def _kind_name(value: Any) -> str:
    if isinstance(value, bool):
        return 'bool'
    if isinstance(value, int):
        return 'integer'
    if isinstance(value, float):
        return 'double'
    if isinstance(value, str):
        return 'string'
    return 'array' if isinstance(value, (list, tuple)) or hasattr(value, 'tolist') else type(
        value).__name__


def _not_a_number(value: object, got: str) -> str:
    """Why a value ROS did not give as a number is refused: a number beyond a double's range
    (``1e400``) reaches the node as a string, and is named as such."""
    try:
        beyond = isinstance(value, str) and math.isinf(float(value)) and 'inf' not in value.lower()
    except ValueError:
        beyond = False
    if beyond:
        return 'is beyond the range of a double (about 1.8e308), so ROS passed it as a string'
    return f'is {_a(got)}, not a number'


def _a(kind: str) -> str:
    return f"{'an' if kind[0] in 'aeiou' else 'a'} {kind}"


def precheck(node: Node, specs: Iterable[ParameterSpec], kinds: Mapping[str, int]) -> None:
    """Check the overrides of ``specs`` before they are declared with the ROS types ``kinds``
    (name -> ``ParameterType``). Whole doubles given for integer rows are converted.

    Raises:
        ParameterError: a value of the wrong type or outside the row's range (one line naming
            the parameter, the value, the allowed range, the unit and the meaning).
    """
    from rclpy.parameter import Parameter

    overrides = _overrides(node)
    for spec in specs:
        p = overrides.get(spec.name)
        if p is None:
            continue
        value = typed(spec, kinds.get(spec.name), p.value)
        if value is not p.value:
            overrides[spec.name] = Parameter(spec.name, value=value)
        spec.validate(value)   # ParameterError: out of range, not a choice, not 4 numbers


def typed(spec: ParameterSpec, kind: int | None, value: Any) -> Any:
    """``value`` for the row ``spec`` declared with the ROS type ``kind`` (``ParameterType``):
    as it is, or a whole double given for an integer row as an integer.

    Raises:
        ParameterError: a value of the wrong type, in one line naming the parameter, the
            value, what it is and what the row allows (not rclpy's "expected '3' got '4'").
    """
    got = _kind_name(value)
    if kind == ParameterType.PARAMETER_DOUBLE:
        if got not in ('double', 'integer'):
            raise spec.refuse(value, _not_a_number(value, got))
    elif kind == ParameterType.PARAMETER_INTEGER:
        if got == 'double' and math.isfinite(value) and value == int(value):
            return int(value)
        if got != 'integer':
            raise spec.refuse(value, 'is not a whole number' if got == 'double'
                              else _not_a_number(value, got))
    elif kind == ParameterType.PARAMETER_STRING:
        if got != 'string':
            raise spec.refuse(value, f'is {_a(got)}, not a name')
    elif kind == ParameterType.PARAMETER_NOT_SET:
        if got not in ('double', 'integer', 'string') and not (
                got == 'array' and getattr(spec, 'accepts_array', False)):
            raise spec.refuse(value, f'is {_a(got)}')
    elif kind == ParameterType.PARAMETER_BOOL:
        if got != 'bool':
            raise spec.refuse(value, f'is {_a(got)}, not true or false')
    elif kind in _ARRAYS:
        item, what = _ARRAYS[kind]
        if got != 'array' or not all(item(v) for v in value):
            raise spec.refuse(value, f'is {_a(got)}, not {what}')
    return value


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


#: Array parameter types: what each item must be, and the words for the whole.
_ARRAYS = {ParameterType.PARAMETER_DOUBLE_ARRAY: (_number, 'a list of numbers'),
           ParameterType.PARAMETER_STRING_ARRAY: (lambda v: isinstance(v, str),
                                                  'a list of names')}


def declare_rows(node: Node, rows: Sequence[tuple[str, Any, ParameterDescriptor]]) -> None:
    """Declare plain rows ``(name, default, descriptor)``; an integer given for a double row
    is converted.

    Raises:
        BadParameters: a value of the wrong type (names it, the expected type and the
            descriptor's allowed values and description).
    """
    from rclpy.parameter import Parameter

    overrides = _overrides(node)
    for name, default, _ in rows:
        p = overrides.get(name)
        if p is not None and isinstance(default, float) and isinstance(p.value, int) \
                and not isinstance(p.value, bool):
            overrides[name] = Parameter(name, value=float(p.value))
    try:
        node.declare_parameters('', list(rows))
    except ParameterException as exc:
        described = {name: d for name, _, d in rows}
        name = _failed_name(exc, described)
        if name is None:
            raise BadParameters(one_line(str(exc))) from None
        d = described[name]
        default = next(v for n, v, _ in rows if n == name)
        value = overrides[name].value if name in overrides else None
        allowed = f'; {d.additional_constraints}' if d.additional_constraints else ''
        raise BadParameters(f'{name}={value!r} is {_a(_kind_name(value))}, expected '
                            f'{_a(_kind_name(default))}{allowed} ({d.description})') from None


def _failed_name(exc: Exception, names: Iterable[str]) -> str | None:
    """The parameter an rclpy ParameterException is about (the longest name it mentions)."""
    text = str(exc)
    found = [n for n in names if re.search(rf"(?<![\w.]){re.escape(n)}(?![\w.])", text)]
    return max(found, key=len) if found else None


def refuse_unknown(node: Node) -> None:
    """Refuse overrides that name no declared parameter of ``node`` (call after the last
    declaration, before the node does anything).

    Raises:
        BadParameters: the unknown names, each with its close matches, and the valid names.
    """
    _refuse_foreign_params_files(node)
    unknown = sorted(n for n in _overrides(node) if not node.has_parameter(n))
    if not unknown:
        return
    declared = sorted(node.list_parameters([], 0).names)
    parts = []
    for name in unknown:
        close = difflib.get_close_matches(name, declared, n=3, cutoff=0.6)
        hint = f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ''
        parts.append(f'{name!r}{hint}')
    raise BadParameters(f"unknown parameter{'s' if len(unknown) > 1 else ''} "
                        f"{', '.join(parts)} for node {node.get_name()!r}; its parameters: "
                        f"{', '.join(declared)}")


def _refuse_foreign_params_files(node: Node) -> None:
    """A params file with no section for ``node`` is refused (it would set nothing)."""
    fqn = node.get_fully_qualified_name()
    for path, sections in _PARAMS_SECTIONS.items():
        if any(_section_matches(s, fqn) for s in sections):
            continue
        have = ', '.join(repr(s) for s in sections) or 'none'
        close = difflib.get_close_matches(node.get_name(), [s.strip('/').rsplit('/', 1)[-1]
                                                            for s in sections], n=1)
        hint = f' (did you mean {node.get_name()!r} for {close[0]!r}?)' if close else ''
        raise BadParameters(f'params file {path} sets nothing for node {fqn!r}: its sections '
                            f"are {have}{hint}; name the node's section "
                            f"{node.get_name()!r} or {fqn!r}, or use '/**' for every node")


def explain(exc: BaseException, specs: Iterable[ParameterSpec] = ()) -> str:
    """The one line for a start-up error: the table's text for a ValueError; for an rclpy
    ParameterException that got through, rclpy's text plus the row's allowed range, unit and
    meaning when a row of ``specs`` is named."""
    if isinstance(exc, ParameterException):
        by_name = {s.name: s for s in specs}
        name = _failed_name(exc, by_name)
        text = one_line(str(exc))
        return text if name is None else f'{text}; {by_name[name].allowed_text()}'
    return one_line(str(exc))


def report(name: str, exc: BaseException, specs: Iterable[ParameterSpec] = ()) -> NoReturn:
    """Print the one line for a start-up error (console format, to stderr: rclpy's logging
    may not be initialised when ``rclpy.init`` itself failed) and end the process at once with
    :data:`EXIT_BAD_PARAMETERS`. Nothing ran, so nothing needs tearing down, and tearing down
    a half-built node's DDS participant hung or crashed the process now and then when many
    started at once (seen in a clean-clone test run: a refused node still alive after 60 s)."""
    text = explain(exc, specs)
    if not text.startswith('invalid '):
        text = f'invalid parameters: {text}'
    print(f'[ERROR] [{time.time():.9f}] [{name}]: {text}', file=sys.stderr, flush=True)
    exit_now(EXIT_BAD_PARAMETERS)
