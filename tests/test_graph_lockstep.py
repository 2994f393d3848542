"""The closed loop through ROS (real processes over DDS) reproduces the in-process batch runner.

Plant and controller are the installed executables, each a process, on a domain of their own;
the test process records ``state`` and ``planing_force`` with a probe node. Lockstep with the
same zero-order-hold control period as ``simulate(..., control_period=...)`` must give the same
trajectory to 1e-12 (it is in fact bit-identical: the same doubles go through the same
operations in the same order). What needs the processes is here: the run over DDS between
two executables, SIGINT in the middle of a run, each process's threads pinned, the PM QoS
request held. (The reset service and every model under every law: tests/node.)
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from ament_index_python.packages import get_package_share_directory
from test_graph_support import Probe, batch_samples, plant_args, stop_all

from fohssv_controller.fractional_pid import FractionalPID
from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.ros.host import CPU_LATENCY_DEVICE, cpu_latency_limit

import rosproc

pytestmark = pytest.mark.graph

TOL = 1e-12
#: Simulated time of the lockstep run compared with the batch runner.
DURATION = 0.1


def _run(model: str, controller_exe: str, duration: float, controller_args=(), ctl_log=None,
         **plant_params) -> tuple[np.ndarray, np.ndarray, str, bool]:
    """The samples at the probe, the plant's output and whether the controller held the PM
    QoS device (once it answered the run: fully built)."""
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain)
    yaml_file = f"{get_package_share_directory('fohssv_sim')}/config/plant.yaml"
    ctl = rosproc.start('fohssv_controller', controller_exe, list(controller_args), env=env,
                        log=ctl_log)
    plant = rosproc.start('fohssv_sim', 'plant',
                          ['--ros-args', '--params-file', yaml_file] + plant_args(
                              model=model, duration=duration, min_state_subscribers=2,
                              end_linger=60.0, **plant_params)[1:], env=env)
    try:
        # the plant keeps its writers until stopped, so the probe may lag behind the run
        n = round(duration / 1e-4) + 1
        probe.wait(lambda: (len(probe.states) >= n and len(probe.forces) >= n)
                   or plant.poll() is not None, 90, f'{n} samples at the probe')
        ctl_held = _holds_latency_device(ctl.pid)
        out = stop_all(plant)
        assert plant.returncode == 0, out
        assert 'stopping cleanly at t=' in out, out
        assert len(probe.states) >= n and len(probe.forces) >= n, out
        return probe.state_array(), np.array(probe.forces), out, ctl_held
    finally:
        stop_all(plant, ctl)
        probe.close()


def test_lockstep_over_dds_reproduces_the_batch_runner(tmp_path):
    """The FOM plant (its params file, as ``ros2 run`` with ``--params-file`` gives it) and
    the PI^lambda D^mu node (its own executable, fractional integral and derivative terms
    active), each a process: every sample, in order, at the batch runner's times and equal to
    it. The FOM's samples but the first take the compiled sample (compiled_sample.py) and its
    commands are taken by rcl in compiled code (PlantNode.spin_taking), here from another
    process. (Every model under every built-in law, external and hosted, against the batch
    runner: tests/node/test_plant_hosted.py.) The controller node, given
    cpu_dma_latency:=-1, holds no PM QoS request and says nothing of one."""
    gains = {'integral_order': 0.85, 'derivative_order': 0.7, 'depth_ki': 2.0,
             'pitch_ki': -1.0, 'pitch_kd': -0.2}
    args = ['--ros-args', '-p', 'cpu_dma_latency:=-1'] + [
        a for k, v in gains.items() for a in ('-p', f'{k}:={v}')]
    duration = DURATION
    ctl_log = tmp_path / 'controller.log'
    states, forces, out, ctl_held = _run('fractional', 'fractional_pid', duration, args,
                                         ctl_log=ctl_log)
    assert not ctl_held and 'cpu_dma_latency' not in ctl_log.read_text()
    ref, fref = batch_samples('fractional', FractionalPID(**gains), duration)
    assert states.shape == ref.shape, out
    assert np.array_equal(states[:, 0], ref[:, 0])
    assert np.max(np.abs(states - ref)) <= TOL
    assert np.array_equal(forces[:, 0], fref[:, 0])
    assert np.max(np.abs(forces - fref)) <= TOL
    assert f'"samples": {len(ref) - 1}' in out
    assert f'"compiled_samples": {len(ref) - 2}' in out, out
    assert '"compiled_take": true' in out, out
    # the law's response differs from eq. 31's (the gains reached the node)
    eq31, _ = batch_samples('fractional', StateFeedback(), duration)
    assert np.max(np.abs(states[:, 1:] - eq31[:, 1:])) > 1e-6


def test_sigint_during_a_lockstep_run_stops_cleanly(tmp_path):
    """Issue 12, defect 12: SIGINT used to reach the plant while a command callback was
    publishing the next sample: rclpy shut the context down under it and the executor logged
    ``[FATAL] Exception in 'subscriptions' callback`` with a stack (in every run here, with the
    interpreted ABM solver keeping the plant in its callback most of the time). Two runs at
    once, each interrupted while it steps (half a second in: the ABM plant is in its callback
    nearly all the time from the start): exit 0, the summary, no FATAL and no traceback."""
    import signal
    import time

    runs = []
    for i in range(2):
        env = rosproc.ros_env()
        logs = (tmp_path / f'plant{i}.log', tmp_path / f'ctl{i}.log')
        ctl = rosproc.start('fohssv_controller', 'state_feedback', env=env, log=logs[1])
        plant = rosproc.start('fohssv_sim', 'plant', plant_args(
            model='fractional', solver='abm'), env=env, log=logs[0])
        runs.append((plant, ctl, logs))
    try:
        for _, _, logs in runs:
            rosproc.wait_for(lambda logs=logs: 'peers matched' in logs[0].read_text(), 60,
                             what='the run to start')
        time.sleep(0.5)
        for plant, _, _ in runs:
            plant.send_signal(signal.SIGINT)
        codes = [rosproc.wait_exit(plant, 30) for plant, _, _ in runs]
        for _, ctl, _ in runs:
            codes.append(rosproc.stop(ctl))
    finally:
        stop_all(*[p for run in runs for p in run[:2]])
    texts = [log.read_text() for _, _, logs in runs for log in logs]
    assert codes == [0] * 4, texts
    for text in texts:
        assert 'FATAL' not in text and 'Traceback' not in text, text
    for _, _, logs in runs:
        assert 'interrupted; stopping cleanly. summary:' in logs[0].read_text()


def _cpus_allowed(pid: int) -> dict[int, str]:
    """Each thread of a process and the CPUs it may run on (``Cpus_allowed_list``)."""
    out = {}
    for tid in os.listdir(f'/proc/{pid}/task'):
        try:
            with open(f'/proc/{pid}/task/{tid}/status') as f:
                out[int(tid)] = next(ln.split(':', 1)[1].strip() for ln in f
                                     if ln.startswith('Cpus_allowed_list:'))
        except (FileNotFoundError, ProcessLookupError):   # a thread that ended meanwhile
            continue
    return out


def test_cpu_affinity_pins_every_thread_and_the_run_is_unchanged(tmp_path):
    """cpu_affinity on the plant and the controller node: every thread of each process (DDS's
    included, and those started after the pin, at matching) runs only on its CPU while the
    lockstep run gives the batch runner's samples; the plant's summary names its CPUs. Both
    also ask for a CPU wake-up latency (cpu_dma_latency 7 us on the plant, 5 on the
    controller node): while the run waits and runs each holds the kernel's PM QoS device open
    and the kernel's system-wide limit is at most 7 us (the least of the requests held; other
    tests' nodes may hold 0); the plant's summary says 7. Where this process may not write
    the device (not root), each says in one line that it could not and runs on."""
    permitted = _may_hold_latency()
    usable = sorted(os.sched_getaffinity(0))
    # one usable CPU: both pinned to it (the pins change nothing there; the latency checks run)
    plant_cpu, ctl_cpu = usable[-1], usable[0]
    duration = 0.1
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    probe = Probe(domain)
    plant_log, ctl_log = tmp_path / 'plant.log', tmp_path / 'controller.log'
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(
        model='fractional', duration=duration, min_state_subscribers=2, end_linger=60.0,
        cpu_affinity=plant_cpu, cpu_dma_latency=7), env=env, log=plant_log)
    ctl = None
    try:
        rosproc.wait_for(lambda: 'cpu_affinity: ' in plant_log.read_text()
                         and 'cpu_dma_latency: ' in plant_log.read_text(), 60,
                         what="the plant's pin and latency request")
        # the plant waits for its controller meanwhile: its request is held before the run
        held = _holds_latency_device(plant.pid)
        limit = cpu_latency_limit()
        # and holds a CPU wake-up latency limit (the controller node's hold, checked below)
        ctl = rosproc.start('fohssv_controller', 'state_feedback',
                            ['--ros-args', '-p', f'cpu_affinity:={ctl_cpu}', '-p',
                             'cpu_dma_latency:=5'], env=env, log=ctl_log)
        rosproc.wait_for(lambda: 'cpu_affinity: ' in ctl_log.read_text(), 60,
                         what="the controller's pin")
        n = round(duration / 1e-4) + 1
        probe.wait(lambda: (len(probe.states) >= n and len(probe.forces) >= n)
                   or plant.poll() is not None, 90, f'{n} samples at the probe')
        threads = {'plant': _cpus_allowed(plant.pid), 'controller': _cpus_allowed(ctl.pid)}
        ctl_holds = _holds_latency_device(ctl.pid)
        out = stop_all(plant) + plant_log.read_text()
        assert plant.returncode == 0 and 'stopping cleanly at t=' in out, out
    finally:
        stop_all(plant, ctl)
        probe.close()
    for name, cpu in (('plant', plant_cpu), ('controller', ctl_cpu)):
        cpus = threads[name]
        assert len(cpus) >= 5 and set(cpus.values()) == {str(cpu)}, (name, cpus)
    assert f'threads run on CPU {plant_cpu}' in plant_log.read_text()
    assert f'threads run on CPU {ctl_cpu}' in ctl_log.read_text()
    text = plant_log.read_text()
    summary = rosproc.summary(text)
    if permitted:
        assert ctl_holds and 'CPU wake-up latency at most 5 us' in ctl_log.read_text()
        assert held and limit is not None and 0 <= limit <= 7, (held, limit)
        assert 'CPU wake-up latency at most 7 us while this process runs' in text, text
        assert summary['cpu_dma_latency'] == 7
    else:
        assert not ctl_holds and 'cpu_dma_latency: 5 us not requested' in ctl_log.read_text()
        assert not held and summary['cpu_dma_latency'] is None
        assert 'cpu_dma_latency: 7 us not requested: /dev/cpu_dma_latency' in text, text
    assert summary['cpu_affinity'] == [plant_cpu]
    ref, fref = batch_samples('fractional', StateFeedback(), duration)
    states, forces = probe.state_array(), np.array(probe.forces)
    assert states.shape == ref.shape
    assert np.max(np.abs(states - ref)) <= TOL and np.max(np.abs(forces - fref)) <= TOL


def _may_hold_latency() -> bool:
    """Whether a process of this user may open the PM QoS device for writing, as the nodes do
    (opening it adds a request at the default, no limit, until it is closed)."""
    try:
        os.close(os.open(CPU_LATENCY_DEVICE, os.O_WRONLY))
    except OSError:
        return False
    return True


def _holds_latency_device(pid: int) -> bool:
    """Whether the process has the PM QoS device open (its request is held while it is)."""
    for fd in os.listdir(f'/proc/{pid}/fd'):
        try:
            if os.readlink(f'/proc/{pid}/fd/{fd}') == CPU_LATENCY_DEVICE:
                return True
        except OSError:            # closed meanwhile
            continue
    return False
