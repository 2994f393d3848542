"""``make demo``: the main job, the closed loop through ROS 2 over DDS.

Starts the plant (FOM, alpha = 0.85, V = 75 m/s, x(0) = 0, lockstep, 2 s of simulated time)
and the eq. 31 state-feedback controller as two separate processes on a ROS domain of their
own, records the run to a rosbag2/MCAP bag with the recorder node (a third process), and
prints a summary computed from the bag: dominant frequency and amplitude of w, peak |Fp|,
samples and integration steps, wall time, with the control period and step.

    python scripts/demo.py [--model fractional] [--duration 2.0] [--controller state_feedback]
                           [--bag runs/demo-...]

ROS domain: ``ROS_DOMAIN_ID`` when it is exported, else ``FOHSSV_DEMO_DOMAIN``, else
1 + pid % 200 (a domain of its own); the first line printed names it. Discovery stays on this
machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``).

The run ends as the launch file's does (fohssv_sim.closed_loop.EXIT_RULE): when the plant
exits 0, or when any node exits non-zero: then the demo prints that node's exit code and last
line, stops the others, removes the bag if nothing was recorded, and exits with that code.
"""

from __future__ import annotations

import argparse
import json
import os
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
    DEMO_PLANT,
    ExitVerdict,
    NodeSpec,
    closed_loop,
    exit_verdict,
    reason_line,
    ros_args,
)


def _exe(package: str, name: str) -> str:
    return os.path.join(get_package_prefix(package), 'lib', package, name)


def command(spec: NodeSpec) -> list[str]:
    """The command line that starts ``spec`` (what ``ros2 run`` resolves, with its
    parameters)."""
    return [_exe(spec.package, spec.executable), *ros_args(spec)]


def specs(args: argparse.Namespace, bag: Path) -> tuple[NodeSpec, NodeSpec, NodeSpec]:
    """The nodes of the demo: the launch file's list (fohssv_sim.closed_loop) with the
    command line's choices."""
    return closed_loop(controller=args.controller, duration=args.duration, bag_path=str(bag),
                       plant={'model': args.model, 'fractional_order': args.alpha,
                              'speed': args.speed})


def demo_domain(environ: dict[str, str]) -> int:
    """The ROS domain of the demo: ``ROS_DOMAIN_ID`` when exported (as every ROS tool honours
    it), else ``FOHSSV_DEMO_DOMAIN``, else 1 + pid % 200 (a domain of its own, so that two demos
    on one machine do not meet)."""
    for name in ('ROS_DOMAIN_ID', 'FOHSSV_DEMO_DOMAIN'):
        value = environ.get(name, '').strip()
        if value:
            if not value.isdigit() or not 0 <= int(value) <= 232:
                raise ValueError(f'{name}={value!r} is not a ROS domain: an integer in '
                                 '[0, 232] (Fast DDS)')
            return int(value)
    return 1 + os.getpid() % 200


class Started:
    """A node process of the demo; its output is read by a thread (``echo``: printed with that
    prefix as it comes) or written to ``log``; ``last_line()`` for the exit rule (the line
    that says why it exited)."""

    def __init__(self, proc: subprocess.Popen, *, log: Path | None = None,
                 echo: str | None = None) -> None:
        self.proc, self.log, self.echo = proc, log, echo
        self.lines: list[str] = []
        self.reader = None
        if proc.stdout is not None:
            self.reader = threading.Thread(target=self._pump, daemon=True)
            self.reader.start()

    def _pump(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)
            if self.echo is not None:
                print(self.echo + line.rstrip(), flush=True)

    def last_line(self) -> str:
        """Why it exited: its last error line, else its last line."""
        if self.reader is not None:
            self.reader.join(timeout=2)
        return reason_line(self.lines if self.log is None else self.log.read_text().splitlines())


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
    """Stop what still runs; the exit codes. After a complete run the recorder closes the bag
    by itself once it holds everything the plant's run_end lists (exit 6 naming any loss):
    it is waited for (30 s) before it gets SIGTERM."""
    codes = {}
    recorder = nodes['recorder'].proc
    if wait_recorder:
        try:
            recorder.wait(timeout=30)
        except subprocess.TimeoutExpired:
            pass
    for name in ('plant', 'controller', 'recorder'):
        if name in nodes:
            codes[name] = _stop(nodes[name].proc, 60 if name == 'recorder' else 10)
    for node in nodes.values():
        if node.reader is not None:
            node.reader.join(timeout=5)
    return codes


