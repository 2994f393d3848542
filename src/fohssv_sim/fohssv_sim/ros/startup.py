"""Start-up of every fohssv node: bad input gives one line and exit code 2, never a traceback.

Shared by the plant, the controller node, the recorder and the player (one implementation):

* :func:`init`: ``rclpy.init``; a missing or malformed ``--params-file`` or bad ``--ros-args``
  (rcl's ``RCLError``, a multi-line text with C source locations) becomes
  :class:`BadParameters` with one line. Discovery stays on this machine unless asked
  otherwise: when neither ``ROS_AUTOMATIC_DISCOVERY_RANGE`` nor the older
  ``ROS_LOCALHOST_ONLY`` is set, :func:`init` sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
  (ROS's own default is ``SUBNET``: every host on the network) and logs one line saying so;
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`` opens it on purpose.
* :func:`precheck`: checks the overrides of a node's table rows (``--ros-args -p`` and params
  files) against the table *before* rclpy declares them, so a wrong type or a value out of
  range is reported by the table's own text (name, value, allowed range, unit, meaning)
  instead of rclpy's exception.
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
* :func:`destroy_on_error`: a node whose construction fails is destroyed at once (a half-built
  node left for interpreter exit crashed or hung the process after the error line).

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
from typing import Any

import rclpy
import rclpy.logging
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from ..params import ParameterSpec

__all__ = ['EXIT_BAD_PARAMETERS', 'DEFAULT_DISCOVERY_RANGE', 'default_discovery',
           'BadParameters', 'init', 'precheck', 'declare_rows',
           'refuse_unknown', 'explain', 'one_line', 'report', 'destroy_on_error']

#: Exit code of every node for invalid arguments or parameters at start.
EXIT_BAD_PARAMETERS = 2
#: Discovery range of the nodes when the environment does not choose one.
DEFAULT_DISCOVERY_RANGE = 'LOCALHOST'
_DISCOVERY_VARS = ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_LOCALHOST_ONLY')


def default_discovery(environ: dict[str, str] | None = None) -> bool:
    """Set ``ROS_AUTOMATIC_DISCOVERY_RANGE`` to :data:`DEFAULT_DISCOVERY_RANGE` in
    ``environ`` (``os.environ``, read by rcl at init) when the environment leaves discovery
    unset; True when it did."""
    env = os.environ if environ is None else environ
    if any(env.get(name, '').strip() for name in _DISCOVERY_VARS):
        return False
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = DEFAULT_DISCOVERY_RANGE
    return True


class BadParameters(ValueError):
    """Invalid arguments or parameters at start; the message is the one line to print."""


def destroy_on_error(init: Callable[..., None]) -> Callable[..., None]:
    """Decorate a node's ``__init__``: if it raises (a start-up error), the half-built node
    is destroyed before the error propagates. Otherwise the exception's traceback keeps it
    alive past ``rclpy.shutdown()``, and destroying it then, at interpreter exit, crashed the
    process (SIGSEGV after the error line) or hung it, in about one start in ten."""

    @functools.wraps(init)
    def wrapper(self: Node, *args: Any, **kwargs: Any) -> None:
        try:
            init(self, *args, **kwargs)
        except BaseException:
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
            f'{DEFAULT_DISCOVERY_RANGE}, the fohssv default); set '
            'ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET to reach nodes on other hosts')


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


def _a(kind: str) -> str:
    return f"{'an' if kind[0] in 'aeiou' else 'a'} {kind}"


def precheck(node: Node, specs: Iterable[ParameterSpec], kinds: Mapping[str, int]) -> None:
    """Check the overrides of ``specs`` before they are declared with the ROS types ``kinds``
    (name -> ``ParameterType``). Whole doubles given for integer rows are converted.

    Raises:
        ParameterError: a value of the wrong type or outside the row's range (one line naming
            the parameter, the value, the allowed range, the unit and the meaning).
    """
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import Parameter

    overrides = _overrides(node)
    for spec in specs:
        p = overrides.get(spec.name)
        if p is None:
            continue
        value = p.value
        kind = kinds.get(spec.name)
        got = _kind_name(value)
        if kind == ParameterType.PARAMETER_DOUBLE:
            if got not in ('double', 'integer'):
                raise spec.refuse(value, f'is {_a(got)}, not a number')
        elif kind == ParameterType.PARAMETER_INTEGER:
            if got == 'double' and math.isfinite(value) and value == int(value):
                overrides[spec.name] = Parameter(spec.name, value=int(value))
                value = int(value)
            elif got != 'integer':
                what = 'not a whole number' if got == 'double' else f'{_a(got)}, not a number'
                raise spec.refuse(value, f'is {what}')
        elif kind == ParameterType.PARAMETER_STRING:
            if got != 'string':
                raise spec.refuse(value, f'is {_a(got)}, not a name')
        elif kind == ParameterType.PARAMETER_NOT_SET:
            if got not in ('double', 'integer', 'string'):
                raise spec.refuse(value, f'is {_a(got)}')
        spec.validate(value)   # ParameterError: out of range, not a choice, not 4 numbers


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
    unknown = sorted(n for n in _overrides(node) if not node.has_parameter(n))
    if not unknown:
        return
    declared = sorted(node._parameters) if isinstance(getattr(node, '_parameters', None),
                                                      dict) else []
    parts = []
    for name in unknown:
        close = difflib.get_close_matches(name, declared, n=3, cutoff=0.6)
        hint = f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ''
        parts.append(f'{name!r}{hint}')
    raise BadParameters(f"unknown parameter{'s' if len(unknown) > 1 else ''} "
                        f"{', '.join(parts)} for node {node.get_name()!r}; its parameters: "
                        f"{', '.join(declared)}")


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


def report(name: str, exc: BaseException, specs: Iterable[ParameterSpec] = ()) -> int:
    """Print the one line for a start-up error (console format, to stderr: rclpy's logging
    may not be initialised when ``rclpy.init`` itself failed) and end the process at once with
    :data:`EXIT_BAD_PARAMETERS`. Nothing ran, so nothing needs tearing down, and tearing down
    a half-built node's DDS participant hung or crashed the process now and then when many
    started at once (seen in a clean-clone test run: a refused node still alive after 60 s)."""
    text = explain(exc, specs)
    if not text.startswith('invalid '):
        text = f'invalid parameters: {text}'
    print(f'[ERROR] [{time.time():.9f}] [{name}]: {text}', file=sys.stderr, flush=True)
    sys.stdout.flush()
    os._exit(EXIT_BAD_PARAMETERS)
