"""The closed loop of ``make demo`` and of ``ros2 launch fohssv_sim closed_loop.launch.py``: one
list of nodes with their parameters, read by both (``scripts/demo.py`` turns it into
command lines, the launch file into ``launch_ros`` nodes; ``tests/test_launch.py`` checks both
against the installed executables and their declared parameters).

By default two processes: the plant (FOM, alpha = 0.85, V = 75 m/s, x(0) = 0, lockstep, 2 s
of simulated time) recording its own run (in-plant recording: its ``record`` parameter; a
writer process fed through shared memory writes the bag, off the loop, so nothing in the loop
waits for a recorder) and a controller node hosting the law named by ``controller`` (default
eq. 31); hosted (``hosted``), the plant alone. With ``recorder='node'`` a third process, the
recorder node, records over DDS with the settings that make its bag complete
(docs/recording.md, "The first commands of a run"): the recorder subscribes to ``state``
only once it hears a controller (``command_publishers: 1``), the plant waits for two
``state`` subscribers (``min_state_subscribers: 2``), the controller holds its commands until
the plant and the recorder both listen (``min_command_subscribers: 2``), and the recorder,
slower than the lockstep loop, paces it (``pace_to_subscribers: 512``). On request (the
launch's ``viewer:=true``, ``scripts/demo.py --viewer``) another node, :func:`viewer`,
serves the run to Foxglove; it reads only the typed views, so the loop's start rules do not
change.

How the run ends (:data:`EXIT_RULE`, :func:`exit_verdict`; the launch file and ``scripts/demo.py``
both follow it): the plant's exit 0 ends the run (the others are stopped, the recorder closes
the bag); any node's non-zero exit ends it too, with that node's exit code and last line, and
the launch or demo exits non-zero instead of waiting for a node that will never come.

Where the lockstep loop's two processes run (:func:`loop_cpus`, :func:`pinned`: the demo's
default; ``scripts/demo.py --pin off`` and the launch file leave it to the scheduler, as
several loops may share a machine): in lockstep, plant and controller node wake each other once
per sample. Left to the scheduler, a wake-up often lands the woken process on the CPU of the
one that woke it, and the two take turns on one CPU for stretches of the run: on this project's
2-core VM the pinned lockstep FOM loop ran 1.02-1.30 times as fast as unpinned (median 1.17
of eight full runs of ``bench/bench_ros.py``, its pinned case) and the demo's loop time varied
much less.

Pure: no rclpy, no launch.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

__all__ = ['NodeSpec', 'closed_loop', 'in_plant', 'default_bag', 'viewer', 'watched',
           'DEMO_PLANT', 'DEFAULT_CONTROLLER',
           'DEFAULT_DURATION', 'DEFAULT_VIEWER_PORT', 'ros_args', 'flag', 'EXIT_RULE',
           'ExitVerdict', 'exit_verdict', 'reason_line', 'loop_cpus', 'pinned']

#: The demo's plant parameters (besides ``duration`` and the start settings).
DEMO_PLANT: dict[str, Any] = {
    'model': 'fractional', 'fractional_order': 0.85, 'speed': 75.0, 'mode': 'lockstep',
    'initial_state': [0.0, 0.0, 0.0, 0.0],
}
DEFAULT_CONTROLLER = 'state_feedback'
#: Simulated seconds of the demo run.
DEFAULT_DURATION = 2.0
#: The Foxglove viewer's port (the one Foxglove's Open connection dialog proposes).
DEFAULT_VIEWER_PORT = 8765


@dataclass(frozen=True)
class NodeSpec:
    """One node of the closed loop: what ``ros2 run package executable`` starts, its node
    name and its parameters (values are numbers, strings, lists, or whatever the caller put
    in, e.g. launch substitutions)."""

    package: str
    executable: str
    name: str
    parameters: dict[str, Any] = field(default_factory=dict)


def flag(value: Any) -> bool:
    """A launch argument or command-line switch as a bool: 'true' (any case), '1', 'yes' or
    True."""
    return str(value).strip().lower() in ('true', '1', 'yes')


def closed_loop(controller: Any = DEFAULT_CONTROLLER, duration: Any = DEFAULT_DURATION,
                bag_path: Any = '', plant: dict[str, Any] | None = None,
                hosted: bool = False, recorder: str = 'plant') -> tuple[NodeSpec, ...]:
    """The closed loop: the plant recording its own run (in-plant recording, ``record``)
    and the controller node; with ``hosted`` the plant only, hosting the law itself (its
    ``controller`` parameter): no controller node, no DDS in the loop. ``recorder='node'``:
    the plant, the controller node and a recorder node (plant and recorder node when
    hosted), with the settings that make that bag complete.

    Args:
        controller: the ``controller`` parameter of the generic controller node (a plugin
            name of the group ``fohssv.controllers``), or of the plant when ``hosted``.
        duration: simulated seconds the plant runs before it exits 0.
        bag_path: the bag to create ('' = :func:`default_bag`, ``runs/<UTC time>``).
        plant: plant parameters replacing :data:`DEMO_PLANT` entries (e.g. another model).
        hosted: the law in the plant (the same ``min_state_subscribers``: the hosted law
            counts as one, so the plant waits for a recorder node).
        recorder: ``'plant'`` (in-plant recording, :func:`in_plant`) or ``'node'``.
    """
    if recorder == 'plant':
        return in_plant(closed_loop(controller, duration, bag_path, plant, hosted, 'node'),
                        bag_path or default_bag())
    if recorder != 'node':
        raise ValueError(f"recorder={recorder!r}: 'plant' (in-plant recording) or 'node' "
                         '(the recorder node)')
    if hosted:
        spec_plant, _, spec_recorder = closed_loop(controller, duration, bag_path, plant,
                                                   recorder='node')
        return (NodeSpec(spec_plant.package, spec_plant.executable, spec_plant.name,
                         {**spec_plant.parameters, 'controller': controller}), spec_recorder)
    return (
        NodeSpec('fohssv_sim', 'plant', 'plant', {
            **DEMO_PLANT, **(plant or {}), 'duration': duration,
            # the controller and the recorder: the plant waits for both
            'min_state_subscribers': 2,
            # the recorder is slower than the loop: it paces the run (nothing lost)
            'pace_to_subscribers': 512}),
        NodeSpec('fohssv_controller', 'controller', 'controller', {
            'controller': controller,
            # the plant and the recorder: no command goes out before both listen
            'min_command_subscribers': 2}),
        NodeSpec('fohssv_sim', 'recorder', 'recorder', {
            'bag_path': bag_path,
            # subscribe to state (which the plant waits for) only once a controller is heard
            'command_publishers': 1}),
    )


def default_bag(now: datetime | None = None) -> Path:
    """``runs/<UTC time>`` under ``$FOHSSV_ROOT`` (or the current directory): the bag of a
    run given no ``bag_path``, recorded by the plant or by the recorder node."""
    now = now or datetime.now(timezone.utc)
    return Path(os.environ.get('FOHSSV_ROOT', '.')) / 'runs' / now.strftime(
        '%Y%m%dT%H%M%S_%fZ')


def in_plant(nodes: tuple[NodeSpec, ...], bag: Any) -> tuple[NodeSpec, ...]:
    """The loop of ``nodes`` (plant, controller node, recorder node; or plant and recorder
    node when hosted) without the recorder node: the plant records its own run to ``bag``
    (its ``record``; None: unrecorded), so nothing waits for a third process (no
    ``pace_to_subscribers``, one state subscriber, one command subscriber; a hosted law
    counts as the state subscriber)."""
    plant, ctl = nodes[0], (nodes[1] if len(nodes) == 3 else None)
    params = {k: v for k, v in plant.parameters.items() if k != 'pace_to_subscribers'}
    params['min_state_subscribers'] = 1
    if bag is not None:
        params['record'] = str(bag)
    out = NodeSpec(plant.package, plant.executable, plant.name, params)
    if ctl is None:
        return (out,)
    return (out, NodeSpec(ctl.package, ctl.executable, ctl.name,
                          {**ctl.parameters, 'min_command_subscribers': 1}))


def viewer(port: Any = DEFAULT_VIEWER_PORT, rate: Any = None) -> NodeSpec:
    """The Foxglove viewer (``ros2 run fohssv_sim viewer``) on ws://127.0.0.1:``port``, at
    most ``rate`` views a second (None: the viewer's default)."""
    return NodeSpec('fohssv_sim', 'viewer', 'viewer',
                    {'port': port, **({} if rate is None else {'rate': rate})})


def watched(specs: tuple[NodeSpec, ...]) -> tuple[NodeSpec, ...]:
    """The loop's nodes with the plant waiting for a viewer's readers of its views before the
    first sample (``min_view_subscribers`` 1: the viewer's readers are volatile, so views
    published before they match never reach it). The plant is the first node."""
    plant = specs[0]
    return (replace(plant, parameters={**plant.parameters, 'min_view_subscribers': 1}),
            *specs[1:])


def loop_cpus(usable: Iterable[int] | None = None) -> tuple[int, int] | None:
    """The CPUs that keep the lockstep loop's plant and controller node apart: the first two
    of ``usable`` (default: the CPUs this process may run on, as ``taskset`` shows them), or
    None when there are fewer than two."""
    if usable is None:
        try:
            usable = os.sched_getaffinity(0)
        except AttributeError:  # pragma: no cover - not Linux: every CPU
            usable = range(os.cpu_count() or 1)
    cpus = sorted(set(usable))
    return (cpus[0], cpus[1]) if len(cpus) >= 2 else None


def pinned(specs: tuple[NodeSpec, ...], cpus: tuple[int, int] | None) -> tuple[NodeSpec, ...]:
    """The loop's nodes with the plant on ``cpus[0]`` and the controller node on ``cpus[1]``
    (their ``cpu_affinity``); the recorder, a viewer and a hosted plant's loop are left to
    the scheduler (a hosted plant has no peer to wake). ``cpus`` None: ``specs`` unchanged."""
    if cpus is None:
        return specs
    out = list(specs)
    ctl = [i for i, s in enumerate(out) if s.package == 'fohssv_controller']
    if not ctl:
        return specs
    for i, cpu in ((0, cpus[0]), (ctl[0], cpus[1])):
        out[i] = replace(out[i], parameters={**out[i].parameters, 'cpu_affinity': cpu})
    return tuple(out)


def _value(v: Any) -> str:
    if isinstance(v, (list, tuple)):
        return '[' + ','.join(_value(x) for x in v) + ']'
    if isinstance(v, float):
        return repr(v)
    return str(v)


def ros_args(spec: NodeSpec) -> list[str]:
    """``['--ros-args', '-p', 'name:=value', ...]`` for the node's parameters (an empty
    string is left out: the node's default)."""
    out = ['--ros-args']
    for k, v in spec.parameters.items():
        if v != '':
            out += ['-p', f'{k}:={_value(v)}']
    return out


#: How a node's exit ends the closed loop (the launch file's exit handlers, scripts/demo.py).
EXIT_RULE = ('the plant exiting 0 ends the run: the controller and the recorder are stopped '
             '(SIGINT) and the recorder closes the bag; any node exiting non-zero (at start: a '
             'bad parameter, a bag_path that exists, an unknown controller; later: a plant '
             'error, lost messages) ends it with that node\'s exit code and last line, and the '
             'launch (exit 1) or the demo (that exit code) fails')


@dataclass(frozen=True)
class ExitVerdict:
    """What one node's exit means for the closed loop (:func:`exit_verdict`)."""

    failed: bool         # the loop fails: stop everything, exit non-zero
    ends_run: bool       # stop the other nodes now
    message: str


def exit_verdict(name: str, code: int, is_plant: bool, last_line: str = '') -> ExitVerdict:
    """:data:`EXIT_RULE` for node ``name`` exiting with ``code`` (negative: killed by that
    signal); ``last_line`` is the last line it printed (its error, when it fails)."""
    if code != 0:
        text = f'{name} exited with code {code}'
        return ExitVerdict(True, True, f'{text}: {last_line}' if last_line else text)
    if is_plant:
        return ExitVerdict(False, True, 'the plant exited: stopping the nodes still running')
    return ExitVerdict(False, False, f'{name} exited')


def reason_line(lines: list[str]) -> str:
    """The line that says why a node exited: its last error line (``[ERROR]``, ``error:``,
    ``[FATAL]``), else its last non-empty line ('' if none)."""
    lines = [x.strip() for x in lines if x.strip()]
    errors = [x for x in lines if '[ERROR]' in x or '[FATAL]' in x or 'error:' in x]
    return (errors or lines or [''])[-1]
