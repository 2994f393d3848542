"""The closed loop of ``make demo`` and of ``ros2 launch fohssv_sim closed_loop.launch.py``: one
list of nodes with their parameters, read by both (``scripts/demo.py`` turns it into
command lines, the launch file into ``launch_ros`` nodes; ``tests/test_launch.py`` checks both
against the installed executables and their declared parameters).

Three processes: the plant (FOM, alpha = 0.85, V = 75 m/s, x(0) = 0, lockstep, 2 s of simulated
time by default), a controller node hosting the law named by ``controller`` (default eq. 31)
and the recorder. The settings that make the bag complete (docs/recording.md, "The first
commands of a run"): the recorder subscribes to ``state`` only once it hears a controller
(``command_publishers: 1``), the plant waits for two ``state`` subscribers (the controller and
the recorder: ``min_state_subscribers: 2``), and the controller holds its commands until the
plant and the recorder both listen (``min_command_subscribers: 2``); the recorder, slower than
the lockstep loop, paces it (``pace_to_subscribers: 512``). On request (the launch's
``viewer:=true``, ``scripts/demo.py --viewer``) a fourth node, :func:`viewer`, serves the
run to Foxglove; it reads only the typed views, so the loop's start rules do not change.

Pure: no rclpy, no launch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ['NodeSpec', 'closed_loop', 'viewer', 'DEMO_PLANT', 'DEFAULT_CONTROLLER',
           'DEFAULT_DURATION', 'DEFAULT_VIEWER_PORT', 'ros_args']

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


def closed_loop(controller: Any = DEFAULT_CONTROLLER, duration: Any = DEFAULT_DURATION,
                bag_path: Any = '', plant: dict[str, Any] | None = None
                ) -> tuple[NodeSpec, NodeSpec, NodeSpec]:
    """The plant, the controller and the recorder of the closed loop.

    Args:
        controller: the ``controller`` parameter of the generic controller node (a plugin
            name of the group ``fohssv.controllers``).
        duration: simulated seconds the plant runs before it exits 0.
        bag_path: the recorder's ``bag_path`` ('' = ``runs/<UTC time>``).
        plant: plant parameters replacing :data:`DEMO_PLANT` entries (e.g. another model).
    """
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


def viewer(port: Any = DEFAULT_VIEWER_PORT) -> NodeSpec:
    """The Foxglove viewer (``ros2 run fohssv_sim viewer``) on ws://127.0.0.1:``port``."""
    return NodeSpec('fohssv_sim', 'viewer', 'viewer', {'port': port})


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
