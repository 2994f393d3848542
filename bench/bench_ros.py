"""Benchmark of the ROS 2 graph: real processes over DDS on this machine, the issue's targets.

Cases, all in one run (the machine is shared and noisy: compare within a run):

* echo: the bare DDS round trip, two processes echoing a ``std_msgs/Float64MultiArray`` with
  the executor and the QoS of the ``state``/``command`` topics (``bench/ros_echo.py``):
  round trips per second, the ceiling of any lockstep loop;
* lockstep: plant + eq. 31 controller node (``state_feedback``), FOM (default solver) and
  delay-free model at the default control period: samples per second, as a ratio to the echo;
  and the delay-free model with one step per sample (``control_period`` = ``step``,
  profiled): what the loop costs on top of the round trip when the integration is cheap;
* real time: plant in ``realtime`` mode (real_time_factor 1) + the controller node for 10 s of
  simulated time, for the delay-free, delayed and fractional (alpha 0.85, V 75, h 2e-5, 'soe')
  models at control periods 1e-4 s and 1e-3 s: achieved real-time factor and deadline misses
  (a sample published more than one pacing tick after it was due);
* profile: one short real-time run per model at 1e-4 s with the plant's ``profile:=1``: the
  plant's cost per sample of advance, each publish and the command callback (mean us);
* in-plant recording: the demo's lockstep FOM loop with the plant's ``record`` and without,
  alternately: recorded loop time (first sample to bag closed) / unrecorded.

Every plant run reports its process CPU time per sample (``cpu_per_sample_us``, all threads,
from the first sample to the last); the controller's over the same span is read from /proc
(10 ms resolution) when the plant starts and when it logs its summary. Prints a table of the targets
(measured, goal, pass/fail) and writes the figures to ``--out``.

    python bench/bench_ros.py --out bench/results/ros.json [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from ament_index_python.packages import get_package_prefix

HERE = Path(__file__).resolve().parent
MODELS = ('delay-free', 'delayed', 'fractional')
#: Model parameters of the real-time cases (the FOM of the issue: alpha 0.85, V 75, h 2e-5).
MODEL_PARAMS = {'delay-free': {}, 'delayed': {},
                'fractional': {'fractional_order': 0.85, 'speed': 75.0, 'step': 2e-5,
                               'solver': 'soe'}}


def _exe(package: str, name: str) -> str:
    return os.path.join(get_package_prefix(package), 'lib', package, name)


class Domains:
    """A fresh ROS_DOMAIN_ID per run (a run's late packets never reach the next one)."""

    def __init__(self) -> None:
        self.next = 1 + (os.getpid() * 11) % 200

    def env(self) -> dict[str, str]:
        self.next = 1 + (self.next + 37) % 200
        return dict(os.environ, ROS_DOMAIN_ID=str(self.next),
                    ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')


def _cpu_seconds(pid: int) -> float | None:
    """utime + stime of a running process (s), from /proc (Linux); None if unavailable."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return None


def _stop(proc: subprocess.Popen) -> str:
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out or ''


def run_plant(domains: Domains, plant_params: dict, timeout: float) -> dict:
    """One plant + eq. 31 controller run; returns the plant's summary, with the controller's
    CPU time per sample from the plant's start (peers matched) to its end."""
    env = domains.env()
    args = ['--ros-args']
    for k, v in plant_params.items():
        args += ['-p', f'{k}:={v}']
    ctl = subprocess.Popen([_exe('fohssv_controller', 'state_feedback')], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           start_new_session=True)
    lines: list[str] = []
    ctl_cpu: list[float | None] = []
    try:
        plant = subprocess.Popen([_exe('fohssv_sim', 'plant'), *args], env=env,
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 start_new_session=True)

        def pump() -> None:
            for line in plant.stdout:
                lines.append(line)
                if 'peers matched' in line:
                    ctl_cpu.append(_cpu_seconds(ctl.pid))
                elif 'summary: {' in line:
                    ctl_cpu.append(_cpu_seconds(ctl.pid))

        reader = threading.Thread(target=pump, daemon=True)
        reader.start()
        try:
            code = plant.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            plant.kill()
            code = plant.wait()
        reader.join(timeout=10)
    finally:
        _stop(ctl)
    text = ''.join(lines)
    found = [ln for ln in lines if 'summary: {' in ln]
    if code not in (0, 1) or not found:
        raise RuntimeError(f'plant exited {code}:\n{text[-2000:]}')
    s = json.loads(found[-1].split('summary: ', 1)[1])
    s['exit_code'] = code
    if code == 1:   # the run stopped: a diverged closed loop is a result, not a crash
        s['failure'] = next((ln.split(']: ', 1)[-1] for ln in lines if 'simulation failed'
                             in ln), 'exit 1')
        print(f"          (stopped at t={s['t']:g} s: {s['failure'][:160]})", flush=True)
    if len(ctl_cpu) == 2 and None not in ctl_cpu and s['samples']:
        s['controller_cpu_time'] = ctl_cpu[1] - ctl_cpu[0]
        s['controller_cpu_per_sample_us'] = s['controller_cpu_time'] / s['samples'] * 1e6
    return s


def run_echo(domains: Domains, count: int) -> dict:
    """The bare round-trip loop (bench/ros_echo.py) for ``count`` round trips."""
    env = domains.env()
    script = str(HERE / 'ros_echo.py')
    pong = subprocess.Popen([sys.executable, script, 'pong'], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out = subprocess.run([sys.executable, script, 'ping', '--count', str(count)],
                             env=env, timeout=300, capture_output=True, text=True)
    finally:
        _stop(pong)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith('{')]
    if out.returncode != 0 or not lines:
        raise RuntimeError(f'echo ping exited {out.returncode}:\n{out.stdout}{out.stderr}')
    return json.loads(lines[-1])


def _timed_loop(env: dict, plant_params: dict, timeout: float) -> tuple[float, dict]:
    """A lockstep plant + eq. 31 controller node: (wall seconds from the plant's first sample
    to its bag closed (with ``record``) or to its run's end, the plant's summary)."""
    args = ['--ros-args']
    for k, v in plant_params.items():
        args += ['-p', f'{k}:={v}']
    ctl = subprocess.Popen([_exe('fohssv_controller', 'state_feedback')], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT,
                           start_new_session=True)
    times: dict[str, float] = {}
    summary: dict = {}
    try:
        plant = subprocess.Popen([_exe('fohssv_sim', 'plant'), *args], env=env,
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 start_new_session=True)
        for line in plant.stdout:
            for key in ('starting at t = 0', 'summary: {', 'in-plant recording: closed'):
                if key in line:
                    times.setdefault(key, time.monotonic())
            if 'summary: {' in line:
                summary = json.loads(line.split('summary: ', 1)[1])
        code = plant.wait(timeout=timeout)
    finally:
        _stop(ctl)
    end = times.get('in-plant recording: closed', times.get('summary: {'))
    if code != 0 or end is None or 'starting at t = 0' not in times:
        raise RuntimeError(f'plant exited {code} ({sorted(times)})')
    return end - times['starting at t = 0'], summary


def run_inplant_recording(domains: Domains, quick: bool) -> dict:
    """In-plant recorded vs unrecorded: the demo's loop (FOM, lockstep, eq. 31 node),
    alternately with ``record`` and without, twice each; the ratio of the mean loop times
    (first sample to bag closed / to the run's end) and each plant's CPU per sample."""
    import tempfile

    params = {'model': 'fractional', 'fractional_order': 0.85, 'speed': 75.0,
              'mode': 'lockstep', 'duration': 0.5 if quick else 2.0}
    runs: dict[str, list] = {'recorded': [], 'unrecorded': []}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(2):
            for key in ('unrecorded', 'recorded'):
                extra = {'record': f'{tmp}/run{i}'} if key == 'recorded' else {}
                wall, s = _timed_loop(domains.env(), {**params, **extra}, timeout=900.0)
                runs[key].append({'loop_time': wall, 'cpu_per_sample_us': s['cpu_per_sample_us'],
                                  'record_waits': s.get('record_waits'),
                                  'record_lost': s.get('record_lost')})
    mean = {k: sum(r['loop_time'] for r in v) / len(v) for k, v in runs.items()}
    out = {'runs': runs, 'mean_loop_time': mean,
           'ratio': mean['recorded'] / mean['unrecorded'], 'duration': params['duration']}
    cpu = {k: sum(r['cpu_per_sample_us'] for r in v) / len(v) for k, v in runs.items()}
    print(f"record    in-plant recorded vs unrecorded lockstep FOM loop ({params['duration']:g} s"
          f" simulated, 2 runs each): {mean['recorded']:.2f} s / {mean['unrecorded']:.2f} s = "
          f"{out['ratio']:.2f}; plant CPU {cpu['recorded']:.0f} / {cpu['unrecorded']:.0f} "
          'us/sample', flush=True)
    return out


def _row(name: str, value: float, goal: str, ok: bool, fmt: str = '{:.3f}') -> dict:
    return {'target': name, 'measured': value, 'goal': goal, 'pass': bool(ok),
            'text': fmt.format(value)}


def _rt_priority_permitted() -> bool:
    """Whether this process could set SCHED_FIFO (root, or an rtprio limit)."""
    import resource

    if not hasattr(os, 'sched_setscheduler'):
        return False
    return os.geteuid() == 0 or resource.getrlimit(resource.RLIMIT_RTPRIO)[0] > 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=Path('bench/results/ros.json'))
    ap.add_argument('--quick', action='store_true',
                    help='1 s instead of 10 s of simulated real time, shorter loops')
    a = ap.parse_args()
    sim_time = 1.0 if a.quick else 10.0
    domains = Domains()
    started = time.monotonic()

    echo_count = 5000 if a.quick else 20000
    echo = run_echo(domains, echo_count)
    print(f"echo      bare DDS round trip: {echo['round_trips_per_second']:.0f} round trips/s "
          f"({1e6 / echo['round_trips_per_second']:.0f} us each, {echo['round_trips']})",
          flush=True)

    lockstep = {}
    # the product's cases (default solver and step), then the node-side cost alone: one RK4
    # step per sample (control_period = step), profiled
    for key, params in (
            ('fractional', {'model': 'fractional', 'duration': 0.2 if a.quick else 0.5}),
            ('delay-free', {'model': 'delay-free', 'duration': 0.5 if a.quick else 2.0}),
            ('delay-free, 1 step/sample', {'model': 'delay-free', 'control_period': 1e-5,
                                           'duration': 0.1 if a.quick else 0.3,
                                           'profile': 1})):
        s = run_plant(domains, {'mode': 'lockstep', **params}, timeout=900.0)
        rate = echo['round_trips_per_second']
        s['ratio_to_echo'] = s['samples_per_second'] / rate
        s['cost_over_round_trip_us'] = 1e6 / s['samples_per_second'] - 1e6 / rate
        lockstep[key] = s
        print(f"lockstep  {key:11s} T={s['control_period']:g} s: "
              f"{s['samples_per_second']:.0f} samples/s ({s['ratio_to_echo']:.2f} of the echo, "
              f"{s['cost_over_round_trip_us']:+.0f} us/sample over it), solver {s['solver']}, "
              f"plant CPU {s['cpu_per_sample_us']:.0f} us/sample over {s['t']:g} s simulated",
              flush=True)
        if 'profile' in s:
            print('          mean us per call: ' + ', '.join(
                f"{k} {v['mean_us']:.1f}" for k, v in s['profile'].items()), flush=True)

    realtime = []
    for model in MODELS:
        for period in (1e-4, 1e-3):
            params = {'model': model, 'mode': 'realtime', 'control_period': period,
                      'duration': sim_time, 'real_time_factor': 1.0, **MODEL_PARAMS[model]}
            s = run_plant(domains, params, timeout=900.0)
            realtime.append(s)
            print(f"realtime  {model:11s} T={period:g} s: achieved RTF "
                  f"{s['achieved_real_time_factor']:.3f}, deadline misses "
                  f"{s['deadline_misses']}/{s['samples_paced']} "
                  f"({100 * s['deadline_miss_rate']:.2f} %), slips {s['slips']}, plant CPU "
                  f"{s['cpu_per_sample_us']:.0f} us/sample, controller CPU "
                  f"{s.get('controller_cpu_per_sample_us', float('nan')):.0f} us/sample, worst "
                  f"lateness {1e3 * s['worst_lateness']:.1f} ms", flush=True)

    # the 1e-3 s runs with the plant's thread under SCHED_FIFO (realtime_priority), where the
    # machine permits it: how much of the misses are scheduling stalls of the process. (At
    # 1e-4 s a FIFO plant starved the controller process on 2 cores: its commands lagged by
    # milliseconds and the closed loop left the physical bounds.)
    fifo = []
    if _rt_priority_permitted():
        for model in MODELS:
            for period in (1e-3,):
                params = {'model': model, 'mode': 'realtime', 'control_period': period,
                          'duration': sim_time, 'real_time_factor': 1.0,
                          'realtime_priority': 50, **MODEL_PARAMS[model]}
                s = run_plant(domains, params, timeout=900.0)
                fifo.append(s)
                print(f"realtime  {model:11s} T={period:g} s, realtime_priority 50: achieved "
                      f"RTF {s['achieved_real_time_factor']:.3f}, deadline misses "
                      f"{s['deadline_misses']}/{s['samples_paced']} "
                      f"({100 * s['deadline_miss_rate']:.2f} %), worst lateness "
                      f"{1e3 * s['worst_lateness']:.1f} ms", flush=True)
    else:
        print('realtime  (SCHED_FIFO not permitted here: no realtime_priority runs)')

    profiles = {}
    for model in MODELS:
        params = {'model': model, 'mode': 'realtime', 'control_period': 1e-4,
                  'duration': 0.5 if a.quick else 2.0, 'profile': 1, **MODEL_PARAMS[model]}
        s = run_plant(domains, params, timeout=900.0)
        profiles[model] = s
        parts = ', '.join(f"{k} {v['mean_us']:.1f}" for k, v in s['profile'].items())
        print(f"profile   {model:11s} T=1e-4 s realtime, mean us per call: {parts}; "
              f"plant CPU {s['cpu_per_sample_us']:.0f} us/sample", flush=True)

    inplant = run_inplant_recording(domains, a.quick)

    targets = []
    for s in realtime:
        name = f"realtime {s['model']} T={s['control_period']:g} s"
        if s['exit_code'] != 0:
            targets.append(_row(f'{name}: ran the whole {sim_time:g} s', s['t'], 'completes',
                                False, 'stopped {:g} s'))
        if s['control_period'] < 5e-4:
            targets.append(_row(f'{name}: achieved real-time factor',
                                s['achieved_real_time_factor'], '>= 0.99',
                                s['achieved_real_time_factor'] >= 0.99))
            targets.append(_row(f'{name}: deadline misses', 100 * s['deadline_miss_rate'],
                                '<= 1 %', s['deadline_miss_rate'] <= 0.01, '{:.2f} %'))
        else:
            targets.append(_row(f'{name}: deadline misses', 100 * s['deadline_miss_rate'],
                                '<= 0.1 %', s['deadline_miss_rate'] <= 0.001, '{:.3f} %'))
    targets.append(_row('in-plant recorded / unrecorded lockstep loop', inplant['ratio'],
                        '<= 1.2', inplant['ratio'] <= 1.2, '{:.2f}'))
    fom = lockstep['fractional']
    targets.append(_row('lockstep FOM samples/s / bare DDS round trips/s',
                        fom['ratio_to_echo'], '>= 0.80', fom['ratio_to_echo'] >= 0.80,
                        '{:.2f}'))

    print('\nissue 11 targets (this run):')
    width = max(len(r['target']) for r in targets)
    print(f"  {'target':{width}s}  {'measured':>10s}  {'goal':>9s}  result")
    for r in targets:
        print(f"  {r['target']:{width}s}  {r['text']:>10s}  {r['goal']:>9s}  "
              f"{'pass' if r['pass'] else 'FAIL'}")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({
        'benchmark': 'ros graph', 'machine': platform.platform(), 'cpus': os.cpu_count(),
        'python': sys.version.split()[0], 'quick': a.quick,
        'simulated_time_realtime': sim_time, 'wall_time': time.monotonic() - started,
        'echo': echo, 'lockstep': lockstep, 'realtime': realtime,
        'realtime_priority_50': fifo, 'profile': profiles, 'inplant_recording': inplant,
        'targets': targets}, indent=2) + '\n')
    print(f'wrote {a.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
