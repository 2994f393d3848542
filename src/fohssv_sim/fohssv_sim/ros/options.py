"""Options of the plant node that are not model parameters: one table, one dataclass; and
the validated options every node's table uses.

Pure (no rclpy): the table :data:`NODE_PARAMETERS` is declared as ROS parameters next to
:data:`fohssv_sim.params.PARAMETERS` by :mod:`fohssv_sim.ros.ros_params`, and documented in
``docs/ros.md`` from the same rows. ``needs_reset=True`` rows are read-only on a running node.

The kinds of row besides numbers and names (state, switch, text, names) are in
:mod:`fohssv_sim.param_kinds`, with the rows the environments share (``control_period``,
``initial_state``); this module re-exports the kinds for the nodes. :class:`TableOptions`
turns a table's values into validated attributes (the recorder's and the player's options,
:mod:`.bag_options`).

Control period versus docs/model.md §7: the plant holds each command for ``control_period``
(zero-order hold). The default 1e-4 s (5 FOM steps of 2e-5 s, 10 RK4 steps of 1e-5 s) shifts
the FOM limit cycle at V = 75 by about 1-2 % against continuous feedback; 1e-3 s would shift it
by more than 10 %. Every result must state the control period it ran with.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Any

from ..param_kinds import (
    CONTROL_PERIOD,
    INITIAL_STATE,
    FlagSpec,
    NamesSpec,
    StateSpec,
    TextSpec,
)
from ..params import (
    ModelParameters,
    ParameterError,
    ParameterSpec,
    field_specs,
    spec_field,
    steps_per_period,
    validate_fields,
)

__all__ = ['MODES', 'NODE_PARAMETERS', 'NODE_PARAMETER_BY_NAME', 'ADVANCED', 'StateSpec',
           'FlagSpec',
           'TextSpec', 'NamesSpec', 'CpusSpec', 'CPU_AFFINITY', 'CPU_DMA_LATENCY', 'usable_cpus',
           'TableOptions', 'PlantOptions', 'check_options',
           'clock_samples', 'view_samples', 'ros_type_name', 'whole_number']

#: The plant node's two modes.
MODES = ('lockstep', 'realtime')


def usable_cpus() -> tuple[int, ...]:
    """The CPUs this process may run on (``os.sched_getaffinity``; all CPUs where that is
    not available)."""
    try:
        return tuple(sorted(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return tuple(range(os.cpu_count() or 1))


@dataclass(frozen=True)
class CpusSpec(ParameterSpec):
    """A set of CPUs (a ROS parameter typed at run time: a CPU number such as ``1``, a list
    in ``taskset -c`` form such as ``'0,2-3'``, an integer array, or ``''`` for none). Its value
    is the sorted tuple of CPU numbers (``()`` for none); each must be one this process may
    run on."""

    numeric: bool = False
    #: a ROS array is one of its forms (ros_params.check_value lets it through)
    accepts_array = True

    def range_text(self) -> str:
        return ("'' (not pinned), a CPU number or a list such as '0,2-3' of CPUs this "
                'process may use')

    def validate(self, value: Any) -> tuple[int, ...]:
        """Return the CPUs as a sorted tuple.

        Raises:
            ParameterError: not CPU numbers, or a CPU this process may not use.
        """
        spans = self._parse(value)
        usable = usable_cpus()
        if spans is None:
            raise self.refuse(value, 'is not a CPU number or a list of them (this process may '
                              f'use CPU {_ranges(usable)})')
        top = usable[-1]       # CPUs above it are refused as spans, never built one by one
        cpus = sorted({c for a, b in spans for c in range(a, min(b, top) + 1)})
        bad = _spans(c for c in cpus if c not in usable) + [
            (max(a, top + 1), b) for a, b in spans if b > top]
        if bad:
            raise self.refuse(value, f'names CPU {_span_text(bad)}, which this process may not '
                              f'use (it may use CPU {_ranges(usable)})')
        return tuple(cpus)

    @staticmethod
    def _parse(value: Any) -> list[tuple[int, int]] | None:
        """The (first, last) CPU ranges ``value`` names; None when it names none."""
        if isinstance(value, bool):
            return None
        if isinstance(value, int):
            items: list[Any] = [value]
        elif isinstance(value, str):
            items = [p.strip() for p in value.split(',')] if value.strip() else []
        elif isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
            items = list(value)
        else:
            return None
        spans = []
        for item in items:
            if isinstance(item, bool):
                return None
            if isinstance(item, int):
                first = last = item
            elif isinstance(item, str):
                lo, dash, hi = item.partition('-')
                if not (_decimal(lo) and (not dash or _decimal(hi))):
                    return None
                first, last = int(lo), int(hi) if dash else int(lo)
            else:
                return None
            if first < 0 or last < first:
                return None
            spans.append((first, last))
        return spans


def _decimal(text: str) -> bool:
    """ASCII digits only (``str.isdigit`` also takes '²', which ``int`` refuses)."""
    return text.isascii() and text.isdecimal()


def _spans(cpus: Any) -> list[tuple[int, int]]:
    """CPU numbers as runs of consecutive ones, (first, last) each."""
    out: list[tuple[int, int]] = []
    for c in sorted(cpus):
        if out and out[-1][1] == c - 1:
            out[-1] = (out[-1][0], c)
        else:
            out.append((c, c))
    return out


def _span_text(spans: list[tuple[int, int]]) -> str:
    """Spans in ``taskset -c`` form: ``0-3,6``."""
    return ','.join(f'{a}' if a == b else f'{a}-{b}' for a, b in spans)


def _ranges(cpus: Any) -> str:
    """CPU numbers in ``taskset -c`` form: ``0-3,6``."""
    return _span_text(_spans(cpus))


#: The CPUs a node's threads run on: the plant's and the controller nodes' row.
CPU_AFFINITY = CpusSpec(
    'cpu_affinity', '-', '', '-', "CPUs the node's threads run on (every thread of the "
    "process, DDS's too, pinned at start, as ros2_control's controller manager pins its loop "
    "with its cpu_affinity); '' = not pinned, the scheduler's choice. In lockstep with an "
    'external controller, the plant on one CPU and the controller node on another keeps each '
    "process's hand-over from DDS to its callback on one CPU (on a 2-core machine: plant 0, "
    'controller 1)')


#: The CPU wake-up latency a node's process asks Linux for while it runs: the plant's and the
#: controller nodes' row.
CPU_DMA_LATENCY = ParameterSpec(
    'cpu_dma_latency', '-', -1, 'us', 'the CPU wake-up latency this process asks Linux for '
    'while it runs (PM QoS: /dev/cpu_dma_latency held open, as cyclictest and real-time Linux '
    'guides do; dropped by the kernel when the process ends, however it ends); -1 (the '
    'default) = no request: the setting is system-wide, it keeps every idle CPU of the machine '
    'polling, and a simulator should not change that unasked. 0 keeps idle CPUs polling '
    'instead of halting, so a DDS message wakes its reader sooner (the lockstep round trip '
    'several times as fast on a small VM; a demo or a benchmark may ask for it) at the price '
    'of idle CPUs that do not rest; needs write access to /dev/cpu_dma_latency (root): '
    'without it the node says so in one line and runs on', low=-1.0, low_open=False, high=1e6,
    high_open=False)

#: The ROS types of the row kinds that are not plain numbers or names.
_TYPE_OF_KIND = ((StateSpec, 'double[]'), (NamesSpec, 'string[]'), (FlagSpec, 'bool'),
                 (CpusSpec, 'integer, string or integer[]'))


def ros_type_name(spec: ParameterSpec) -> str:
    """The ROS parameter type of a table row: ``double``, ``integer``, ``string``, ``string or
    double`` (dynamically typed: a name or a number), ``double[]`` (a state), ``bool`` (a
    switch), ``string[]`` (a list of names) or ``integer, string or integer[]``
    (CPUs: dynamically typed). The one rule;
    :func:`fohssv_sim.ros.ros_params.ros_type` maps it to rclpy's ``ParameterType``."""
    for kind, name in _TYPE_OF_KIND:
        if isinstance(spec, kind):
            return name
    if spec.choices and spec.numeric:
        return 'string or double'
    if not spec.numeric:
        return 'string'
    if isinstance(spec.default, int) and not isinstance(spec.default, bool):
        return 'integer'
    return 'double'


