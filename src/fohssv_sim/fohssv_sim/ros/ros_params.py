"""ROS parameters generated from parameter tables (:class:`fohssv_sim.params.ParameterSpec`).

Used by every node: the plant (model table + node options), the controller node (a
controller's ``field_specs(Parameters)``), the recorder and the player (their tables in
:mod:`.bag_options`). Each row becomes a declared parameter whose descriptor carries the
description with unit and reference, the allowed values as ``additional_constraints``, a
``FloatingPointRange``/``IntegerRange`` when both bounds are finite, and ``read_only`` when the
row ``needs_reset``.

ROS typing of the rows:

* a number (default float) -> ``double``; an integer default -> ``integer``;
* a name only (``choices``, not numeric) -> ``string``;
* a name *or* a number (``step``, ``planing_offset``, ``advection_delay``) -> dynamically typed:
  ``step:=auto`` and ``step:=2.0e-5`` are both accepted, and the table's validation decides;
* a state (:class:`fohssv_sim.ros.options.StateSpec`) -> ``double_array``;
* a switch (:class:`~fohssv_sim.ros.options.FlagSpec`) -> ``bool``; free text
  (:class:`~fohssv_sim.ros.options.TextSpec`) -> ``string``; a list of names
  (:class:`~fohssv_sim.ros.options.NamesSpec`) -> ``string_array``.

One validation path: a value is checked by :func:`check_value` (its ROS type, then its row's
range and wording) at start, for each given value (:func:`declare`), and on set, for each
change, before the node's own cross-row rules (:func:`install_validation`); the refusal is the
row's one line (:class:`~fohssv_sim.params.ParameterError`). Every descriptor is declared with
``dynamic_typing`` (its type is still the value's: ``ros2 param describe`` shows ``double``),
so a value of the wrong type reaches that check instead of rclpy's ``Wrong parameter type,
expected '3' got '4'``; the descriptor carries the range (rclpy applies it first, as it does
for any node), the unit, the description and ``read_only``. An integer given for a ``double``
row (``-p speed:=80``, ``speed: 80`` in YAML, or on set) and a whole double for an ``integer``
row are converted, not refused. The node applies an accepted change afterwards (``post_set``).
"""

from __future__ import annotations

import array
import math
import re
import sys
import weakref
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..params import ParameterSpec
from .options import NamesSpec, StateSpec, ros_type_name
from .startup import _a, _kind_name, _not_a_number, given, params_file_args, redeclare, report

__all__ = ['ros_type', 'descriptor', 'declare', 'check_value', 'values_of',
           'install_validation', 'python_value', 'refuse_early']

#: Each node's rows by name with their ROS types: what a change is checked against.
_ROWS: weakref.WeakKeyDictionary[Node, dict[str, tuple[ParameterSpec, int]]] = \
    weakref.WeakKeyDictionary()


#: ROS parameter types by the names :func:`.options.ros_type_name` gives.
_ROS_TYPES = {'double[]': ParameterType.PARAMETER_DOUBLE_ARRAY,
              'string[]': ParameterType.PARAMETER_STRING_ARRAY,
              'bool': ParameterType.PARAMETER_BOOL,
              'string or double': ParameterType.PARAMETER_NOT_SET,
              'integer, string or integer[]': ParameterType.PARAMETER_NOT_SET,
              'string': ParameterType.PARAMETER_STRING,
              'integer': ParameterType.PARAMETER_INTEGER,
              'double': ParameterType.PARAMETER_DOUBLE}


def ros_type(spec: ParameterSpec) -> int:
    """The ``ParameterType`` of a row (``PARAMETER_NOT_SET`` = dynamically typed)."""
    return _ROS_TYPES[ros_type_name(spec)]


def descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """The descriptor of one row."""
    unit = f' [{spec.unit}]' if spec.unit and spec.unit != '-' else ''
    ref = f' ({spec.reference})' if spec.reference else ''
    d = ParameterDescriptor(
        name=spec.name,
        description=f'{spec.description}{unit}{ref}',
        additional_constraints=f'allowed: {spec.range_text()}{unit}',
        read_only=spec.needs_reset,
        dynamic_typing=True,     # the type is checked by check_value, in the row's words
    )
    kind = ros_type(spec)
    bounded = (spec.numeric and spec.low is not None and spec.high is not None
               and math.isfinite(spec.low) and math.isfinite(spec.high))
    if bounded and kind == ParameterType.PARAMETER_DOUBLE:
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.low),
                                                     to_value=float(spec.high), step=0.0)]
    elif bounded and kind == ParameterType.PARAMETER_INTEGER:
        d.integer_range = [IntegerRange(from_value=int(math.ceil(spec.low)),
                                        to_value=int(math.floor(spec.high)), step=1)]
    return d


