"""The default closed loop (what ``ros2 launch fohssv_sim closed_loop.launch.py`` and
``make demo`` start: the plant recording its own run, and the controller node) under load:
two busy processes beside it, and every bag complete.

With ``launch`` and ``launch_ros`` importable (a full ROS 2 install, or the public sources on
``PYTHONPATH``) the launch file itself runs, as ``ros2 launch`` runs it; without them (the
project's venv: launch is not on PyPI) the same node list runs as processes, started as the
launch file starts them. ``make soak`` (CI runs it after ``make test``) runs ten.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fohssv_sim import closed_loop as cl
from fohssv_sim.bag import load_run
from fohssv_sim.bag.check import check

import rosproc

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / 'src' / 'fohssv_sim' / 'launch' / 'closed_loop.launch.py'
RUNS = int(os.environ.get('FOHSSV_LAUNCH_RUNS', '1'))
DURATION = 0.2
HAVE_LAUNCH = all(importlib.util.find_spec(m) for m in ('launch', 'launch_ros'))

#: The launch file run as ``ros2 launch`` runs it (LaunchService, arguments NAME:=VALUE).
_RUN_LAUNCH = '''
import sys
import launch
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
ls = launch.LaunchService(argv=sys.argv[2:])
ls.include_launch_description(IncludeLaunchDescription(
    PythonLaunchDescriptionSource(sys.argv[1]),
    launch_arguments=[tuple(a.split(':=', 1)) for a in sys.argv[2:]]))
sys.exit(ls.run())
'''


def _busy(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(n)]


def _run(bag: Path, env: dict[str, str], log: Path) -> int:
    if HAVE_LAUNCH:
        with open(log, 'w') as out:
            return subprocess.run([sys.executable, '-c', _RUN_LAUNCH, str(LAUNCH),
                                   f'duration:={DURATION}', f'bag_path:={bag}'], env=env,
                                  stdout=out, stderr=subprocess.STDOUT, timeout=600).returncode
    specs = cl.closed_loop(duration=DURATION, bag_path=str(bag))
    assert [s.executable for s in specs] == ['plant', 'controller']
    assert specs[0].parameters['record'] == str(bag)
    procs = [rosproc.start(s.package, s.executable, cl.ros_args(s), env=env,
                           log=log.with_suffix(f'.{s.name}.log')) for s in reversed(specs)]
    ctl, plant = procs
    try:
        code = rosproc.wait_exit(plant, 600)
    finally:
        rosproc.stop(ctl)
        rosproc.stop(plant)
    return code


@pytest.mark.graph
@pytest.mark.load
@pytest.mark.parametrize('run', range(RUNS))
def test_the_default_launch_under_load_records_every_message(tmp_path, run):
    bag = tmp_path / 'run'
    env = rosproc.ros_env(rosproc.unique_domain_id())
    busy = _busy(2)
    try:
        code = _run(bag, env, tmp_path / 'launch.log')
    finally:
        for p in busy:
            p.kill()
            p.wait()
    logs = ''.join(p.read_text() for p in tmp_path.glob('*.log'))
    assert code == 0, logs
    assert check(bag).ok
    r = load_run(bag)
    n = round(DURATION / 1e-4)
    assert not r.truncated and len(r.t) == n + 1, logs
    assert np.allclose(r.t, np.arange(n + 1) * 1e-4, rtol=0, atol=1e-12)    # every sample
    assert np.array_equal(r.command_t[:n], r.t[:n])              # every command
    assert r.parameters['model'] == 'fractional'


@pytest.mark.skipif(not HAVE_LAUNCH, reason='launch and launch_ros are not installed (not on '
                    'PyPI): PYTHONPATH to their public sources runs this')
def test_a_launch_argument_of_the_wrong_kind_is_named(tmp_path):
    out = subprocess.run([sys.executable, '-c', _RUN_LAUNCH, str(LAUNCH), 'duration:=abc',
                          f'bag_path:={tmp_path / "bag"}'], env=rosproc.ros_env(
                              rosproc.unique_domain_id()), capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 1
    assert ("launch argument duration:='abc' is not a number (simulated seconds the plant "
            'runs before it exits; default 2.0)') in out.stdout + out.stderr
    assert not (tmp_path / 'bag').exists()
