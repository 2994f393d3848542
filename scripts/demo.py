"""``make demo``: the main job, the closed loop through ROS 2 over DDS.

Starts the plant (FOM, alpha = 0.85, V = 75 m/s, x(0) = 0, lockstep, 2 s of simulated time)
and the eq. 31 state-feedback controller as two separate processes on a ROS domain of their
own, records the run to a rosbag2/MCAP bag, and prints a summary computed from the bag:
dominant frequency and amplitude of w, peak |Fp|, samples and integration steps, wall time,
with the control period and step.

Recording (``--recorder``): ``plant`` (default) is in-plant recording, the plant's
``record:=BAG`` (a writer process fed through shared memory writes the bag, off the loop);
``node`` is the recorder node, a third process subscribed over DDS, which the loop must wait
for (``pace_to_subscribers``). Then (unless ``--no-baseline``) the same loop runs once more
unrecorded, and the demo prints both loop times and their ratio: what recording costs. A loop
time runs from the plant's first sample to its bag closed (recorded) or its last sample
(unrecorded), as the plant's log lines arrive.

    python scripts/demo.py [--model fractional] [--duration 2.0] [--controller state_feedback]
                           [--bag runs/demo-...] [--recorder plant|node] [--no-baseline]
                           [--hosted]

``--hosted`` (``make demo DEMO_ARGS=--hosted``): the plant hosts the controller itself
(``controller:=NAME`` on the plant): no controller process, no DDS in the loop.
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
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from ament_index_python.packages import get_package_prefix

from fohssv_sim.bag import BagError, load_run
from fohssv_sim.closed_loop import (
    DEFAULT_CONTROLLER,
    DEFAULT_DURATION,
    DEMO_PLANT,
    NodeSpec,
    closed_loop,
    ros_args,
)


def _exe(package: str, name: str) -> str:
    return os.path.join(get_package_prefix(package), 'lib', package, name)


def command(spec: NodeSpec) -> list[str]:
    """The command line that starts ``spec`` (what ``ros2 run`` resolves, with its
    parameters)."""
    return [_exe(spec.package, spec.executable), *ros_args(spec)]


def specs(args: argparse.Namespace, bag: Path) -> tuple[NodeSpec, ...]:
    """The nodes of the demo: the launch file's list (fohssv_sim.closed_loop) with the
    command line's choices (plant, controller, recorder; plant and recorder when hosted)."""
    return closed_loop(controller=args.controller, duration=args.duration, bag_path=str(bag),
                       plant={'model': args.model, 'fractional_order': args.alpha,
                              'speed': args.speed}, hosted=args.hosted)


def in_plant(nodes: tuple[NodeSpec, ...], bag: Path | None
             ) -> tuple[NodeSpec, NodeSpec | None]:
    """The plant and the controller of the loop without the recorder node (the controller
    None when the plant hosts the law): the plant records its own run to ``bag``
    (``record``; None: unrecorded), so nothing waits for a third process (no
    ``pace_to_subscribers``, one state subscriber, one command subscriber; a hosted law
    counts as the state subscriber)."""
    plant, ctl = nodes[0], (nodes[1] if len(nodes) == 3 else None)
    params = {k: v for k, v in plant.parameters.items() if k != 'pace_to_subscribers'}
    params['min_state_subscribers'] = 1
    if bag is not None:
        params['record'] = str(bag)
    return (NodeSpec(plant.package, plant.executable, plant.name, params),
            None if ctl is None else NodeSpec(ctl.package, ctl.executable, ctl.name,
                                              {**ctl.parameters, 'min_command_subscribers': 1}))


class Loop:
    """A plant and a controller process; the plant's lines with their arrival times."""

    def __init__(self, plant: NodeSpec, ctl: NodeSpec | None, env: dict[str, str],
                 echo: str) -> None:
        self.wall0 = time.monotonic()
        self.ctl = None if ctl is None else subprocess.Popen(
            command(ctl), env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True)
        self.plant = subprocess.Popen(command(plant), env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True,
                                      start_new_session=True)
        self.lines: list[tuple[float, str]] = []
        self.echo = echo
        self.reader = threading.Thread(target=self._pump, daemon=True)
        self.reader.start()

    def _pump(self) -> None:
        for line in self.plant.stdout:
            self.lines.append((time.monotonic(), line))
            if self.echo:
                print(self.echo + line.rstrip(), flush=True)

    def wait(self, timeout: float) -> int:
        """The plant's exit code (SIGINT after ``timeout`` s); the controller is stopped."""
        try:
            code = self.plant.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.plant.send_signal(signal.SIGINT)
            code = self.plant.wait(timeout=30)
            print(f'demo: the plant did not finish within {timeout:g} s', file=sys.stderr)
        self.wall = time.monotonic() - self.wall0
        self.reader.join(timeout=5)
        if self.ctl is not None:
            self.ctl.send_signal(signal.SIGINT)
            try:
                self.ctl.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.ctl.kill()
        return code

    def controller_output(self) -> str:
        """What the controller process printed ('' when the plant hosts the law)."""
        return '' if self.ctl is None else self.ctl.stdout.read()

    def at(self, words: str) -> float:
        """When the first plant line holding ``words`` arrived (nan: none)."""
        return next((t for t, line in self.lines if words in line), float('nan'))

    def loop_time(self) -> float:
        """First sample to bag closed (in-plant recorded) or to the run's summary."""
        end = self.at('in-plant recording: closed')
        if end != end:
            end = self.at('summary: {')
        return end - self.at('starting at t = 0')

    def summary(self) -> dict:
        for _, line in self.lines:
            if 'summary: {' in line:
                return json.loads(line.split('summary: ', 1)[1])
        return {}


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
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
    ap.add_argument('--no-baseline', dest='baseline', action='store_false',
                    help='skip the unrecorded run that measures what recording costs')
    return ap


