"""``make demo``: the main job, the closed loop through ROS 2 over DDS.

Starts the plant (FOM, alpha = 0.85, V = 75 m/s, x(0) = 0, lockstep, 2 s of simulated time)
and the eq. 31 state-feedback controller as two separate processes on a ROS domain of their
own, records every ``state`` and ``planing_force`` sample with a subscriber in this process,
and prints a summary computed from the samples it received: dominant frequency and amplitude
of w, peak |Fp|, samples and integration steps, wall time, with the control period and step.

    python scripts/demo.py [--model fractional] [--duration 2.0] [--controller state_feedback]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import rclpy
from ament_index_python.packages import get_package_prefix
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64MultiArray

from fohssv_sim.contract import PLANING_FORCE, STATE
from fohssv_sim.ros.qos import profile


def _exe(package: str, name: str) -> str:
    return os.path.join(get_package_prefix(package), 'lib', package, name)


def dominant_frequency(t: np.ndarray, x: np.ndarray, pad: int = 16) -> float:
    """Frequency (Hz) of the largest peak of the Hann-windowed, zero-padded spectrum."""
    x = x - x.mean()
    n = len(x)
    spec = np.abs(np.fft.rfft(x * np.hanning(n), n * pad))
    freqs = np.fft.rfftfreq(n * pad, d=float(t[1] - t[0]))
    spec[0] = 0.0
    return float(freqs[int(np.argmax(spec))])


class Recorder:
    """Records state and planing_force in a background thread."""

    def __init__(self, domain: int) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('demo_recorder', context=self.context)
        self.states: list[tuple] = []
        self.forces: list[tuple] = []
        self.node.create_subscription(Float64MultiArray, STATE.name,
                                      lambda m: self.states.append(tuple(m.data)),
                                      profile(STATE))
        self.node.create_subscription(Float64MultiArray, PLANING_FORCE.name,
                                      lambda m: self.forces.append(tuple(m.data)),
                                      profile(PLANING_FORCE))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = False
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--model', default='fractional')
    ap.add_argument('--alpha', type=float, default=0.85)
    ap.add_argument('--speed', type=float, default=75.0)
    ap.add_argument('--duration', type=float, default=2.0)
    ap.add_argument('--controller', default='state_feedback')
    ap.add_argument('--timeout', type=float, default=600.0, help='wall-clock limit (s)')
    args = ap.parse_args()

    domain = int(os.environ.get('FOHSSV_DEMO_DOMAIN', 1 + os.getpid() % 200))
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    plant_cmd = [_exe('fohssv_sim', 'plant'), '--ros-args',
                 '-p', f'model:={args.model}', '-p', f'fractional_order:={args.alpha}',
                 '-p', f'speed:={args.speed}', '-p', 'mode:=lockstep',
                 '-p', f'duration:={args.duration}', '-p', 'initial_state:=[0.0,0.0,0.0,0.0]',
                 '-p', 'min_state_subscribers:=2']
    ctl_cmd = [_exe('fohssv_controller', 'controller'), '--ros-args',
               '-p', f'controller:={args.controller}']
    print(f'demo: plant ({args.model}, alpha={args.alpha:g}, V={args.speed:g} m/s, x(0)=0, '
          f'lockstep, {args.duration:g} s) and controller {args.controller!r} as two '
          f'processes, ROS_DOMAIN_ID={domain}', flush=True)
    recorder = Recorder(domain)
    wall0 = time.monotonic()
    ctl = subprocess.Popen(ctl_cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True, start_new_session=True)
    plant = subprocess.Popen(plant_cmd, env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, start_new_session=True)
    plant_out: list[str] = []

    def pump() -> None:
        for line in plant.stdout:
            plant_out.append(line)
            print('  plant: ' + line.rstrip(), flush=True)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        code = plant.wait(timeout=args.timeout)
    except subprocess.TimeoutExpired:
        plant.send_signal(signal.SIGINT)
        code = plant.wait(timeout=10)
        print(f'demo: the plant did not finish within {args.timeout:g} s', file=sys.stderr)
    finally:
        wall = time.monotonic() - wall0
        reader.join(timeout=5)
        ctl.send_signal(signal.SIGINT)
        try:
            ctl.wait(timeout=10)
        except subprocess.TimeoutExpired:
            ctl.kill()
        expected = round(args.duration / 1e-4) + 1
        deadline = time.monotonic() + 5
        while len(recorder.states) < expected and time.monotonic() < deadline:
            time.sleep(0.05)
        recorder.close()
    if code != 0:
        print(f'demo: plant exited with code {code}', file=sys.stderr)
        print(ctl.stdout.read(), file=sys.stderr)
        return 1

    summary = {}
    for line in plant_out:
        if 'summary: {' in line:
            summary = json.loads(line.split('summary: ', 1)[1])
    states = np.array(recorder.states)
    forces = np.array(recorder.forces)
    t, w = states[:, 0], states[:, 2]
    half = t >= t[-1] / 2
    freq = dominant_frequency(t[half], w[half])
    amp = 0.5 * (w[half].max() - w[half].min())
    print()
    print(f'closed loop through ROS 2: {args.model}, alpha={args.alpha:g}, V={args.speed:g} '
          f'm/s, controller {args.controller}')
    print(f'  integration step        {summary.get("step", float("nan")):g} s '
          f'({summary.get("solver", "?")})')
    print(f'  control period (ZOH)    {summary.get("control_period", float("nan")):g} s')
    print(f'  samples received        {len(states)} states, {len(forces)} forces '
          f'(t = {t[0]:g} .. {t[-1]:g} s)')
    print(f'  integration steps       {summary.get("steps", "?")}')
    print(f'  w, last half [{t[half][0]:g}, {t[-1]:g}] s: dominant frequency {freq:.1f} Hz, '
          f'amplitude {amp:.4g} m/s (half peak-to-peak), mean {w[half].mean():.4g} m/s')
    print(f'  peak |Fp|               {np.abs(forces[:, 1]).max():.4g} m^2/s^2')
    print(f'  wall time               {wall:.1f} s (plant loop {summary.get("wall_time", 0):.1f}'
          f' s, {summary.get("samples_per_second", 0):.0f} samples/s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
