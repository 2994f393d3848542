"""Your own controller as a package (docs/controllers.md; issue 50 item 4), the ROS way.

The package is made from the page's own template (its files as the page shows them, the
controller module being the README's example), built with the page's colcon command in a
workspace of its own, and its overlay sourced as the page says. Then, as a user would: the
generic node's unknown-controller message lists the new law, the generic node started by name
(what ``ros2 run fohssv_controller controller`` resolves) closes the loop with a plant, and the
plant hosts it. Both runs must give the in-process batch run of the same class to 1e-12.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_graph_support import batch_samples, finish, stop_all

from fohssv_sim.bag import load_run

import rosproc

ROOT = Path(__file__).resolve().parents[1]
PAGE = (ROOT / 'docs' / 'controllers.md').read_text()
EXAMPLES = ROOT / 'tests' / 'examples'
DURATION = 0.05


def template_files() -> dict[str, str]:
    """path inside the package folder -> content, as docs/controllers.md gives them."""
    files = {}
    for path, rest in re.findall(r'^\*\*`my_controllers/([^`]+)`\*\*(.*?)(?=^\*\*`|^Build)',
                                 PAGE, re.S | re.M):
        block = re.match(r'\s*```\w*\n(.*?)```', rest, re.S)
        if block:
            files[path] = block.group(1)
        elif 'an empty file' in rest:
            files[path] = ''
        elif "the README's example" in rest:
            files[path] = (EXAMPLES / 'pitch_damper.py').read_text()
    return files


def build_block() -> str:
    return next(b for b in re.findall(r'```bash\n(.*?)```', PAGE, re.S) if 'colcon build' in b)


def test_the_template_is_a_package_with_the_readme_example():
    files = template_files()
    assert set(files) == {'package.xml', 'setup.py', 'resource/my_controllers',
                          'my_controllers/__init__.py', 'my_controllers/pitch_damper.py'}
    assert "'fohssv.controllers': ['pitch_damper = my_controllers.pitch_damper:PitchDamper']" \
        in files['setup.py']


def _overlay(tmp_path: Path, domain: int) -> dict[str, str]:
    """The package built as the page says, in tmp_path/ros2_ws; the environment after
    ``source install/setup.bash`` there."""
    ws = tmp_path / 'ros2_ws'
    for path, text in template_files().items():
        (ws / 'src' / 'my_controllers' / path).parent.mkdir(parents=True, exist_ok=True)
        (ws / 'src' / 'my_controllers' / path).write_text(text)
    block = build_block()
    colcon = next(ln.split('#')[0].strip() for ln in block.splitlines()
                  if ln.startswith('colcon build'))
    source = next(ln.split('#')[0].strip() for ln in block.splitlines()
                  if ln.startswith('source install/'))
    out = subprocess.run(['bash', '-c', f'{colcon} >&2 && {source} && env -0'], cwd=ws,
                         env=rosproc.ros_env(domain), capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    env = dict(item.split('=', 1) for item in out.stdout.split('\0') if '=' in item)
    assert str(ws / 'install') in env.get('AMENT_PREFIX_PATH', ''), env.get('AMENT_PREFIX_PATH')
    return env


@pytest.mark.graph
def test_the_package_built_with_colcon_is_listed_run_by_name_and_hosted(tmp_path):
    sys.path.insert(0, str(EXAMPLES))
    from pitch_damper import PitchDamper

    env = _overlay(tmp_path, rosproc.unique_domain_id())
    ref, _ = batch_samples('delay-free', PitchDamper(pitch_damping=0.9), DURATION)

    # the unknown-controller message lists it (the overlay is seen); the generic node by name
    # beside a plant, and the plant hosting it: started together, each in a domain of its own
    unknown = rosproc.start('fohssv_controller', 'controller',
                            ['--ros-args', '-p', 'controller:=nope'], env=env)
    external = dict(env, ROS_DOMAIN_ID=str(rosproc.unique_domain_id()))
    hosted = dict(env, ROS_DOMAIN_ID=str(rosproc.unique_domain_id()))
    plant = ['--ros-args', '-p', 'model:=delay-free', '-p', f'duration:={DURATION}']
    ctl = rosproc.start('fohssv_controller', 'controller', [
        '--ros-args', '-p', 'controller:=pitch_damper', '-p', 'pitch_damping:=0.9'],
        env=external)
    plants = [
        rosproc.start('fohssv_sim', 'plant', [*plant, '-p', f"record:={tmp_path / 'ext'}"],
                      env=external),
        rosproc.start('fohssv_sim', 'plant', [
            *plant, '-p', 'controller:=pitch_damper', '-p', 'controller.pitch_damping:=0.9',
            '-p', f"record:={tmp_path / 'hosted'}"], env=hosted)]
    try:
        code, out = finish(unknown, 60)
        assert code == 2 and re.search(r"unknown controller 'nope'; valid controllers .*"
                                       r'pitch_damper', out), out
        for proc in plants:
            code, out = finish(proc, 120)
            assert code == 0, out
    finally:
        stop_all(unknown, ctl, *plants)
    for bag in ('ext', 'hosted'):
        run = load_run(tmp_path / bag)
        states = np.column_stack([run.t, run.state])
        assert states.shape == ref.shape, bag
        assert np.max(np.abs(states - ref)) <= 1e-12, bag


@pytest.mark.graph
def test_the_pip_way_registers_the_controller_for_the_nodes(tmp_path):
    """The same package installed by pip (into a folder here, not into the shared venv): the
    registry the nodes read lists the law."""
    for path, text in template_files().items():
        (tmp_path / 'my_controllers' / path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / 'my_controllers' / path).write_text(text)
    subprocess.run([sys.executable, '-m', 'pip', 'install', '-q', '--no-deps',
                    '--no-build-isolation', '--target', str(tmp_path / 'site'),
                    str(tmp_path / 'my_controllers')], check=True, timeout=300)
    out = subprocess.run(
        [sys.executable, '-c', 'from fohssv_sim import control; print(control.available())'],
        env=rosproc.ros_env(PYTHONPATH=f"{tmp_path / 'site'}:{os.environ.get('PYTHONPATH', '')}"),
        capture_output=True, text=True, check=True, timeout=120).stdout
    assert 'pitch_damper' in out, out
