"""The closed loop of ``make demo`` for a full ROS 2 install (launch is not on PyPI, so this
file does not run in the project's venv): the plant (FOM, alpha = 0.85, V = 75 m/s,
x(0) = 0, lockstep), a controller node hosting the law named by the ``controller`` argument
(default: eq. 31) and the recorder, with the settings that make the bag complete. The nodes and
their parameters are :func:`fohssv_sim.closed_loop.closed_loop`, the list ``scripts/demo.py``
starts too. When the plant exits (``duration`` reached, or an error) everything shuts down and
the recorder closes the bag.

    ros2 launch fohssv_sim closed_loop.launch.py controller:=lqr duration:=2.0 \\
        bag_path:=runs/launched [viewer:=true]

``viewer:=true`` also starts the Foxglove viewer (fohssv_sim.closed_loop.viewer()) on
ws://localhost:8765.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, LogInfo, RegisterEventHandler, Shutdown
from launch.conditions import IfCondition
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from fohssv_sim.closed_loop import DEFAULT_CONTROLLER, DEFAULT_DURATION, closed_loop, viewer

#: Launch arguments: the keyword arguments of closed_loop(), with default, type, meaning.
ARGUMENTS = {
    'controller': (DEFAULT_CONTROLLER, str, 'controller plugin hosted by the controller node '
                   '(group fohssv.controllers): state_feedback, lqr, ...'),
    'duration': (str(DEFAULT_DURATION), float,
                 'simulated seconds the plant runs before it exits'),
    'bag_path': ('', str, "the recorder's bag directory; empty = runs/<UTC time>"),
}
#: Launch arguments of the nodes started on request, with default, type, meaning.
OPTIONAL_ARGUMENTS = {
    'viewer': ('false', bool, 'true: also start the Foxglove viewer on ws://localhost:8765 '
               '(Open connection in Foxglove; layout docs/foxglove/fohssv_layout.json)'),
}


def generate_launch_description():
    specs = closed_loop(**{name: ParameterValue(LaunchConfiguration(name), value_type=kind)
                           for name, (_, kind, _) in ARGUMENTS.items()})
    # the viewer only with viewer:=true (it reads the views: the loop does not wait for it)
    optional = [(viewer(), IfCondition(LaunchConfiguration('viewer')))]
    nodes = [Node(package=s.package, executable=s.executable, name=s.name, output='screen',
                  parameters=[s.parameters], condition=condition)
             for s, condition in [*((s, None) for s in specs), *optional]]
    plant = nodes[0]
    return LaunchDescription([
        *(DeclareLaunchArgument(name, default_value=default, description=text)
          for name, (default, _, text) in {**ARGUMENTS, **OPTIONAL_ARGUMENTS}.items()),
        *nodes,
        # the run is over when the plant exits: stop the controller and close the bag (the
        # recorder closes it completely on the SIGINT that launch sends at shutdown)
        RegisterEventHandler(OnProcessExit(target_action=plant, on_exit=[
            LogInfo(msg='the plant exited: shutting down the controller and the recorder'),
            Shutdown(reason='the plant exited')])),
    ])