_P = ParameterSpec

#: Plant-node options (units in the table; ranges checked by :class:`PlantOptions`).
NODE_PARAMETERS: tuple[ParameterSpec, ...] = (
    _P('mode', '-', 'lockstep', '-', "'lockstep': publish the state, wait for the command that "
       "answers it, then advance (deterministic); 'realtime': advance paced by the wall clock, "
       'holding the latest command', choices=MODES, numeric=False),
    CONTROL_PERIOD,
    _P('duration', '-', 0.0, 's', 'simulated time after which the plant stops and exits 0; '
       '0 = run until stopped', low=0.0, low_open=False, high=1e6, high_open=False,
       needs_reset=False),
    INITIAL_STATE,
    _P('real_time_factor', '-', 1.0, '-', 'realtime mode: simulated seconds per wall second',
       low=0.0, high=1000.0, high_open=False, needs_reset=False),
    _P('pacing_period', '-', 1e-3, 's', 'realtime mode: deadline tolerance (one pacing tick): '
       'a sample published more than max(this, control_period / real_time_factor) after its '
       'due time is a deadline miss; a backlog of 10 ticks slips the schedule', low=1e-5,
       low_open=False, high=1.0, high_open=False),
    _P('clock_period', '-', 0.0, 's', 'realtime mode: simulated time between /clock messages '
       '(published at t = k clock_period); 0 = at every sample; a whole multiple of '
       'control_period. Lockstep publishes /clock at every sample. Either mode publishes it only '
       'while someone subscribes (a volatile topic: a reader that is not there gets nothing '
       'either way; one that matches during a run gets it from the plant\'s next look, within '
       '10-50 ms)', low=0.0, low_open=False,
       high=1.0, high_open=False),
    _P('view_period', '-', 0.01, 's', 'simulated time between the typed views for viewers '
       '(pose, twist, planing_wrench, vehicle_marker; published at t = k view_period, both '
       'modes); 0 = off; a whole multiple of control_period, or at most control_period (then '
       'every sample). The contract topics are unaffected', low=0.0, low_open=False,
       high=1.0, high_open=False),
    _P('profile', '-', 0, '-', '1: time each part of the per-sample path (advance, each '
       'publish, the command callback) and add the figures to the summary; 0: off (the hot '
       'path then makes no timing calls)', low=0.0, low_open=False, high=1.0,
       high_open=False),
    _P('command_timeout', '-', 5.0, 's', 'lockstep mode: wall time to wait for the command '
       'answering a state before the plant fails (exit code 3)', low=0.0, high=3600.0,
       high_open=False, needs_reset=False),
    _P('watchdog_timeout', '-', 0.1, 's', 'realtime mode: wall time without a command after '
       'which the plant warns (once per outage) and keeps holding the last good command; '
       '0 = off', low=0.0, low_open=False, high=3600.0, high_open=False, needs_reset=False),
    _P('max_command_age', '-', 1.0, 's', 'realtime mode: a command answering a state more '
       "than this much simulated time before the plant's current sample is rejected as stale, "
       'and one answering a time after the current sample is rejected as from the future '
       '(both counted with the rejected commands; the last good command is kept). Rejecting a '
       'late command keeps an even older one held, so this catches commands that cannot '
       'answer the run (a reset, a stale replay, a corrupt time), not mere latency',
       low=0.0, high=3600.0, high_open=False, needs_reset=False),
    _P('max_fin_deflection', '-', 0.5, 'rad', 'a command with |delta_f| above this is '
       'rejected (the last good command is kept)', low=0.0, high=math.pi / 2, high_open=False,
       needs_reset=False),
    _P('max_cavitator_deflection', '-', 0.5, 'rad', 'a command with |delta_c| above this is '
       'rejected (the last good command is kept)', low=0.0, high=math.pi / 2, high_open=False,
       needs_reset=False),
    _P('min_state_subscribers', '-', 1, '-', 'matched subscribers of state (controllers, '
       'recorders) to wait for before the first sample; a hosted controller counts as one',
       low=0.0, low_open=False, high=1000.0,
       high_open=False),
    _P('min_command_publishers', '-', 1, '-', 'matched publishers of command to wait for '
       'before the first sample; a hosted controller counts as one', low=0.0, low_open=False,
       high=1000.0, high_open=False),
    _P('min_view_subscribers', '-', 0, '-', 'matched subscribers of each typed view (pose, '
       'twist, planing_wrench, vehicle_marker) to wait for before the first sample, e.g. 1 '
       'for a viewer (its readers are volatile: views published before they match are not '
       'theirs); 0 = none', low=0.0, low_open=False, high=1000.0, high_open=False),
    _P('start_timeout', '-', 0.0, 's', 'wall time to wait for those matches; 0 = wait until '
       'they are there (the plant logs what it waits for every 5 s); when a positive timeout '
       'expires the plant exits with code 4 (both modes)', low=0.0, low_open=False,
       high=3600.0, high_open=False),
    _P('pace_to_subscribers', '-', 0, 'samples', 'lockstep mode: every this many samples wait '
       "until every subscriber acknowledged the samples, so a recorder slower than the loop "
       "paces the run instead of losing samples (set it when recording, e.g. 512; below the "
       "queue depth of 2000). After 1 s the loop goes on while that cannot lose a sample, "
       "else it waits up to 10 s (a stalled subscriber is then left behind with a warning); "
       "0 = off: the loop runs at the controller's pace",
       low=0.0, low_open=False, high=1900.0, high_open=False),
    _P('realtime_priority', '-', 50, '-', 'realtime mode: SCHED_FIFO priority (1-99) of the '
       "plant's pacing thread, as ros2_control's controller manager runs its loop (its "
       'thread_priority, also 50 by default); needs CAP_SYS_NICE or an rtprio limit (the '
       'plant says so in one line and runs with the normal scheduler without it); 0 = the '
       'normal scheduler',
       low=0.0, low_open=False, high=99.0, high_open=False),
    TextSpec('controller', '-', '', '-', "the controller law: '' (default) = an external "
             'controller node over command; else the name of a controller plugin (entry point '
             'in group fohssv.controllers, e.g. state_feedback) that the plant hosts: the law '
             'runs inside the loop every control period (no peer, no DDS in the loop), its '
             'parameters are declared here as controller.NAME, and the plant publishes the '
             'commands it gives on command', numeric=False,
             allowed="'' (an external controller node) or a plugin name of group "
             'fohssv.controllers'),
    _P('max_command_lag', '-', 20.0, 'control periods', 'realtime mode, external controller: '
       "a command's lag is how many control periods its sample lies before the plant's "
       'current one when it arrives; when every command arriving over this many control '
       'periods of simulated time lags by more than this (the loop cannot keep up with the '
       'control period), the plant stops with exit code 6, naming the lag, its cost per '
       'sample and the remedies', low=1.0, low_open=False, high=1e6, high_open=False,
       needs_reset=False),
    _P('max_deadline_miss_rate', '-', 0.0, '-', 'realtime mode: when over this share of the '
       'deadlines (0 to 1) has been missed once 1000 samples were paced, the plant stops with '
       'exit code 11, naming its cost per sample and the remedies; 0 (default): never stops '
       '(it warns above 0.01 and says "not real time" at the end)', low=0.0, low_open=False,
       high=1.0, high_open=False, needs_reset=False),
    TextSpec('record', '-', '', '-', "in-plant recording: bag directory to create for the "
             "plant's own run (rosbag2 MCAP as the recorder node writes it: every message the "
             'plant publishes and every command it takes, written by a writer process fed '
             "through shared memory, off the per-sample path); '' = off",
             allowed="'' (off) or a path that does not exist (its parent is created)"),
    _P('record_buffer', '-', 32 * 1024 * 1024, 'bytes', 'in-plant recording: size of the ring '
       'between the plant and its writer process; when it is full a lockstep plant waits for '
       'the writer, a realtime plant counts and logs the lost messages (exit code 8)',
       low=4096.0, low_open=False, high=float(2 ** 30), high_open=False),
    CPU_AFFINITY,
    CPU_DMA_LATENCY,
    _P('end_linger', '-', 1.0, 's', 'wall time the plant keeps its publishers after the run '
       'ended, so a subscriber that lags (a recorder, a plotter) can still take the last '
       'samples: Fast DDS drops the samples a reader has not taken when their writer goes '
       'away; ends early once nothing subscribes to state and planing_force', low=0.0,
       low_open=False, high=3600.0, high_open=False, needs_reset=False),
)

