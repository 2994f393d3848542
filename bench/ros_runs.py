"""The processes of ``bench/bench_ros.py``'s runs (bench only, not a benchmark itself).

A fresh ROS domain per run (:class:`Domains`); one plant run with the eq. 31 law, through the
controller node or hosted (:func:`run_plant`, again on another domain when it met another
graph); a real-time run held to a deadline-miss target, again while the host's steal covers
its misses (:func:`run_steady`, :func:`host_excuse`); the bare DDS echo
(:func:`run_echo`, ``bench/ros_echo.py``) and a plant that does no work against the
controller node (:func:`run_null_plant`); the demo's lockstep loop timed from its first
sample (:func:`_timed_loop`, placed by :func:`demo_cpus`); and the one-line report of a
real-time run (:func:`_realtime_line`). The cases (ros_lockstep.py, ros_realtime.py) and the
diagnostics in ``tools/diag/`` run their processes through these.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from ament_index_python.packages import get_package_prefix
from benchutil import host_cpu_ticks, steal_seconds, steal_share

from fohssv_sim.ros.options import NODE_PARAMETERS

HERE = Path(__file__).resolve().parent


MODELS = ('delay-free', 'delayed', 'fractional')


#: Model parameters of the real-time cases (the FOM of the issue: alpha 0.85, V 75, h 2e-5).
MODEL_PARAMS = {'delay-free': {}, 'delayed': {},
                'fractional': {'fractional_order': 0.85, 'speed': 75.0, 'step': 2e-5,
                               'solver': 'soe'}}


def _exe(package: str, name: str) -> str:
    return os.path.join(get_package_prefix(package), 'lib', package, name)


def ros_args(params: dict | None) -> list[str]:
    """``--ros-args -p k:=v ...`` for a node's parameters (nothing for none)."""
    args = ['--ros-args'] if params else []
    for k, v in (params or {}).items():
        args += ['-p', f'{k}:={v}']
    return args


