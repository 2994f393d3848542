"""Benchmark of the ROS 2 graph: real processes over DDS on this machine.

* real time: plant in ``realtime`` mode (real_time_factor 1) with the eq. 31 controller node
  for 10 s of simulated time: achieved real-time factor and deadline-miss rate, at the default
  control period (1e-4 s) and at 1e-3 s, for the delay-free model and the FOM (with the 'soe'
  solver: the exact 'abm' costs O(n) per step and cannot run 10 s live);
* lockstep: samples (control periods) and integration steps per second of the lockstep loop.

    python bench/bench_ros.py --out bench/results/ros.json [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from ament_index_python.packages import get_package_prefix


def _exe(package: str, name: str) -> str:
    return os.path.join(get_package_prefix(package), 'lib', package, name)


def run(domain: int, plant_params: dict, timeout: float) -> dict:
    """One plant + eq. 31 controller run; returns the plant's summary."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    args = ['--ros-args']
    for k, v in plant_params.items():
        args += ['-p', f'{k}:={v}']
    ctl = subprocess.Popen([_exe('fohssv_controller', 'state_feedback')], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           start_new_session=True)
    try:
        out = subprocess.run([_exe('fohssv_sim', 'plant'), *args], env=env, timeout=timeout,
                             capture_output=True, text=True)
    finally:
        ctl.send_signal(2)
        try:
            ctl.wait(timeout=10)
        except subprocess.TimeoutExpired:
            ctl.kill()
    text = out.stdout + out.stderr
    lines = [ln for ln in text.splitlines() if 'summary: {' in ln]
    if out.returncode != 0 or not lines:
        raise RuntimeError(f'plant exited {out.returncode}:\n{text[-2000:]}')
    return json.loads(lines[-1].split('summary: ', 1)[1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench/results/ros.json'))
    ap.add_argument('--quick', action='store_true', help='1 s instead of 10 s of real time')
    a = ap.parse_args()
    sim_time = 1.0 if a.quick else 10.0
    domain = 1 + (os.getpid() * 11) % 200
    results = []
    cases = [('realtime', 'delay-free', 1e-4), ('realtime', 'delay-free', 1e-3),
             ('realtime', 'fractional', 1e-4), ('realtime', 'fractional', 1e-3),
             ('lockstep', 'delay-free', 1e-4), ('lockstep', 'fractional', 1e-4)]
    for mode, model, period in cases:
        duration = sim_time if mode == 'realtime' else (2.0 if model == 'delay-free' else 0.5)
        params = {'model': model, 'mode': mode, 'control_period': period,
                  'duration': duration, 'real_time_factor': 1.0}
        if model == 'fractional' and mode == 'realtime':
            params['solver'] = 'soe'   # O(1) per step; 'abm' is O(n) and cannot run 10 s live
        t0 = time.monotonic()
        s = run(domain, params, timeout=900.0)
        s['bench_wall'] = time.monotonic() - t0
        domain = 1 + (domain + 37) % 200
        results.append(s)
        print(f'{mode:9s} {model:11s} T={period:g} s: ' + (
            f"achieved RTF {s['achieved_real_time_factor']:.3f}, deadline misses "
            f"{s['deadline_misses']}/{s['samples_paced']} ({100 * s['deadline_miss_rate']:.1f} %)"
            f", slips {s['slips']}, max command lag {s['max_command_lag'] * 1e3:.2f} ms sim"
            if mode == 'realtime' else
            f"{s['samples_per_second']:.0f} samples/s, {s['steps_per_second']:.0f} steps/s "
            f"over {s['t']:g} s simulated"), flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({
        'benchmark': 'ros graph', 'machine': platform.platform(), 'cpus': os.cpu_count(),
        'python': sys.version.split()[0], 'simulated_time_realtime': sim_time,
        'results': results}, indent=2) + '\n')
    print(f'wrote {a.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