NODE_PARAMETER_BY_NAME: dict[str, ParameterSpec] = {p.name: p for p in NODE_PARAMETERS}
#: The plant's host-tuning and measurement rows, listed apart in the docs: their defaults suit
#: a user's run; the demo and the benchmarks set them.
ADVANCED = ('pacing_period', 'profile', 'pace_to_subscribers', 'realtime_priority',
            'record_buffer', 'cpu_affinity', 'cpu_dma_latency', 'end_linger')


def _f(name: str) -> Any:
    return spec_field(NODE_PARAMETER_BY_NAME[name])


def whole_number(spec: ParameterSpec, value: Any) -> Any:
    """A validated ``value`` of a row typed ``integer`` in ROS as an int; other rows' values
    unchanged.

    Raises:
        ParameterError: not a whole number.
    """
    if ros_type_name(spec) != 'integer':
        return value
    if value != int(value):
        raise spec.refuse(value, 'is not a whole number')
    return int(value)


class TableOptions:
    """A node's validated options: one read-only attribute per row of ``TABLE``.

    Each value (the row's default when not given) is validated by its row
    (:meth:`~fohssv_sim.params.ParameterSpec.validate`: its range, its wording); rows typed
    ``integer`` in ROS hold ints. A subclass states the rules a range cannot say in
    :meth:`check`, refusing with the row's words (:meth:`~fohssv_sim.params.ParameterSpec.refuse`).

    Raises:
        ParameterError: an invalid value, naming it, the allowed range and unit.
        TypeError: a name that is no row of the table.
    """

    TABLE: tuple[ParameterSpec, ...] = ()

    def __init__(self, **values: Any) -> None:
        unknown = sorted(set(values) - {s.name for s in self.TABLE})
        if unknown:
            raise TypeError(f'{type(self).__name__}: no option {", ".join(unknown)}')
        for spec in self.TABLE:
            value = spec.validate(values.get(spec.name, spec.default))
            object.__setattr__(self, spec.name, whole_number(spec, value))
        self.check()

    def check(self) -> None:
        """Rules beyond each row's range (none here); may normalise with :meth:`_set`."""

    def _set(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f'{type(self).__name__} is read-only')

    @classmethod
    def spec(cls, name: str) -> ParameterSpec:
        """The row named ``name``."""
        return next(s for s in cls.TABLE if s.name == name)

    def as_dict(self) -> dict[str, Any]:
        """The values by name, in table order."""
        return {s.name: getattr(self, s.name) for s in self.TABLE}

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other.as_dict() == self.as_dict()

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        fields = ', '.join(f'{k}={v!r}' for k, v in self.as_dict().items())
        return f'{type(self).__name__}({fields})'


