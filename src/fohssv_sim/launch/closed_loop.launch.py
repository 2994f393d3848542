"""The closed loop of ``make demo`` for a full ROS 2 install (launch is not on PyPI, so this
file does not run in the project's venv): the plant (FOM, alpha = 0.85, V = 75 m/s,
x(0) = 0) in lockstep for 2 s of simulated time, and a controller node hosting the law named by
the ``controller`` argument (default: eq. 31).

    ros2 launch fohssv_sim closed_loop.launch.py controller:=lqr duration:=2.0
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    plant_yaml = os.path.join(get_package_share_directory('fohssv_sim'), 'config',
                              'plant.yaml')
    return LaunchDescription([
        DeclareLaunchArgument('controller', default_value='state_feedback'),
        DeclareLaunchArgument('duration', default_value='2.0'),
        Node(package='fohssv_sim', executable='plant', name='plant', output='screen',
             parameters=[plant_yaml, {'model': 'fractional', 'fractional_order': 0.85,
                                      'speed': 75.0, 'mode': 'lockstep',
                                      'initial_state': [0.0, 0.0, 0.0, 0.0],
                                      'duration': LaunchConfiguration('duration')}]),
        Node(package='fohssv_controller', executable='controller', name='controller',
             output='screen',
             parameters=[{'controller': LaunchConfiguration('controller')}]),
    ])