def dominant_frequency(t: np.ndarray, x: np.ndarray, pad: int = 16) -> float:
    """Frequency (Hz) of the largest peak of the Hann-windowed, zero-padded spectrum."""
    x = x - x.mean()
    n = len(x)
    spec = np.abs(np.fft.rfft(x * np.hanning(n), n * pad))
    freqs = np.fft.rfftfreq(n * pad, d=float(t[1] - t[0]))
    spec[0] = 0.0
    return float(freqs[int(np.argmax(spec))])


def _with_recorder_node(nodes, env, bag: Path, timeout: float) -> tuple[int, Loop, float]:
    """The loop recorded by the recorder node (a third process): (exit code, the loop, when
    the recorder had closed the bag)."""
    plant, ctl, rec = nodes if len(nodes) == 3 else (nodes[0], None, nodes[1])
    rec_log = bag.parent / f'{bag.name}.recorder.log'
    with open(rec_log, 'w') as log:
        recorder = subprocess.Popen(command(rec), env=env, stdout=log,
                                    stderr=subprocess.STDOUT, text=True, start_new_session=True)
    deadline = time.monotonic() + 60
    while 'recording to' not in rec_log.read_text() and time.monotonic() < deadline:
        if recorder.poll() is not None:
            print(f'demo: the recorder exited: {rec_log.read_text()}', file=sys.stderr)
            return 1, None, 0.0
        time.sleep(0.05)
    closed: list[float] = []
    watcher = threading.Thread(target=lambda: (recorder.wait(), closed.append(time.monotonic())),
                               daemon=True)
    watcher.start()
    loop = Loop(plant, ctl, env, '  plant: ')
    code = loop.wait(timeout)
    try:
        # the recorder closes the bag by itself once it holds everything the plant's
        # run_end lists (exit 6 naming any loss); SIGINT only if it does not
        rec_code = recorder.wait(timeout=30)
    except subprocess.TimeoutExpired:
        recorder.send_signal(signal.SIGINT)   # drains, then closes the bag properly
        try:
            rec_code = recorder.wait(timeout=60)
        except subprocess.TimeoutExpired:
            recorder.kill()
            rec_code = -9
    watcher.join(timeout=5)
    if code != 0:
        print(f'demo: plant exited with code {code}', file=sys.stderr)
        print(loop.controller_output(), file=sys.stderr)
        return 1, loop, 0.0
    if rec_code != 0:
        print(f'demo: recorder exited with code {rec_code}: {rec_log.read_text()}',
              file=sys.stderr)
        return 1, loop, 0.0
    return 0, loop, closed[0] if closed else time.monotonic()


def main() -> int:
    args = parser().parse_args()
    stamp = datetime.now(timezone.utc).strftime('%Y%m%dT%H%M%SZ')
    bag = args.bag or Path('runs') / f'demo-{stamp}'
    if bag.exists():
        print(f'demo: {bag} exists already; choose another --bag', file=sys.stderr)
        return 2

    domain = int(os.environ.get('FOHSSV_DEMO_DOMAIN', 1 + os.getpid() % 200))
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    # plant, controller, recorder: the launch file's nodes and parameters (closed_loop.py:
    # the settings that make the bag complete are explained there)
    nodes = specs(args, bag)
    if args.hosted:
        print(f'demo: the plant hosts controller {args.controller!r} (no controller process)',
              flush=True)
    how = ('the plant records its own run (in-plant, record:=BAG), two processes'
           if args.recorder == 'plant' else 'the recorder node records it, three processes')
    print(f'demo: plant ({args.model}, alpha={args.alpha:g}, V={args.speed:g} m/s, x(0)=0, '
          f'lockstep, {args.duration:g} s) and controller {args.controller!r}; {how}; '
          f'ROS_DOMAIN_ID={domain}', flush=True)
    print(f'demo: recording to {bag}', flush=True)
    bag.parent.mkdir(parents=True, exist_ok=True)
    if args.recorder == 'plant':
        loop = Loop(*in_plant(nodes, bag), env, '  plant: ')
        code = loop.wait(args.timeout)
        if code != 0:
            print(f'demo: plant exited with code {code}', file=sys.stderr)
            print(loop.controller_output(), file=sys.stderr)
            return 1
        recorded = loop.loop_time()
    else:
        code, loop, closed = _with_recorder_node(nodes, env, bag, args.timeout)
        if code != 0:
            return code
        recorded = closed - loop.at('starting at t = 0')
    baseline = None
    if args.baseline:
        print('demo: the same loop once more, unrecorded (what recording costs)', flush=True)
        base = Loop(*in_plant(nodes, None), env, '')
        if base.wait(args.timeout) == 0:
            baseline = base.loop_time()
        else:
            print('demo: the unrecorded loop failed: ' + ''.join(x for _, x in base.lines[-3:]),
                  file=sys.stderr)
    wall, summary = loop.wall, loop.summary()
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
          f'm/s, controller {args.controller}')
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
    if baseline is not None:
        print(f'  recording cost          recorded loop {recorded:.2f} s / unrecorded lockstep '
              f'loop {baseline:.2f} s = {recorded / baseline:.2f} ({args.recorder} recording;'
              ' first sample to bag closed / to last sample)')
    print(f'  plots:                  fohssv plot {bag}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
