"""A run recorded by the real recorder from the real plant and controller (three processes over
DDS): the bag holds the batch runner's trajectory sample for sample, and `fohssv plot` on it
summarises what an independent in-process run gives."""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
from ament_index_python.packages import get_package_prefix
from test_graph_support import batch_samples, finish, plant_args, stop_all

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.bag import load_run
from fohssv_sim.bag.check import check

import rosproc

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'
DURATION = 0.3


def test_recorded_closed_loop_equals_batch_run_and_plots(tmp_path):
    env = rosproc.ros_env()
    bag = tmp_path / 'run'
    log = tmp_path / 'recorder.log'
    rec = rosproc.start('fohssv_sim', 'recorder', ['--ros-args', '-p', f'bag_path:={bag}',
                                                   '-p', 'command_publishers:=1'],
                        env=env, log=log)
    ctl = plant = None
    try:
        rosproc.wait_for(lambda: 'recording to' in log.read_text(), 60, what='the recorder')
        ctl = rosproc.start('fohssv_controller', 'state_feedback',
                            ['--ros-args', '-p', 'min_command_subscribers:=2'], env=env)
        plant = rosproc.start('fohssv_sim', 'plant', plant_args(
            model='delay-free', mode='lockstep', duration=DURATION,
            min_state_subscribers=2, pace_to_subscribers=512), env=env)
        code, out = finish(plant, 120)
        assert code == 0, out
        time.sleep(0.5)   # the recorder's last flush period
        rec.send_signal(signal.SIGINT)
        assert rec.wait(timeout=30) == 0, log.read_text()
    finally:
        stop_all(*(p for p in (plant, ctl, rec) if p is not None))

    ref, fref = batch_samples('delay-free', StateFeedback(), DURATION)
    run = load_run(bag)
    assert not run.truncated
    assert np.array_equal(run.t, ref[:, 0])                    # exact simulation times
    assert np.max(np.abs(run.state - ref[:, 1:])) <= 1e-12      # sample for sample
    assert np.array_equal(run.planing_force_t, fref[:, 0])
    assert np.array_equal(run.command_t[:len(ref) - 1], ref[:-1, 0])   # every command
    assert np.array_equal(run.log_time['state'], np.round(ref[:, 0] * 1e9).astype(np.int64))
    assert run.parameters['model'] == 'delay-free' and run.parameters['control_period'] == 1e-4
    assert check(bag).ok

    out = subprocess.run([str(FOHSSV), 'plot', str(bag), '--out', str(tmp_path / 'fig')],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    s = json.loads((tmp_path / 'fig' / 'run_summary.json').read_text())[str(bag)]
    half = ref[:, 0] >= DURATION / 2
    assert s['samples'] == len(ref)
    assert abs(s['w_peak_to_peak'] - np.ptp(ref[half, 2])) <= 1e-12
    assert abs(s['peak_abs_planing_force'] - np.abs(fref[:, 1]).max()) <= 1e-9
    assert (tmp_path / 'fig' / 'run_time.png').stat().st_size > 10_000
