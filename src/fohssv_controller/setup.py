from glob import glob

from setuptools import find_packages, setup

package_name = 'fohssv_controller'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', sorted(glob('config/*.yaml'))),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='fohssv maintainers',
    description='Swappable controller nodes for the fohssv plant',
    license='Apache-2.0',
    entry_points={
        # Built-in controller laws, found by name by the generic controller node.
        # Third-party packages register theirs in the same group.
        'fohssv.controllers': [
            'state_feedback = fohssv_controller.state_feedback:StateFeedback',
            'lqr = fohssv_controller.lqr:LQR',
            'fractional_pid = fohssv_controller.fractional_pid:FractionalPID',
            'scheduled = fohssv_controller.scheduled:Scheduled',
        ],
        'console_scripts': [
            'controller = fohssv_controller.ros.entry:controller',
            'state_feedback = fohssv_controller.ros.entry:state_feedback',
            'lqr = fohssv_controller.ros.entry:lqr',
            'fractional_pid = fohssv_controller.ros.entry:fractional_pid',
        ],
    },
)
