"""The closed loop of ``make demo`` for a full ROS 2 install (launch is not on PyPI, so this
file does not run in the project's venv): the plant (FOM, alpha = 0.85, V = 75 m/s,
x(0) = 0, lockstep) recording its own run (in-plant recording, ``record``), and a controller
node hosting the law named by the ``controller`` argument (default: eq. 31): the run
``make demo`` makes. With ``hosted:=true`` the plant hosts the law itself and there is no
controller node; with ``recorder:=node`` a recorder node records over DDS instead (and paces
the loop). The nodes and their parameters are :func:`fohssv_sim.closed_loop.closed_loop`, the
list ``scripts/demo.py`` starts too (made when the launch runs, from the arguments' values; a
value of the wrong kind, such as ``duration:=abc``, ends the launch with one line naming the
argument).

How it ends (:data:`fohssv_sim.closed_loop.EXIT_RULE`, the rule ``scripts/demo.py`` follows
too): when the plant exits 0 (``duration`` reached, its bag closed) everything shuts down;
when any node exits non-zero (a bad argument at start such as ``controller:=nope`` or a
``bag_path`` that exists, a lost message, a plant error) the launch logs that node's exit code
and last line, stops the others and exits 1.

    ros2 launch fohssv_sim closed_loop.launch.py controller:=lqr duration:=2.0 \\
        bag_path:=runs/launched [hosted:=true] [recorder:=node] [viewer:=true] \\
        [viewer_port:=8765] [viewer_rate:=30]

``viewer:=true`` also starts the Foxglove viewer (fohssv_sim.closed_loop.viewer()) on
ws://localhost:``viewer_port``; the plant then waits for its view readers
(min_view_subscribers:=1).
"""

from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    LogInfo,
    OpaqueFunction,
    RegisterEventHandler,
    Shutdown,
)
from launch.event_handlers import OnProcessExit, OnProcessIO
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from fohssv_sim.closed_loop import (
    DEFAULT_CONTROLLER,
    DEFAULT_DURATION,
    DEFAULT_VIEWER_PORT,
    closed_loop,
    exit_verdict,
    flag,
    reason_line,
    viewer,
    watched,
)

#: Launch arguments: the keyword arguments of closed_loop(), with default, type, meaning.
ARGUMENTS = {
    'controller': (DEFAULT_CONTROLLER, str, 'controller plugin (group fohssv.controllers): '
                   'state_feedback, lqr, ...; hosted by the controller node, or by the plant '
                   'with hosted:=true'),
    'duration': (str(DEFAULT_DURATION), float,
                 'simulated seconds the plant runs before it exits'),
    'bag_path': ('', str, 'the bag directory to create; empty = runs/<UTC time>'),
    'hosted': ('false', flag, 'true: the plant hosts the controller (no controller node, no '
               'DDS in the loop)'),
    'recorder': ('plant', str, "'plant': the plant records its own run (in-plant "
                 "recording, as make demo); 'node': a recorder node records over DDS"),
}
#: Launch arguments of the nodes started on request, with default, type, meaning.
OPTIONAL_ARGUMENTS = {
    'viewer': ('false', flag, 'true: also start the Foxglove viewer on '
               'ws://localhost:VIEWER_PORT (Open connection in Foxglove; layout '
               'docs/foxglove/fohssv_layout.json)'),
    'viewer_port': (str(DEFAULT_VIEWER_PORT), int, "the viewer's TCP port (0 = a free "
                    'port, logged)'),
    'viewer_rate': ('30.0', float, 'most views per wall-clock second the viewer sends'),
}

#: Key of ``last`` naming the first node that failed.
FAILED = '<failed>'


class NodeFailed(RuntimeError):
    """A node of the closed loop exited non-zero. Raised from the exit handler: launch then
    logs the message, shuts the other nodes down and returns 1 (an exception is the only way
    a launch file sets ``ros2 launch``'s exit status)."""


def _watch(name, last):
    """Keep the line that says why ``name`` would exit: its last error line, else its last
    line (:func:`fohssv_sim.closed_loop.reason_line`)."""
    def on_output(event):
        lines = [last.get(name, ''), *event.text.decode(errors='replace').splitlines()]
        last[name] = reason_line(lines)
    return on_output


def _on_exit(name, is_plant, last):
    def on_exit(event, context):
        verdict = exit_verdict(name, event.returncode, is_plant, last.get(name, ''))
        if last.get(FAILED) is not None:     # stopping after a failure: that one is the cause
            return [LogInfo(msg=f'{verdict.message} (stopped after {last[FAILED]} failed)')
                    ] if verdict.failed else None
        if verdict.failed:
            last[FAILED] = name
            raise NodeFailed(verdict.message)
        if verdict.ends_run:
            return [LogInfo(msg=verdict.message), Shutdown(reason=verdict.message)]
        return None
    return on_exit


def _value(context, name, table):
    """The value of launch argument ``name`` as its kind, or one line naming it."""
    default, kind, text = table[name]
    given = LaunchConfiguration(name).perform(context)
    try:
        return kind(given)
    except ValueError:
        raise ValueError(f'launch argument {name}:={given!r} is not {KINDS[kind]} ({text}; '
                         f'default {default})') from None


#: What a launch argument of each kind must be, for the line that refuses one.
KINDS = {float: 'a number', int: 'an integer', str: 'text', flag: 'true or false'}


def _nodes(context):
    """The nodes (made from the arguments' values: hosted:=true has no controller node) and
    the handlers of the exit rule."""
    try:
        specs = closed_loop(**{name: _value(context, name, ARGUMENTS) for name in ARGUMENTS})
        if _value(context, 'viewer', OPTIONAL_ARGUMENTS):    # the plant waits for it
            specs = (*watched(specs), viewer(_value(context, 'viewer_port', OPTIONAL_ARGUMENTS),
                                             _value(context, 'viewer_rate', OPTIONAL_ARGUMENTS)))
    except ValueError as exc:
        raise NodeFailed(str(exc)) from None
    nodes = [Node(package=s.package, executable=s.executable, name=s.name, output='screen',
                  parameters=[s.parameters]) for s in specs]
    plant = nodes[0]
    last = {}           # node name -> the line saying why it would exit (its last error)
    handlers = []
    for spec, node in zip(specs, nodes):
        handlers += [
            RegisterEventHandler(OnProcessIO(target_action=node,
                                             on_stdout=_watch(spec.name, last),
                                             on_stderr=_watch(spec.name, last))),
            # every node's exit: the plant's exit 0 ends the run (the recorder closes the bag
            # completely on the SIGINT that launch sends at shutdown); any non-zero exit
            # ends the launch with that node's line and exit status 1
            RegisterEventHandler(OnProcessExit(target_action=node, on_exit=_on_exit(
                spec.name, node is plant, last))),
        ]
    return [*nodes, *handlers]


def generate_launch_description():
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, _, text) in {**ARGUMENTS, **OPTIONAL_ARGUMENTS}.items()),
        OpaqueFunction(function=_nodes),
    ])