@dataclass(frozen=True)
class PlantOptions:
    """Validated plant-node options (see :data:`NODE_PARAMETERS`).

    Raises:
        ParameterError: an invalid value, naming it, the allowed range and unit.
    """

    mode: str = _f('mode')
    control_period: float = _f('control_period')
    duration: float = _f('duration')
    initial_state: tuple = _f('initial_state')
    real_time_factor: float = _f('real_time_factor')
    pacing_period: float = _f('pacing_period')
    clock_period: float = _f('clock_period')
    view_period: float = _f('view_period')
    profile: int = _f('profile')
    command_timeout: float = _f('command_timeout')
    watchdog_timeout: float = _f('watchdog_timeout')
    max_command_age: float = _f('max_command_age')
    max_fin_deflection: float = _f('max_fin_deflection')
    max_cavitator_deflection: float = _f('max_cavitator_deflection')
    min_state_subscribers: int = _f('min_state_subscribers')
    min_command_publishers: int = _f('min_command_publishers')
    min_view_subscribers: int = _f('min_view_subscribers')
    start_timeout: float = _f('start_timeout')
    pace_to_subscribers: int = _f('pace_to_subscribers')
    realtime_priority: int = _f('realtime_priority')
    controller: str = _f('controller')
    max_command_lag: float = _f('max_command_lag')
    max_deadline_miss_rate: float = _f('max_deadline_miss_rate')
    record: str = _f('record')
    record_buffer: int = _f('record_buffer')
    cpu_affinity: tuple[int, ...] = _f('cpu_affinity')
    cpu_dma_latency: int = _f('cpu_dma_latency')
    end_linger: float = _f('end_linger')

    def __post_init__(self) -> None:
        validate_fields(self)
        for spec in field_specs(self):
            object.__setattr__(self, spec.name, whole_number(spec, getattr(self, spec.name)))

    def replace(self, **changes: Any) -> PlantOptions:
        """A validated copy with ``changes``."""
        return dataclasses.replace(self, **changes)


