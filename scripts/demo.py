"""``make demo``: the main job, the closed loop through ROS 2 over DDS.

Starts the plant (FOM, alpha = 0.85, V = 75 m/s, x(0) = 0, lockstep, 2 s of simulated time)
and the eq. 31 state-feedback controller as two separate processes on a ROS domain of their
own, records the run to a rosbag2/MCAP bag, and prints a summary computed from the bag:
dominant frequency and amplitude of w, peak |Fp|, samples and integration steps, wall time,
with the control period and step.

Recording (``--recorder``): ``plant`` (default) is in-plant recording, the plant's
``record:=BAG`` (a writer process fed through shared memory writes the bag, off the loop);
``node`` is the recorder node, a third process subscribed over DDS, which the loop must wait
for (``pace_to_subscribers``). The nodes are those ``ros2 launch fohssv_sim
closed_loop.launch.py`` starts with the same arguments (fohssv_sim.closed_loop): the launch
and the demo make the same run. (What recording costs is measured by ``bench/bench_ros.py``,
not here.)

    python scripts/demo.py [--model fractional] [--duration 2.0] [--controller state_feedback]
                           [--bag runs/demo-...] [--recorder plant|node] [--hosted]
                           [--viewer [PORT]] [--pin auto|off] [--cpu-dma-latency US]

``--hosted`` (``make demo DEMO_ARGS=--hosted``): the plant hosts the controller itself
(``controller:=NAME`` on the plant): no controller process, no DDS in the loop.

``--pin`` (default ``auto``): with a controller node and at least two CPUs to run on, the
plant runs on the first of them and the controller node on the second (``cpu_affinity``, as
:func:`fohssv_sim.closed_loop.pinned` sets it; the in-plant writer, the recorder node and a
viewer stay the scheduler's): in lockstep the two wake each other every sample, and left to
the scheduler they often share one CPU for stretches of the run, which made the demo's loop
time vary twofold from run to run here. ``--pin off``: the scheduler's choice.

``--viewer`` (``make demo DEMO_ARGS=--viewer``) also starts the Foxglove viewer on
ws://localhost:8765 (or PORT) and starts the run once a Foxglove client has subscribed (at
most ``--viewer-wait`` s later), so the run is watched from t = 0.

``--cpu-dma-latency`` (default 0): the plant asks Linux for that CPU wake-up latency while it
runs (its ``cpu_dma_latency``: idle CPUs keep polling, so DDS wakes the lockstep loop sooner;
needs write access to /dev/cpu_dma_latency, else one line and the run goes on); -1 = no
request.

ROS domain: ``ROS_DOMAIN_ID`` when it is exported, else ``FOHSSV_DEMO_DOMAIN``, else one of
``FOHSSV_DOMAIN_RANGE`` (``LO-HI``, default 1-200: on a shared host, the range other users
leave free) chosen by the process id (a domain of its own); the first line printed names it.
Discovery stays on this machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``).

The run ends as the launch file's does (fohssv_sim.closed_loop.EXIT_RULE): when the plant
exits 0, or when any node exits non-zero: then the demo prints that node's exit code and last
line, stops the others, removes the bag if nothing was recorded, and exits with that code.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from ament_index_python.packages import get_package_prefix

from fohssv_sim.bag import BagError, load_run
from fohssv_sim.closed_loop import (
    DEFAULT_CONTROLLER,
    DEFAULT_DURATION,
    DEFAULT_VIEWER_PORT,
    DEMO_PLANT,
    ExitVerdict,
    NodeSpec,
    closed_loop,
    exit_verdict,
    loop_cpus,
    pinned,
    reason_line,
    ros_args,
    viewer,
    watched,
)

#: The plant's line when its first sample goes out, and when its in-plant bag is closed.
STARTED, CLOSED, SUMMARY = 'starting at t = 0', 'in-plant recording: closed', 'summary: {'
#: Every node process the demo started: whatever ends the demo (Ctrl-C included), those still
#: running get SIGTERM (a clean stop: the bag is closed) at exit.
_STARTED: list[subprocess.Popen] = []


@atexit.register
def _stop_leftovers() -> None:
    for proc in _STARTED:
        if proc.poll() is None:
            _stop(proc, 30)


def _exe(package: str, name: str) -> str:
    return os.path.join(get_package_prefix(package), 'lib', package, name)


def command(spec: NodeSpec) -> list[str]:
    """The command line that starts ``spec`` (what ``ros2 run`` resolves, with its
    parameters)."""
    return [_exe(spec.package, spec.executable), *ros_args(spec)]


def specs(args: argparse.Namespace, bag: Path) -> tuple[NodeSpec, ...]:
    """The nodes of the demo: the launch file's list (fohssv_sim.closed_loop) with the
    command line's choices (plant, controller, recorder; plant and recorder when hosted),
    plant and controller node pinned apart unless ``--pin off`` (:func:`loop_cpus`)."""
    plant = {'model': args.model, 'fractional_order': args.alpha, 'speed': args.speed}
    if args.cpu_dma_latency is not None:
        plant['cpu_dma_latency'] = args.cpu_dma_latency
    nodes = closed_loop(controller=args.controller, duration=args.duration, bag_path=str(bag),
                        plant=plant, hosted=args.hosted, recorder=args.recorder)
    return pinned(nodes, loop_cpus() if args.pin == 'auto' else None)


#: The domains the demo picks from when none is given: ``FOHSSV_DOMAIN_RANGE`` or this.
DOMAIN_RANGE = (1, 200)


def domain_range(environ: dict[str, str]) -> tuple[int, int]:
    """``FOHSSV_DOMAIN_RANGE`` (``LO-HI``, inclusive, within [0, 232]) or :data:`DOMAIN_RANGE`.

    Raises:
        ValueError: malformed or out of range (one line naming the variable and its value).
    """
    text = environ.get('FOHSSV_DOMAIN_RANGE', '').strip()
    if not text:
        return DOMAIN_RANGE
    lo, _, hi = text.partition('-')
    if not (lo.strip().isdigit() and hi.strip().isdigit()) or not (
            0 <= int(lo) <= int(hi) <= 232):
        raise ValueError(f'FOHSSV_DOMAIN_RANGE={text!r} is not a range of ROS domains: LO-HI '
                         'with 0 <= LO <= HI <= 232 (Fast DDS), e.g. 120-139')
    return int(lo), int(hi)


def demo_domain(environ: dict[str, str]) -> int:
    """The ROS domain of the demo: ``ROS_DOMAIN_ID`` when exported (as every ROS tool honours
    it), else ``FOHSSV_DEMO_DOMAIN``, else one of :func:`domain_range` chosen by the process id
    (a domain of its own, so that two demos on one machine do not meet)."""
    for name in ('ROS_DOMAIN_ID', 'FOHSSV_DEMO_DOMAIN'):
        value = environ.get(name, '').strip()
        if value:
            if not value.isdigit() or not 0 <= int(value) <= 232:
                raise ValueError(f'{name}={value!r} is not a ROS domain: an integer in '
                                 '[0, 232] (Fast DDS)')
            return int(value)
    lo, hi = domain_range(environ)
    return lo + os.getpid() % (hi - lo + 1)


class Started:
    """A node process of the demo; its output is read by a thread (``echo``: printed with that
    prefix as it comes; each line kept with its arrival time) or written to ``log``;
    ``last_line()`` for the exit rule (the line that says why it exited)."""

    def __init__(self, spec: NodeSpec, env: dict[str, str], *, log: Path | None = None,
                 echo: str | None = None) -> None:
        self.log, self.echo = log, echo
        if log is not None:
            with open(log, 'w') as out:
                self.proc = subprocess.Popen(command(spec), env=env, stdout=out,
                                             stderr=subprocess.STDOUT, text=True,
                                             start_new_session=True)
        else:
            self.proc = subprocess.Popen(command(spec), env=env, stdout=subprocess.PIPE,
                                         stderr=subprocess.STDOUT, text=True,
                                         start_new_session=True)
        _STARTED.append(self.proc)
        self.lines: list[str] = []
        self.times: list[float] = []
        self.exited_at: float | None = None
        self.reader = None
        if self.proc.stdout is not None:
            self.reader = threading.Thread(target=self._pump, daemon=True)
            self.reader.start()

    def _pump(self) -> None:
        for line in self.proc.stdout:
            self.times.append(time.monotonic())
            self.lines.append(line)
            if self.echo is not None:
                print(self.echo + line.rstrip(), flush=True)

    def text(self) -> str:
        return self.log.read_text() if self.log is not None else ''.join(self.lines)

    def last_line(self) -> str:
        """Why it exited: its last error line, else its last line."""
        if self.reader is not None:
            self.reader.join(timeout=2)
        return reason_line(self.text().splitlines())

    def at(self, words: str) -> float:
        """When its first line holding ``words`` arrived (nan: none)."""
        return next((t for t, line in zip(self.times, self.lines) if words in line),
                    float('nan'))

    def summary(self) -> dict:
        for line in self.lines:
            if SUMMARY in line:
                return json.loads(line.split('summary: ', 1)[1])
        return {}


def supervise(nodes: dict[str, Started], timeout: float) -> tuple[str, ExitVerdict]:
    """Wait until a node's exit ends the run (fohssv_sim.closed_loop.EXIT_RULE: the plant's
    exit 0, or any node's non-zero exit); after ``timeout`` s the plant gets SIGINT (a clean
    stop) and the run ends with its exit."""
    deadline = time.monotonic() + timeout
    interrupted = False
    while True:
        for name, node in nodes.items():
            code = node.proc.poll()
            if code is None:
                continue
            if node.exited_at is None:
                node.exited_at = time.monotonic()
            verdict = exit_verdict(name, code, name == 'plant',
                                   node.last_line() if code else '')
            if verdict.ends_run:
                return name, verdict
        if not interrupted and time.monotonic() > deadline and 'plant' in nodes:
            print(f'demo: the plant did not finish within {timeout:g} s; stopping it',
                  file=sys.stderr)
            nodes['plant'].proc.send_signal(signal.SIGINT)
            interrupted = True
        time.sleep(0.05)


def _stop(proc: subprocess.Popen, grace: float) -> int:
    if proc.poll() is None:
        # every node stops cleanly on SIGTERM as on SIGINT (the recorder drains and closes the
        # bag); one still importing its modules ends quietly, without a KeyboardInterrupt
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def stop_all(nodes: dict[str, Started], wait_recorder: bool) -> dict[str, int]:
    """Stop what still runs; the exit codes. After a complete run the recorder node closes
    the bag by itself once it holds everything the plant's run_end lists (exit 6 naming any
    loss): it is waited for (30 s) before it gets SIGTERM, and when it exited is noted."""
    codes = {}
    recorder = nodes.get('recorder')
    if recorder is not None and wait_recorder:
        try:
            recorder.proc.wait(timeout=30)
            recorder.exited_at = recorder.exited_at or time.monotonic()
        except subprocess.TimeoutExpired:
            pass
    for name in ('plant', 'controller', 'recorder', 'viewer'):
        if name in nodes:
            codes[name] = _stop(nodes[name].proc, 60 if name == 'recorder' else 10)
    for node in nodes.values():
        if node.reader is not None:
            node.reader.join(timeout=5)
    return codes


def remove_if_empty(bag: Path, started: bool) -> None:
    """A failed start leaves a bag without a sample (the recorder node marks its bag
    ``fohssv.empty``; the plant's own writer opened the bag before the run began): remove it
    and its logs rather than leave an empty run behind."""
    meta = bag / 'metadata.yaml'
    if bag.exists() and (not started or (meta.exists() and 'fohssv.empty' in meta.read_text())):
        shutil.rmtree(bag)
        for log in bag.parent.glob(f'{bag.name}.*.log'):
            log.unlink(missing_ok=True)
        print(f'demo: removed the empty bag {bag} (no message was recorded)', file=sys.stderr)


def start_viewer(args: argparse.Namespace, bag: Path, env: dict[str, str]
                 ) -> Started | bool | None:
    """The viewer of ``--viewer``, once it serves and a client subscribed (or
    ``--viewer-wait`` passed); None (after saying why) if it exited; False without
    ``--viewer``."""
    if args.viewer is None:
        return False
    view = Started(viewer(args.viewer), env, log=bag.parent / f'{bag.name}.viewer.log')
    said = False
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        text = view.text()
        if view.proc.poll() is not None:
            print(f'demo: the viewer exited: {text}', file=sys.stderr)
            return None
        if 'Foxglove clients: ' in text:
            break
        served = re.search(r'serving Foxglove on ws://[^:]+:(\d+)', text)
        if served and not said:
            said = True
            deadline = time.monotonic() + args.viewer_wait
            print(f'demo: Foxglove viewer on ws://localhost:{served.group(1)}: in Foxglove, '
                  'Open connection -> Foxglove WebSocket -> that URL, Layout -> Import from '
                  'file docs/foxglove/fohssv_layout.json; the run starts when it connects '
                  f'(at most {args.viewer_wait:g} s)', flush=True)
        time.sleep(0.05)
    return view


def run_loop(nodes: tuple[NodeSpec, ...], args: argparse.Namespace, bag: Path,
             env: dict[str, str], extra: dict[str, Started] | None = None, echo: str = ''
             ) -> tuple[int, dict[str, Started], float]:
    """One run of the loop under the exit rule: the recorder node first when ``nodes`` has
    one (``--recorder node``), else the plant recording to ``bag`` itself. Returns (the demo's
    exit code, the processes, the loop time: first sample to bag closed)."""
    procs: dict[str, Started] = dict(extra or {})
    byname = {n.name: n for n in nodes}
    with_node = 'recorder' in byname
    if with_node:
        procs['recorder'] = Started(byname['recorder'], env,
                                    log=bag.parent / f'{bag.name}.recorder.log')
        deadline = time.monotonic() + 60
        while 'recording to' not in procs['recorder'].text() and time.monotonic() < deadline:
            if procs['recorder'].proc.poll() is not None:
                break      # supervise() reports it
            time.sleep(0.05)
    if 'recorder' not in procs or procs['recorder'].proc.poll() is None:
        if 'controller' in byname:
            procs['controller'] = Started(byname['controller'], env)
        procs['plant'] = Started(byname['plant'], env, echo=echo)
    name, verdict = supervise(procs, args.timeout)
    codes = stop_all(procs, wait_recorder=not verdict.failed)
    main_plant = procs.get('plant')
    started = main_plant is not None and main_plant.at(STARTED) == main_plant.at(STARTED)
    if verdict.failed:
        print(f'demo: {verdict.message}', file=sys.stderr)
        remove_if_empty(bag, started)
        code = procs[name].proc.returncode
        return (code if 0 < code < 128 else 1), procs, float('nan')
    if codes.get('recorder', 0) != 0:
        print(f"demo: recorder exited with code {codes['recorder']}: "
              f"{procs['recorder'].last_line()}", file=sys.stderr)
        return 1, procs, float('nan')
    if with_node:
        end = procs['recorder'].exited_at or time.monotonic()
    else:
        end = main_plant.at(CLOSED)
    return 0, procs, end - main_plant.at(STARTED)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        description=__doc__.split('\n\n')[0], epilog='environment: ROS_DOMAIN_ID (the '
        'domain; else FOHSSV_DEMO_DOMAIN), FOHSSV_DOMAIN_RANGE=LO-HI (the domains the demo '
        'picks from when neither is set; default 1-200, e.g. 120-139 on a shared host)')
    ap.add_argument('--model', default=DEMO_PLANT['model'])
    ap.add_argument('--alpha', type=float, default=DEMO_PLANT['fractional_order'])
    ap.add_argument('--speed', type=float, default=DEMO_PLANT['speed'])
    ap.add_argument('--duration', type=float, default=DEFAULT_DURATION)
    ap.add_argument('--controller', default=DEFAULT_CONTROLLER)
    ap.add_argument('--timeout', type=float, default=600.0, help='wall-clock limit (s)')
    ap.add_argument('--bag', type=Path, default=None,
                    help='bag folder to record (default runs/demo-<UTC time>)')
    ap.add_argument('--recorder', choices=('plant', 'node'), default='plant',
                    help="'plant': in-plant recording (record:=BAG, default); 'node': the "
                         'recorder node, a third process')
    ap.add_argument('--hosted', action='store_true',
                    help='the plant hosts the controller law (controller:=NAME on the plant): '
                         'no controller process')
    ap.add_argument('--pin', choices=('auto', 'off'), default='auto',
                    help="'auto' (default): the plant on the first CPU this process may use, the "
                         "controller node on the second (cpu_affinity), when there are two; "
                         "'off': the scheduler's choice")
    ap.add_argument('--cpu-dma-latency', type=int, default=0, metavar='US',
                    help="the plant's cpu_dma_latency (default 0: idle CPUs keep polling, "
                    'so DDS wakes the loop sooner; needs write access to '
                    '/dev/cpu_dma_latency); -1 = no request')
    ap.add_argument('--viewer', type=int, nargs='?', const=DEFAULT_VIEWER_PORT, default=None,
                    metavar='PORT', help='also start the Foxglove viewer on ws://localhost:PORT '
                    f'(default {DEFAULT_VIEWER_PORT}; 0 = a free port)')
    ap.add_argument('--viewer-wait', type=float, default=120.0, metavar='S',
                    help='with --viewer: wall seconds to wait for a Foxglove client before '
                    'the run starts anyway (default 120)')
    return ap


def dominant_frequency(t: np.ndarray, x: np.ndarray, pad: int = 16) -> float:
    """Frequency (Hz) of the largest peak of the Hann-windowed, zero-padded spectrum."""
    x = x - x.mean()
    n = len(x)
    spec = np.abs(np.fft.rfft(x * np.hanning(n), n * pad))
    freqs = np.fft.rfftfreq(n * pad, d=float(t[1] - t[0]))
    spec[0] = 0.0
    return float(freqs[int(np.argmax(spec))])


def _describe(args: argparse.Namespace, nodes: tuple[NodeSpec, ...], domain: int) -> str:
    law = (f'controller {args.controller!r} hosted in the plant' if args.hosted else
           f'controller {args.controller!r} as a node')
    rec = ('in-plant recording (record:=BAG)' if args.recorder == 'plant' else
           'the recorder node records it')
    procs = 1 + (not args.hosted) + (args.recorder == 'node')
    pins = [n.parameters.get('cpu_affinity') for n in nodes[:2]]    # as specs() placed them
    where = ('' if args.hosted else f'; plant on CPU {pins[0]}, controller on CPU {pins[1]}'
             if pins[0] is not None else '; plant and controller where the scheduler puts them')
    return (f'demo: plant ({args.model}, alpha={args.alpha:g}, V={args.speed:g} m/s, x(0)=0, '
            f'lockstep, {args.duration:g} s), {law}; {rec}; {procs} process(es){where}, '
            f'ROS_DOMAIN_ID={domain}')


def _report(args: argparse.Namespace, bag: Path, plant: Started, wall: float,
            loop: float) -> int:
    summary = plant.summary()
    try:
        run = load_run(bag)   # the summary comes from the bag, not from memory
    except BagError as e:
        print(f'demo: {e}', file=sys.stderr)
        return 1
    t, w = run.t, run.state[:, 1]
    half = t >= t[-1] / 2
    freq = dominant_frequency(t[half], w[half])
    amp = 0.5 * (w[half].max() - w[half].min())
    print()
    print(f'closed loop through ROS 2: {args.model}, alpha={args.alpha:g}, V={args.speed:g} '
          f'm/s, controller {args.controller}{" (hosted)" if args.hosted else ""}')
    print(f'  integration step        {summary.get("step", float("nan")):g} s '
          f'({summary.get("solver", "?")})')
    print(f'  control period (ZOH)    {summary.get("control_period", float("nan")):g} s')
    print(f'  bag                     {bag} ({run.topics.get("/state", 0)} states, '
          f'{run.topics.get("/planing_force", 0)} forces, {run.topics.get("/command", 0)} '
          f'commands; t = {t[0]:g} .. {t[-1]:g} s)')
    print(f'  integration steps       {summary.get("steps", "?")}')
    print(f'  w, last half [{t[half][0]:g}, {t[-1]:g}] s: dominant frequency {freq:.1f} Hz, '
          f'amplitude {amp:.4g} m/s (half peak-to-peak), mean {w[half].mean():.4g} m/s')
    print(f'  peak |Fp|               {np.abs(run.planing_force).max():.4g} m^2/s^2')
    print(f'  wall time               {wall:.1f} s (plant loop {summary.get("wall_time", 0):.1f}'
          f' s, {summary.get("samples_per_second", 0):.0f} samples/s)')
    print(f'  loop time               {loop:.2f} s (first sample to bag closed)')
    print(f'  plots:                  fohssv plot {bag}')
    return 0


def main() -> int:
    args = parser().parse_args()
    stamp = datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')
    bag = args.bag or Path('runs') / f'demo-{stamp}'
    if bag.exists():
        print(f'demo: {bag} exists already; choose another --bag', file=sys.stderr)
        return 2

    try:
        domain = demo_domain(os.environ)
    except ValueError as e:
        print(f'demo: {e}', file=sys.stderr)
        return 2
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    # the launch file's nodes and parameters (closed_loop.py: the settings that make the bag
    # complete are explained there)
    nodes = specs(args, bag)
    print(_describe(args, nodes, domain), flush=True)
    print(f'demo: recording to {bag}', flush=True)
    bag.parent.mkdir(parents=True, exist_ok=True)
    wall0 = time.monotonic()
    view = start_viewer(args, bag, env)          # False without --viewer
    if view is None:
        return 1
    code, procs, loop = run_loop(watched(nodes) if view else nodes, args, bag, env,
                                     {'viewer': view} if view else None, echo='  plant: ')
    wall = time.monotonic() - wall0
    if code != 0:
        return code
    return _report(args, bag, procs['plant'], wall, loop)


if __name__ == '__main__':
    sys.exit(main())
