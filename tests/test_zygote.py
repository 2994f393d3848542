"""The fork server of the graph tests' nodes (tests/zygote.py): a forked node is a process of
its own, as the executable started by ``ros2 run`` is: its pid and session, the environment,
directory and arguments it was given, its output, its exit code and its signals."""

from __future__ import annotations

import os
import signal
import subprocess

import pytest

import rosproc
import zygote

pytestmark = pytest.mark.graph


def test_a_forked_node_is_its_own_process_with_its_environment_output_and_exit_code(tmp_path):
    log = tmp_path / 'plant.log'
    env = rosproc.ros_env(FOHSSV_FAULT_REFUSE_STATE='x')   # read by the plant at its start
    proc = rosproc.start('fohssv_sim', 'plant', ['--ros-args', '-p', 'duration:=0.01'],
                         env=env, log=log)
    assert isinstance(proc, zygote.Forked)
    assert rosproc.wait_exit(proc, 60) == 2, log.read_text()   # invalid settings at start
    text = log.read_text()
    assert "FOHSSV_FAULT_REFUSE_STATE='x': expected N or N:M" in text, text
    assert proc.poll() == 2 and proc.returncode == 2   # kept once read


def test_a_signal_ends_a_forked_node_cleanly_and_its_pipe_has_its_output():
    proc = rosproc.start('fohssv_sim', 'plant', ['--ros-args', '-p', 'start_timeout:=60.0'],
                         env=rosproc.ros_env())
    assert isinstance(proc, zygote.Forked)
    first = proc.stdout.readline()             # the plant's first line: it runs
    assert os.getsid(proc.pid) == proc.pid     # its own session, as start_new_session gives
    with pytest.raises(subprocess.TimeoutExpired):
        proc.wait(0.1)
    assert rosproc.stop(proc, signal.SIGINT) == 0
    assert '[plant]' in first and 'waiting for' in first + proc.stdout.read()


def test_an_environment_that_starts_python_differently_runs_the_executable(tmp_path):
    env = rosproc.ros_env(PYTHONHASHSEED='7')
    proc = rosproc.start('fohssv_sim', 'plant', ['--ros-args', '-p', 'duration:=-1.0'],
                         env=env, log=tmp_path / 'plant.log')
    assert isinstance(proc, subprocess.Popen)
    assert rosproc.wait_exit(proc, 60) == 2
    plain = rosproc.start('fohssv_sim', 'plant', ['--ros-args', '-p', 'duration:=-1.0'],
                          env=rosproc.ros_env(), log=tmp_path / 'again.log', fork=False)
    assert isinstance(plain, subprocess.Popen) and rosproc.wait_exit(plain, 60) == 2