def _ros_default(spec: ParameterSpec) -> Any:
    if isinstance(spec, StateSpec):
        return [float(v) for v in spec.default]
    if isinstance(spec, NamesSpec):
        return [str(v) for v in spec.default]
    return spec.default


def _coerce(kind: int, value: Any) -> Any:
    """An integer (array) for a double (array) row as a double (array), a whole double for an
    integer row as an integer; anything else unchanged."""
    if kind == ParameterType.PARAMETER_DOUBLE and isinstance(value, int) \
            and not isinstance(value, bool):
        return float(value)
    if kind == ParameterType.PARAMETER_INTEGER and isinstance(value, float) \
            and math.isfinite(value) and value == int(value):
        return int(value)
    if kind == ParameterType.PARAMETER_DOUBLE_ARRAY and isinstance(value, (list, tuple,
                                                                           array.array)):
        if all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            return [float(v) for v in value]
    return value


def check_value(spec: ParameterSpec, kind: int, value: Any) -> None:
    """Check one value (already converted by :func:`_coerce`) against its row's ROS type
    ``kind`` and then the row itself.

    Raises:
        ParameterError: a value of the wrong type or outside the row's range (one line naming
            the parameter, the value, the allowed range, the unit and the meaning).
    """
    got = _kind_name(value)
    if kind == ParameterType.PARAMETER_DOUBLE and got != 'double':
        raise spec.refuse(value, _not_a_number(value, got))
    if kind == ParameterType.PARAMETER_INTEGER and got != 'integer':
        raise spec.refuse(value, 'is not a whole number' if got == 'double'
                          else _not_a_number(value, got))
    if kind == ParameterType.PARAMETER_STRING and got != 'string':
        raise spec.refuse(value, f'is {_a(got)}, not a name')
    if kind == ParameterType.PARAMETER_NOT_SET and got not in ('double', 'integer', 'string') \
            and not (got == 'array' and getattr(spec, 'accepts_array', False)):
        raise spec.refuse(value, f'is {_a(got)}')
    if kind == ParameterType.PARAMETER_BOOL and got != 'bool':
        raise spec.refuse(value, f'is {_a(got)}, not true or false')
    if kind in _ARRAYS:
        item, what = _ARRAYS[kind]
        if got != 'array' or not all(item(v) for v in value):
            raise spec.refuse(value, f'is {_a(got)}, not {what}')
    spec.validate(value)   # ParameterError: out of range, not a choice, not 4 numbers


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


#: Array parameter types: what each item must be, and the words for the whole.
_ARRAYS = {ParameterType.PARAMETER_DOUBLE_ARRAY: (_number, 'a list of numbers'),
           ParameterType.PARAMETER_STRING_ARRAY: (lambda v: isinstance(v, str),
                                                  'a list of names')}


def declare(node: Node, specs: Iterable[ParameterSpec]) -> dict[str, Any]:
    """Declare every row on ``node``, with its given value (``--ros-args``, YAML,
    ``parameter_overrides``) where one was given, and return the values as plain Python
    (tuples for arrays).

    Raises:
        ParameterError: a given value of the wrong type or out of range, in the row's words.
    """
    specs = tuple(specs)
    first = node not in _ROWS
    rows = _ROWS.setdefault(node, {})
    values = given(node)
    declared = []
    for s in specs:
        kind = rows.setdefault(s.name, (s, ros_type(s)))[1]
        if s.name in values:
            value = _coerce(kind, values[s.name])
            check_value(s, kind, value)
        else:
            value = _ros_default(s)
        declared.append((s.name, value, descriptor(s)))
    redeclare(node, declared)

    def pre_set(params: list[Parameter]) -> list[Parameter]:
        out = []
        for p in params:
            v = _coerce(rows[p.name][1], p.value) if p.name in rows else p.value
            out.append(p if v is p.value else Parameter(p.name, value=v))
        return out

    if first:
        node.add_pre_set_parameters_callback(pre_set)
        # every row's change is checked, also a row no install_validation names
        node.add_on_set_parameters_callback(
            lambda params: _row_refusal(node, params) or SetParametersResult(successful=True))
    return values_of(node, specs)


def _row_refusal(node: Node, params: Sequence[Parameter]) -> SetParametersResult | None:
    """The refusal of a change whose value its row refuses (:func:`check_value`), or None."""
    rows = _ROWS.get(node, {})
    try:
        for p in params:
            if p.name in rows:
                check_value(*rows[p.name], p.value)
    except ValueError as exc:
        return _refused(node, params, str(exc))
    return None


