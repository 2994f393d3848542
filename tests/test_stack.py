"""The foundation: the environment script, the colcon install, the Docker recipe.

These check what `ros2 run fohssv_sim plant` resolves on a full ROS install and what a new
user's shell gets from `source env.sh`; they use the real build, nothing stubbed.
"""

import os
import re
import subprocess
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix, get_package_share_directory

ROOT = Path(__file__).resolve().parents[1]

EXECUTABLES = {
    'fohssv_sim': ['plant', 'recorder', 'player', 'viewer', 'fohssv'],
    'fohssv_controller': ['controller', 'state_feedback', 'lqr', 'fractional_pid'],
}


def declared_scripts(package):
    text = (ROOT / 'src' / package / 'setup.py').read_text()
    block = text.split("'console_scripts': [", 1)[1].split(']', 1)[0]
    return sorted(re.findall(r"'(\w+) = ", block))


@pytest.mark.parametrize('package', sorted(EXECUTABLES))
def test_ament_index_resolves_the_installed_executables(package):
    prefix = Path(get_package_prefix(package))
    assert prefix == ROOT / 'ros2_ws' / 'install' / package
    assert declared_scripts(package) == sorted(EXECUTABLES[package])
    for exe in EXECUTABLES[package]:
        path = prefix / 'lib' / package / exe   # what `ros2 run <package> <exe>` runs
        assert path.is_file() and os.access(path, os.X_OK), path
        assert path.read_text().startswith(f'#!{ROOT}/.venv/bin/python')
    share = Path(get_package_share_directory(package))
    assert (share / 'package.xml').is_file()


def test_package_manifests_are_format_3_with_real_dependencies():
    for package in EXECUTABLES:
        xml = (ROOT / 'src' / package / 'package.xml').read_text()
        assert '<package format="3">' in xml and '<build_type>ament_python</build_type>' in xml
        for dep in ('rclpy', 'std_msgs', 'geometry_msgs', 'rosgraph_msgs'):
            assert f'<exec_depend>{dep}</exec_depend>' in xml
        assert (ROOT / 'src' / package / 'resource' / package).is_file()


@pytest.mark.graph     # a new shell and interpreter: a process
def test_env_script_gives_a_clean_shell_rclpy_and_the_overlay():
    clean = {'PATH': '/usr/local/bin:/usr/bin:/bin', 'HOME': os.environ.get('HOME', '/root')}
    script = ('cd / && set -u && source "$0/env.sh" && '
              'python -c "import rclpy, std_msgs.msg, rosgraph_msgs.msg, fohssv_sim.params" && '
              'python -c "from ament_index_python.packages import get_package_prefix as g; '
              'print(g(\'fohssv_sim\')); print(g(\'std_msgs\'))" && '
              'echo "$ROS_AUTOMATIC_DISCOVERY_RANGE"')
    out = subprocess.run(['bash', '-c', script, str(ROOT)], env=clean, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.split()
    assert lines[0] == str(ROOT / 'ros2_ws' / 'install' / 'fohssv_sim')
    assert lines[1] == str(ROOT / '.venv')
    # with the loopback profile env.sh applies, SUBNET (as the nodes hand it to rcl): see
    # test_graph_transport for the sockets of a process started after it
    assert lines[2] == 'SUBNET'


def test_dockerfile_names_only_files_that_exist_and_pins_like_requirements():
    dockerfile = (ROOT / 'docker' / 'Dockerfile').read_text()
    assert re.search(r'^ARG ROS_DISTRO=jazzy$', dockerfile, re.M)
    assert re.search(r'^FROM ros:\$\{ROS_DISTRO\}$', dockerfile, re.M)
    for src in re.findall(r'^COPY (\S+) ', dockerfile, re.M):
        assert (ROOT / src).exists(), f'Dockerfile copies missing {src}'
    entry = ROOT / 'docker' / 'entrypoint.sh'
    assert os.access(entry, os.X_OK)
    assert '/fohssv/ros2_ws/install/setup.bash' in entry.read_text()
    # direct pins as in requirements.txt, the others (llvmlite for numba) as in constraints.txt
    pins = {}
    for name in ('constraints.txt', 'requirements.txt'):
        pins.update(line.split('==') for line in (ROOT / name).read_text().split()
                    if '==' in line)
    docker = dict(line.split('==') for line in (ROOT / 'docker' / 'requirements-docker.txt')
                  .read_text().splitlines() if '==' in line and not line.startswith('#'))
    for name, version in docker.items():
        assert pins[name] == version, f'{name} pinned differently for Docker'
    assert 'numba' in docker       # the plant's compiled stepping needs it


def test_colcon_defaults_point_at_the_sources():
    text = (ROOT / 'ros2_ws' / 'colcon_defaults.yaml').read_text()
    assert 'base-paths: ["../src"]' in text


@pytest.mark.graph     # the installed script: a process
def test_fohssv_console_script_is_on_the_venv_path_and_works_in_a_clean_shell():
    clean = {'PATH': '/usr/bin:/bin', 'HOME': os.environ.get('HOME', '/root')}
    out = subprocess.run([str(ROOT / '.venv' / 'bin' / 'fohssv'), '--help'], env=clean,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    for sub in ('stability', 'plot', 'sweep', 'report', 'repair'):
        assert sub in out.stdout