def remove_if_empty(bag: Path, rec_log: Path) -> None:
    """A failed start leaves the bag the recorder opened without a message (it marks it
    ``fohssv.empty``): remove it and its log rather than leave an empty run behind."""
    meta = bag / 'metadata.yaml'
    if meta.exists() and 'fohssv.empty' in meta.read_text():
        shutil.rmtree(bag)
        rec_log.unlink(missing_ok=True)
        print(f'demo: removed the empty bag {bag} (no message was recorded)', file=sys.stderr)


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
    return ap


def dominant_frequency(t: np.ndarray, x: np.ndarray, pad: int = 16) -> float:
    """Frequency (Hz) of the largest peak of the Hann-windowed, zero-padded spectrum."""
    x = x - x.mean()
    n = len(x)
    spec = np.abs(np.fft.rfft(x * np.hanning(n), n * pad))
    freqs = np.fft.rfftfreq(n * pad, d=float(t[1] - t[0]))
    spec[0] = 0.0
    return float(freqs[int(np.argmax(spec))])


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
    # plant, controller, recorder: the launch file's nodes and parameters (closed_loop.py:
    # the settings that make the bag complete are explained there)
    plant_cmd, ctl_cmd, rec_cmd = (command(s) for s in specs(args, bag))
    print(f'demo: plant ({args.model}, alpha={args.alpha:g}, V={args.speed:g} m/s, x(0)=0, '
          f'lockstep, {args.duration:g} s), controller {args.controller!r} and recorder as '
          f'three processes, ROS_DOMAIN_ID={domain}', flush=True)
    print(f'demo: recording to {bag}', flush=True)
    bag.parent.mkdir(parents=True, exist_ok=True)
    rec_log = bag.parent / f'{bag.name}.recorder.log'
    with open(rec_log, 'w') as log:
        recorder = subprocess.Popen(rec_cmd, env=env, stdout=log,
                                    stderr=subprocess.STDOUT, text=True, start_new_session=True)
    nodes = {'recorder': Started(recorder, log=rec_log)}
    deadline = time.monotonic() + 60
    while 'recording to' not in rec_log.read_text() and time.monotonic() < deadline:
        if recorder.poll() is not None:
            break      # supervise() reports it
        time.sleep(0.05)
    wall0 = time.monotonic()
    if recorder.poll() is None:
        nodes['controller'] = Started(subprocess.Popen(
            ctl_cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True))
        nodes['plant'] = Started(subprocess.Popen(
            plant_cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            start_new_session=True), echo='  plant: ')
    name, verdict = supervise(nodes, args.timeout)
    wall = time.monotonic() - wall0
    codes = stop_all(nodes, wait_recorder=not verdict.failed)
    if verdict.failed:
        print(f'demo: {verdict.message}', file=sys.stderr)
        remove_if_empty(bag, rec_log)
        code = nodes[name].proc.returncode
        return code if 0 < code < 128 else 1
    if codes['recorder'] != 0:
        print(f'demo: recorder exited with code {codes["recorder"]}: {rec_log.read_text()}',
              file=sys.stderr)
        return 1
    plant_out = nodes['plant'].lines
    try:
        run = load_run(bag)   # the summary comes from the bag, not from memory
    except BagError as e:
        print(f'demo: {e}', file=sys.stderr)
        return 1

    summary = {}
    for line in plant_out:
        if 'summary: {' in line:
            summary = json.loads(line.split('summary: ', 1)[1])
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
    print(f'  plots:                  fohssv plot {bag}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
