"""The real-time plant with a controller node, real processes over DDS: what needs the
plant's process (its scheduling policy, its linger before it exits). What the run reports, its
profile and the /clock decimation: tests/node/test_plant_realtime.py. Timing targets are not
asserted here (the machine is shared and noisy; `make bench` measures them).
"""

from __future__ import annotations

import os
import time

import pytest
from test_graph_support import plant_args, stop_all

import rosproc

pytestmark = pytest.mark.graph

#: Realtime closed-loop runs here last 0.1 s of simulated time: the vehicle cannot leave its
#: physical bounds within it even with no command at all (open loop it does at t = 0.26 s).
SHORT = 0.1


def _policy(pid: int) -> int:
    """The scheduling policy of a process's main thread (field 41 of /proc/PID/stat)."""
    with open(f'/proc/{pid}/stat') as f:
        return int(f.read().rsplit(')', 1)[1].split()[38])


def test_a_realtime_plant_under_sched_fifo_or_warning_lingers_while_subscribed(tmp_path):
    """realtime_priority:=10: while the run is paced the plant's thread is SCHED_FIFO (1) where
    permitted; elsewhere the plant says why and runs with the normal scheduler. end_linger:=2:
    after 'stopping cleanly' the plant keeps its publishers for 2 s while a controller still
    subscribes to state (so a lagging subscriber can take the tail)."""

    env = rosproc.ros_env(rosproc.unique_domain_id())
    log = tmp_path / 'plant.log'
    ctl = rosproc.start('fohssv_controller', 'state_feedback', env=env)
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model='delay-free', mode='realtime', control_period=1e-3, duration=SHORT,
        real_time_factor=0.03, realtime_priority=10, end_linger=2.0), env=env, log=log)
    policies: list[int] = []
    try:
        rosproc.wait_for(lambda: 'peers matched' in log.read_text(), 30, what='the run')
        deadline = time.monotonic() + 2.0
        while (time.monotonic() < deadline and plant.poll() is None
               and 'stopping cleanly' not in log.read_text()):
            policies.append(_policy(plant.pid))
            time.sleep(0.05)
        rosproc.wait_for(lambda: 'stopping cleanly' in log.read_text(), 60,
                         what='the end of the run', interval=0.005)
        ended = time.monotonic()
        code = rosproc.wait_exit(plant, 30)
        lingered = time.monotonic() - ended
        out = log.read_text()
        assert code == 0, out
    finally:
        stop_all(plant, ctl)
    if os.geteuid() == 0:
        assert 1 in policies and 'not permitted' not in out, (policies, out)
    else:
        assert 'running with the normal scheduler' in out, out
    assert 1.5 <= lingered <= 10.0, lingered
