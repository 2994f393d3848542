"""The closed loop of ``make demo`` for a full ROS 2 install (launch is not on PyPI, so this
file does not run in the project's venv): the plant (FOM, alpha = 0.85, V = 75 m/s,
x(0) = 0, lockstep), a controller node hosting the law named by the ``controller`` argument
(default: eq. 31) and the recorder, with the settings that make the bag complete; with
``hosted:=true`` the plant hosts the law itself and there is no controller node. The nodes and
their parameters are :func:`fohssv_sim.closed_loop.closed_loop`, the list ``scripts/demo.py``
starts too (made when the launch runs, from the arguments' values). When the plant exits
(``duration`` reached, or an error) everything shuts down and the recorder closes the bag.

    ros2 launch fohssv_sim closed_loop.launch.py controller:=lqr duration:=2.0 \\
        bag_path:=runs/launched [hosted:=true]
"""

from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    LogInfo,
    OpaqueFunction,
    RegisterEventHandler,
    Shutdown,
)
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from fohssv_sim.closed_loop import DEFAULT_CONTROLLER, DEFAULT_DURATION, closed_loop, flag

#: Launch arguments: the keyword arguments of closed_loop(), with default, type, meaning.
ARGUMENTS = {
    'controller': (DEFAULT_CONTROLLER, str, 'controller plugin (group fohssv.controllers): '
                   'state_feedback, lqr, ...; hosted by the controller node, or by the plant '
                   'with hosted:=true'),
    'duration': (str(DEFAULT_DURATION), float,
                 'simulated seconds the plant runs before it exits'),
    'bag_path': ('', str, "the recorder's bag directory; empty = runs/<UTC time>"),
    'hosted': ('false', flag, 'true: the plant hosts the controller (no controller node, no '
               'DDS in the loop)'),
}


def _nodes(context):
    specs = closed_loop(**{name: kind(LaunchConfiguration(name).perform(context))
                           for name, (_, kind, _) in ARGUMENTS.items()})
    nodes = [Node(package=s.package, executable=s.executable, name=s.name, output='screen',
                  parameters=[s.parameters]) for s in specs]
    plant = nodes[0]
    return [
        *nodes,
        # the run is over when the plant exits: stop the controller and close the bag (the
        # recorder closes it completely on the SIGINT that launch sends at shutdown)
        RegisterEventHandler(OnProcessExit(target_action=plant, on_exit=[
            LogInfo(msg='the plant exited: shutting down the controller and the recorder'),
            Shutdown(reason='the plant exited')])),
    ]


def generate_launch_description():
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, _, text) in ARGUMENTS.items()),
        OpaqueFunction(function=_nodes),
    ])