class Domains:
    """A fresh ROS_DOMAIN_ID per run (a run's late packets never reach the next one), from
    ``FOHSSV_DOMAIN_RANGE`` (``LO-HI``, as ``make demo`` reads it: on a shared host, the range
    other users leave free) or 1-200."""

    def __init__(self) -> None:
        text = os.environ.get('FOHSSV_DOMAIN_RANGE', '').strip() or '1-200'
        try:
            lo, hi = (int(v) for v in text.split('-'))
        except ValueError:
            raise SystemExit(f'FOHSSV_DOMAIN_RANGE={text!r} is not a range LO-HI of ROS '
                             'domains (0-232)') from None
        if not 0 <= lo <= hi <= 232:
            raise SystemExit(f'FOHSSV_DOMAIN_RANGE={text!r} is not a range LO-HI of ROS '
                             'domains (0-232)')
        self.lo, self.size = lo, hi - lo + 1
        self.next = (os.getpid() * 11) % self.size

    def env(self) -> dict[str, str]:
        self.next = (self.next + 37) % self.size
        return dict(os.environ, ROS_DOMAIN_ID=str(self.lo + self.next),
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


#: Exit codes of a plant run that are results, not crashes: the vehicle lost (1), the
#: external controller's commands too late (6).
RESULT_CODES = {0: 'completed', 1: 'simulation failed', 6: 'command lag'}


#: The plant's exit code when another publisher of state shares its domain (a test or
#: benchmark of someone else on this machine): the run is repeated on another domain.
EXIT_SECOND_PLANT = 5


#: The hosted plant's exit code when another node publishes commands on its domain.
EXIT_SECOND_CONTROLLER = 7


def run_plant(domains: Domains, plant_params: dict, timeout: float,
              env_extra: dict | None = None, controller_params: dict | None = None) -> dict:
    """One plant run with the eq. 31 law: through the controller node (with
    ``controller_params``), or hosted when ``plant_params`` names a ``controller``; returns the
    plant's summary, with the controller node's CPU time per sample from the plant's start
    (peers matched) to its end. A run that met another graph on its domain (exit 5) is
    repeated on the next domain (3 tries)."""
    for _ in range(2):
        try:
            return _run_plant(domains, plant_params, timeout, env_extra, controller_params)
        except SecondPlant as exc:
            print(f'          ({exc}; again on another domain)', flush=True)
    return _run_plant(domains, plant_params, timeout, env_extra, controller_params)


class SecondPlant(RuntimeError):
    """The plant met another publisher of state on its domain."""


def _run_plant(domains: Domains, plant_params: dict, timeout: float,
               env_extra: dict | None = None, controller_params: dict | None = None) -> dict:
    env = dict(domains.env(), **(env_extra or {}))
    args = ros_args(plant_params) or ['--ros-args']
    ctl_args = ros_args(controller_params)
    ctl = None if plant_params.get('controller') else subprocess.Popen(
        [_exe('fohssv_controller', 'state_feedback'), *ctl_args], env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines: list[str] = []
    ctl_cpu: list[float | None] = []
    ticks_before = host_cpu_ticks()
    try:
        plant = subprocess.Popen([_exe('fohssv_sim', 'plant'), *args], env=env,
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 start_new_session=True)

        def pump() -> None:
            for line in plant.stdout:
                lines.append(line)
                if ctl is not None and ('peers matched' in line or 'summary: {' in line):
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
        if ctl is not None:
            _stop(ctl)
    ticks_after = host_cpu_ticks()      # the host around the run, read here, not by the plant
    steal = steal_share(ticks_before, ticks_after)
    text = ''.join(lines)
    found = [ln for ln in lines if 'summary: {' in ln]
    if code == EXIT_SECOND_PLANT or (code == EXIT_SECOND_CONTROLLER
                                      and plant_params.get('controller')):
        # another graph on the domain: a second plant (5), or another node's commands beside
        # a hosted law (7: e.g. someone's test or benchmark sharing this machine)
        raise SecondPlant(f"another graph on ROS_DOMAIN_ID {env['ROS_DOMAIN_ID']}")
    if code not in RESULT_CODES or not found:
        raise RuntimeError(f'plant exited {code}:\n{text[-2000:]}')
    s = json.loads(found[-1].split('summary: ', 1)[1])
    s['exit_code'] = code
    s['host_steal_share'] = steal
    s['host_steal_seconds'] = steal_seconds(ticks_before, ticks_after)
    if code != 0:   # the run stopped: a diverged or lagging loop is a result, not a crash
        s['failure'] = next((ln.split(']: ', 1)[-1] for ln in lines if RESULT_CODES[code]
                             in ln), f'exit {code}')
        print(f"          (stopped at t={s['t']:g} s, exit {code}: {s['failure'][:200]})",
              flush=True)
    if len(ctl_cpu) == 2 and None not in ctl_cpu and s['samples']:
        s['controller_cpu_time'] = ctl_cpu[1] - ctl_cpu[0]
        s['controller_cpu_per_sample_us'] = s['controller_cpu_time'] / s['samples'] * 1e6
    return s


#: A run with no deadline-miss target (lockstep throughput; real-time runs no target holds)
#: during which the hypervisor stole more than this share of the machine's time
#: (``host_steal_share``: the host ran other guests on its cores) measured the host, not the
#: plant: it is run again, at most ``STEAL_RETRIES`` more times, every attempt printed and
#: kept in the JSON. A run held to a deadline-miss target is judged by :func:`host_excuse`.
STEAL_LIMIT, STEAL_RETRIES = 0.01, 2


def host_excuse(s: dict, miss_target: float | None) -> str | None:
    """Why this real-time run measured the host rather than the plant (None: it measured the
    plant). Held to ``miss_target`` (the share of samples allowed late): the run missed it,
    and the CPU time the host stole over the run (``host_steal_seconds``, all CPUs, to a tick
    of 10 ms) is at least the time its late samples beyond the target span, their count times
    the sample's wall period: a vCPU held for d seconds makes at most d / period samples late
    (bench/stalls.py reads such stops in a kernel trace). A run that met its target, or
    whose late samples the steal cannot cover, stands. With no target (None): more than
    :data:`STEAL_LIMIT` of the machine's time stolen."""
    if miss_target is None:
        steal = s.get('host_steal_share')
        if steal is not None and steal > STEAL_LIMIT:
            return f'host steal {100 * steal:.2f} % > {100 * STEAL_LIMIT:g} %'
        return None
    stolen, paced = s.get('host_steal_seconds'), s.get('samples_paced')
    if stolen is None or not paced or s.get('exit_code', 0) != 0:
        return None
    beyond = s['deadline_misses'] - miss_target * paced
    period = s['control_period'] / s.get('real_time_factor', 1.0)
    if beyond <= 0 or stolen < beyond * period:
        return None
    return (f"{s['deadline_misses']} late samples, {beyond:.0f} beyond the target's "
            f"{100 * miss_target:g} % ({1e3 * beyond * period:.1f} ms of samples); the host "
            f'stole {1e3 * stolen:.0f} ms of CPU time over the run')


def run_steady(domains: Domains, make_params, label: str, timeout: float = 900.0,
               miss_target: float | None = None) -> dict:
    """A real-time run (``make_params(attempt)`` gives the plant's parameters), run again
    while :func:`host_excuse` says the host, not the plant, made its result (at most
    :data:`STEAL_RETRIES` more times); printed per attempt with ``label``. Returns the last
    attempt (each earlier one measured the host), with ``attempts`` (each attempt's misses,
    steal, exit code and excuse) and ``attempt`` (which one it is, from 1)."""
    tried = []
    for attempt in range(1 + STEAL_RETRIES):
        s = run_plant(domains, make_params(attempt), timeout=timeout)
        s['host_excuse'] = why = host_excuse(s, miss_target)
        tried.append(s)
        print(_realtime_line(label, s), flush=True)
        if why is None:
            break
        if attempt < STEAL_RETRIES:
            print(f'          ({why}: the host, not the plant; again, attempt {attempt + 2} '
                  f'of {1 + STEAL_RETRIES})', flush=True)
    s = tried[-1]
    s['attempt'] = len(tried)
    s['attempts'] = [{'deadline_miss_rate': a.get('deadline_miss_rate'),
                      'host_steal_share': a.get('host_steal_share'),
                      'host_steal_seconds': a.get('host_steal_seconds'),
                      'host_excuse': a['host_excuse'],
                      'exit_code': a['exit_code'], 't': a['t']} for a in tried]
    return s


#: The CPU wake-up latency limit the nodes hold by default (``cpu_dma_latency``; -1: none):
#: the echo and the floor loop hold the same, so that each ratio compares like with like.
NODE_LATENCY = next(s.default for s in NODE_PARAMETERS if s.name == 'cpu_dma_latency')


def run_echo(domains: Domains, count: int, profile: str | None = None,
             cpus: tuple[int, int] | None = None, latency: int = NODE_LATENCY) -> dict:
    """The bare round-trip loop (bench/ros_echo.py) for ``count`` round trips; ``profile``: a
    Fast DDS profile file instead of the package's (``FASTDDS_DEFAULT_PROFILES_FILE``);
    ``cpus``: the ping's and the pong's CPU (each process pinned, ``--cpu``); ``latency``:
    the CPU wake-up latency limit both hold (``--cpu-dma-latency``; by default the nodes'
    default, :data:`NODE_LATENCY`)."""
    env = domains.env()
    if profile is not None:
        env['FASTDDS_DEFAULT_PROFILES_FILE'] = profile
    script = str(HERE / 'ros_echo.py')
    pin = (['--cpu', str(cpus[0])], ['--cpu', str(cpus[1])]) if cpus else ([], [])
    pin = tuple([*p, '--cpu-dma-latency', str(latency)] for p in pin)
    return _ping_against(env, [sys.executable, script, 'pong', *pin[1]],
                         ['--count', str(count), *pin[0]], 'echo ping')


def _ping_against(env: dict, peer: list[str], ping_args: list[str], name: str) -> dict:
    """Start ``peer`` (a command), run ``ros_echo.py ping`` with ``ping_args`` against it,
    stop the peer: the ping's JSON line (raises with its output when it fails)."""
    peer_proc = subprocess.Popen(peer, env=env, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.STDOUT, start_new_session=True)
    try:
        out = subprocess.run([sys.executable, str(HERE / 'ros_echo.py'), 'ping', *ping_args],
                             env=env, timeout=300, capture_output=True, text=True)
    finally:
        _stop(peer_proc)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith('{')]
    if out.returncode != 0 or not lines:
        raise RuntimeError(f'{name} exited {out.returncode}:\n{out.stdout}{out.stderr}')
    return json.loads(lines[-1])


def run_null_plant(domains: Domains, count: int, cpus: tuple[int, int]) -> dict:
    """A plant that does no work against the real eq. 31 controller node, for ``count`` round
    trips: the echo's ping on the ``state`` and ``command`` topics (``--topics``), pinned to
    ``cpus[0]``, the ``state_feedback`` node pinned to ``cpus[1]`` (``cpu_affinity``). Its rate
    over the echo's is the most any plant's lockstep loop can reach with this controller."""
    return _ping_against(domains.env(), [_exe('fohssv_controller', 'state_feedback'),
                                         *ros_args({'cpu_affinity': cpus[1]})],
                         ['--count', str(count), '--cpu', str(cpus[0]), '--topics', 'state',
                          'command'], 'null plant')


def demo_cpus() -> dict[str, dict]:
    """The demo's placement (``scripts/demo.py``'s default ``--pin auto``): the plant's and the
    controller node's ``cpu_affinity`` parameters, as :func:`fohssv_sim.closed_loop.pinned`
    sets them ({} each with fewer than two CPUs)."""
    from fohssv_sim.closed_loop import loop_cpus

    cpus = loop_cpus()
    if cpus is None:
        return {'plant': {}, 'controller': {}}
    return {'plant': {'cpu_affinity': cpus[0]}, 'controller': {'cpu_affinity': cpus[1]}}


def _placement(cpus: dict[str, dict]) -> str:
    if not cpus['plant']:
        return 'unpinned'
    return (f"plant on CPU {cpus['plant']['cpu_affinity']}, controller on CPU "
            f"{cpus['controller']['cpu_affinity']}")


def _timed_loop(env: dict, plant_params: dict, timeout: float,
                controller_params: dict | None = None) -> tuple[float, dict]:
    """A lockstep plant + eq. 31 controller node: (wall seconds from the plant's first sample
    to its bag closed (with ``record``) or to its run's end, the plant's summary)."""
    args = ros_args(plant_params) or ['--ros-args']
    ctl = subprocess.Popen([_exe('fohssv_controller', 'state_feedback'),
                            *ros_args(controller_params or {})], env=env,
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


def _rt_priority_permitted() -> bool:
    """Whether this process could set SCHED_FIFO (root, or an rtprio limit)."""
    import resource

    if not hasattr(os, 'sched_setscheduler'):
        return False
    return os.geteuid() == 0 or resource.getrlimit(resource.RLIMIT_RTPRIO)[0] > 0


#: The eq. 31 law hosted in the plant (the same law the controller node runs).
HOSTED = {'controller': 'state_feedback'}


def _realtime_line(label: str, s: dict) -> str:
    lag = (f"command lag mean {s['command_lag_mean']:.1f} / worst {s['command_lag_worst']:.0f} "
           'periods, ' if 'command_lag_mean' in s else '')
    ctl = (f", controller CPU {s['controller_cpu_per_sample_us']:.0f} us/sample"
           if 'controller_cpu_per_sample_us' in s else '')
    return (f"realtime  {label}: RTF {s['achieved_real_time_factor']:.3f}, misses "
            f"{s['deadline_misses']}/{s['samples_paced']} ({100 * s['deadline_miss_rate']:.2f} "
            f"%), {lag}plant CPU {s['cpu_per_sample_us']:.0f} us/sample = "
            f"{s['cpu_share_of_period']:.2f} of the period{ctl}, worst lateness "
            f"{1e3 * s['worst_lateness']:.1f} ms" + _steal_text(s.get('host_steal_share'))
            + (f", STOPPED exit {s['exit_code']}" if s['exit_code'] else ''))


def _steal_text(share: float | None) -> str:
    return '' if share is None else f', host steal {100 * share:.2f} %'


def _realtime_params(model: str, period: float, sim_time: float, **extra) -> dict:
    return {'model': model, 'mode': 'realtime', 'control_period': period,
            'duration': sim_time, 'real_time_factor': 1.0, **MODEL_PARAMS[model], **extra}