def check_options(model: ModelParameters, options: PlantOptions) -> int:
    """Check the options against the model; return the integration steps per sample.

    Raises:
        ParameterError: ``control_period`` is not a whole multiple of the model's step, or
            ``clock_period`` is not 0 or a whole multiple of ``control_period``.
    """
    try:
        hold = steps_per_period(options.control_period, model.step)
    except ValueError as exc:
        raise ParameterError(str(exc)) from None
    clock_samples(options)
    view_samples(options)
    return hold


def clock_samples(options: PlantOptions) -> int:
    """Samples per /clock message: 1 in lockstep or with ``clock_period`` 0, else
    ``clock_period / control_period``.

    Raises:
        ParameterError: ``clock_period`` is not a whole multiple of ``control_period``.
    """
    if options.clock_period == 0.0:
        return 1
    k = round(options.clock_period / options.control_period)
    if k < 1 or abs(k * options.control_period - options.clock_period) > (
            1e-9 * options.clock_period):
        raise ParameterError(
            f'clock_period={options.clock_period!r} s is not 0 or a whole multiple of '
            f'control_period={options.control_period!r} s (allowed: 0 or k * control_period, '
            f'k = 1, 2, ...; {NODE_PARAMETER_BY_NAME["clock_period"].description})')
    return 1 if options.mode == 'lockstep' else k


def view_samples(options: PlantOptions) -> int:
    """Samples per typed view: 0 (off) when ``view_period`` is 0, 1 when it is at most
    ``control_period`` (every sample), else ``view_period / control_period``.

    Raises:
        ParameterError: ``view_period`` is longer than ``control_period`` and not a whole
            multiple of it.
    """
    if options.view_period == 0.0:
        return 0
    if options.view_period <= options.control_period:
        return 1
    k = round(options.view_period / options.control_period)
    if abs(k * options.control_period - options.view_period) > (
            1e-9 * options.view_period):
        raise ParameterError(
            f'view_period={options.view_period!r} s is not 0, at most control_period or a '
            f'whole multiple of control_period={options.control_period!r} s (allowed: 0, '
            f'(0, control_period] or k * control_period, k = 2, 3, ...; '
            f'{NODE_PARAMETER_BY_NAME["view_period"].description})')
    return k