def _refused(node: Node, params: Sequence[Parameter], reason: str) -> SetParametersResult:
    """Refuse a change of ``params`` with ``reason``; their descriptors keep the types of the
    values they keep (rclpy's dynamic typing set them to the refused values' types)."""
    for p in params:
        if node.has_parameter(p.name):
            node.describe_parameter(p.name).type = node.get_parameter(p.name).type_.value
    return SetParametersResult(successful=False, reason=reason)


def python_value(value: Any) -> Any:
    """A parameter value as plain Python (arrays as tuples)."""
    if isinstance(value, (array.array, list)):
        return tuple(value)
    return value


def values_of(node: Node, specs: Iterable[ParameterSpec]) -> dict[str, Any]:
    """The current values of the rows, as plain Python."""
    return {s.name: python_value(node.get_parameter(s.name).value) for s in specs}


def install_validation(node: Node, names: Sequence[str],
                       check: Callable[[Mapping[str, Any]], Any],
                       apply: Callable[[Any], None]) -> None:
    """Validate parameter changes with ``check`` and apply them with ``apply``.

    ``check(values)`` gets every value of ``names`` with the requested changes merged in and
    builds the node's pure configuration, raising ``ValueError`` (e.g. ParameterError) to refuse
    with its text; nothing is applied then. After a successful set, ``apply`` receives what
    ``check`` returned.
    """
    names = tuple(names)
    pending: list[Any] = []

    def on_set(params: list[Parameter]) -> SetParametersResult:
        # rclpy calls the callback added last first: the rows' own check comes before check
        refused = _row_refusal(node, params)
        if refused is not None:
            pending.clear()
            return refused
        values = {n: python_value(node.get_parameter(n).value) for n in names}
        for p in params:
            if p.name in values:
                values[p.name] = python_value(p.value)
        try:
            config = check(values)
        except ValueError as exc:
            pending.clear()
            return _refused(node, params, str(exc))
        pending[:] = [config]
        return SetParametersResult(successful=True)

    def post_set(params: list[Parameter]) -> None:
        if pending:
            apply(pending.pop())

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)


#: How rcl reads a plain ``-p NAME:=VALUE`` scalar, for the values :func:`refuse_early` judges
#: (anything else is left to the node's own check after ``rclpy.init``).
_BOOL = {'true': True, 'True': True, 'TRUE': True, 'false': False, 'False': False,
         'FALSE': False}
_INT = re.compile(r'[+-]?[0-9]+')
_FLOAT = re.compile(r'[+-]?([0-9]+\.[0-9]*|\.[0-9]+|[0-9]+)([eE][+-]?[0-9]+)?')
_WORD = re.compile(r'[A-Za-z_][A-Za-z0-9_./-]*')
_UNSURE = {'yes', 'no', 'on', 'off', 'y', 'n', 'null', 'nan', 'inf', 'infinity'}


def _scalar(text: str) -> tuple[bool, Any]:
    """(True, the value) of a ``-p`` value read as rcl reads a plain scalar; (False, None)
    when it is not plainly a bool, an integer, a number or a word."""
    if text in _BOOL:
        return True, _BOOL[text]
    if _INT.fullmatch(text):
        return True, int(text)
    if _FLOAT.fullmatch(text):
        return True, float(text)
    if _WORD.fullmatch(text) and text.lower().lstrip('.') not in _UNSURE:
        return True, text
    return False, None


def refuse_early(name: str, args: Sequence[str] | None, specs: Iterable[ParameterSpec]
                 ) -> None:
    """Before anything of ROS starts (no context, no DDS participant): refuse a ``-p
    NAME:=VALUE`` of a row of ``specs`` that :func:`check_value` refuses, with the one line
    and exit 2 the node would give after ``rclpy.init`` (:func:`.startup.report`), so that a
    refused start creates no DDS entity and tears nothing down. (A recorder refusing
    ``flush_period:=abc`` at start died of SIGSEGV once, one of ten refused at once; 200 such
    starts, ten at a time, did not reproduce it.) Only plain scalars of plain names are judged
    here, and nothing when a params file is given (its values and -p's may override each
    other): the rest is the node's own check."""
    args = list(sys.argv if args is None else args)
    if params_file_args(args):
        return
    rows = {s.name: s for s in specs}
    inside = False
    for i, a in enumerate(args):
        if a == '--ros-args':
            inside = True
        elif a == '--':
            inside = False
        elif inside and a in ('-p', '--param') and i + 1 < len(args):
            key, sep, text = args[i + 1].partition(':=')
            spec = rows.get(key)
            plain, value = _scalar(text)
            if not sep or spec is None or not plain:
                continue
            kind = ros_type(spec)
            try:
                check_value(spec, kind, _coerce(kind, value))
            except ValueError as exc:
                report(name, exc, rows.values())
