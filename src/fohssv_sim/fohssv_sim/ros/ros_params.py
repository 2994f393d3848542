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

An integer given for a ``double`` row (``-p speed:=80``, or ``speed: 80`` in YAML) is
converted to a double instead of failing with rclpy's type error, at start and on set. A value
of the wrong type is refused in the table's words (:func:`.startup.typed`: the parameter, the
value, what it is, what the row allows), at start and on set, not with rclpy's "Wrong
parameter type, expected '3' got '4'" (its enum numbers): every row is declared with
``dynamic_typing`` so that rclpy leaves the type to the row's own check, and its descriptor
keeps the row's type (a refused change puts back the type rclpy's dynamic typing took from it).

Validation (``on_set``) only validates: it rebuilds the pure dataclasses from the current
values plus the change, and refuses with the :class:`~fohssv_sim.params.ParameterError` text.
The node applies an accepted change afterwards (``post_set``).
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
from .startup import params_file_args, precheck, report, typed

__all__ = ['ros_type', 'descriptor', 'declare', 'values_of', 'install_validation',
           'python_value', 'refuse_early']


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
    )
    kind = ros_type(spec)
    # the type is checked by the row (declare's on_set, :func:`.startup.typed`), in its words
    d.dynamic_typing = True
    if kind != ParameterType.PARAMETER_NOT_SET:
        d.type = kind
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
    """An integer (array) for a double (array) row, as a double (array); else unchanged."""
    if kind == ParameterType.PARAMETER_DOUBLE and isinstance(value, int) \
            and not isinstance(value, bool):
        return float(value)
    if kind == ParameterType.PARAMETER_DOUBLE_ARRAY and isinstance(value, (list, tuple,
                                                                           array.array)):
        if all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            return [float(v) for v in value]
    return value


def declare(node: Node, specs: Iterable[ParameterSpec]) -> dict[str, Any]:
    """Declare every row on ``node`` (overrides from ``--ros-args``/YAML apply) and return the
    values as plain Python (tuples for arrays).

    Raises:
        ParameterError: an override of the wrong type or out of range, in the table's words
            (checked before rclpy declares it: see :func:`.startup.precheck`).
    """
    specs = tuple(specs)
    kinds = {s.name: ros_type(s) for s in specs}
    precheck(node, specs, kinds)
    # Integers given where doubles are declared: convert them before rclpy's type check.
    overrides = getattr(node, '_parameter_overrides', None)
    if isinstance(overrides, dict):
        for name, kind in kinds.items():
            p = overrides.get(name)
            if p is not None:
                v = _coerce(kind, p.value)
                if v is not p.value:
                    overrides[name] = Parameter(name, value=v)
    node.declare_parameters('', [(s.name, _ros_default(s), descriptor(s)) for s in specs])

    def pre_set(params: list[Parameter]) -> list[Parameter]:
        out = []
        for p in params:
            kind = kinds.get(p.name)
            v = _coerce(kind, p.value) if kind is not None else p.value
            out.append(p if v is p.value else Parameter(p.name, value=v))
        return out

    node.add_pre_set_parameters_callback(pre_set)
    if node not in _ROWS:

        def of_its_type(params: list[Parameter]) -> SetParametersResult:
            why = _wrong_type(node, params)
            return (SetParametersResult(successful=True) if why is None
                    else _refused(node, params, why))

        node.add_on_set_parameters_callback(of_its_type)
    _ROWS.setdefault(node, {}).update((s.name, (s, kinds[s.name])) for s in specs)
    return values_of(node, specs)


#: Each node's declared rows and their ROS types, for the type check of a change.
_ROWS: weakref.WeakKeyDictionary[Node, dict[str, tuple[ParameterSpec, int]]] = \
    weakref.WeakKeyDictionary()


def _wrong_type(node: Node, params: Sequence[Parameter]) -> str | None:
    """The refusal of the first of ``params`` whose value is of the wrong type for its row
    (:func:`.startup.typed`), or None."""
    rows = _ROWS.get(node, {})
    for p in params:
        if p.name in rows:
            spec, kind = rows[p.name]
            try:
                typed(spec, kind, python_value(p.value))
            except ValueError as exc:
                return str(exc)
    return None


def _refused(node: Node, params: Sequence[Parameter], reason: str) -> SetParametersResult:
    """Refuse a change of ``params`` with ``reason``; their descriptors keep the types of
    the values they keep (rclpy's dynamic typing set them to the refused values' types)."""
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
        why = _wrong_type(node, params)      # this callback runs before declare's
        if why is not None:
            return _refused(node, params, why)
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
    NAME:=VALUE`` of a row of ``specs`` that the row refuses, with the one line and exit 2 the
    node would give after ``rclpy.init`` (:func:`.startup.report`), so that a refused start
    creates no DDS entity and tears nothing down. (A recorder refusing ``flush_period:=abc``
    at start died of SIGSEGV once, one of ten refused at once; 200 such starts, ten at a
    time, did not reproduce it.) Only plain scalars of plain names are judged here, and
    nothing when a params file is given (its values and -p's may override each other): the
    rest is the node's own check."""
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
            try:
                spec.validate(typed(spec, ros_type(spec), value))
            except ValueError as exc:
                report(name, exc, rows.values())
