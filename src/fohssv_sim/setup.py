from glob import glob

from setuptools import find_packages, setup

package_name = 'fohssv_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', sorted(glob('config/*.yaml'))
         + sorted(glob('config/*.xml'))),
        ('share/' + package_name + '/launch', sorted(glob('launch/*.launch.py'))),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='fohssv maintainers',
    description='FO-HSSV plant, recorder, player and analysis',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'plant = fohssv_sim.ros.entry:plant',
            'recorder = fohssv_sim.ros.entry:recorder',
            'player = fohssv_sim.ros.entry:player',
            'viewer = fohssv_sim.ros.entry:viewer',
            'fohssv = fohssv_sim.cli:main',
        ],
    },
)
