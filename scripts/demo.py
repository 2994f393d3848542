"""``make demo``: the main job, the closed loop through ROS 2 over DDS.

Starts the plant (FOM, alpha = 0.85, V = 75 m/s, x(0) = 0, lockstep, 2 s of simulated time)
and the eq. 31 state-feedback controller as two separate processes on a ROS domain of their
own, records the run to a rosbag2/MCAP bag with the recorder node (a third process), and
prints a summary computed from the bag: dominant frequency and amplitude of w, peak |Fp|,
samples and integration steps, wall time, with the control period and step.

    python scripts/demo.py [--model fractional] [--duration 2.0] [--controller state_feedback]
                           [--bag runs/demo-...] [--viewer [PORT]]

``--viewer`` (``make demo DEMO_ARGS=--viewer``) also starts the Foxglove viewer on
ws://localhost:8765 (or PORT) and starts the run once a Foxglove client has subscribed (at
most ``--viewer-wait`` s later), so the run is watched from t = 0.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import re
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
    NodeSpec,
    closed_loop,
    ros_args,
    viewer,
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
    ap.add_argument('--viewer', type=int, nargs='?', const=DEFAULT_VIEWER_PORT, default=None,
                    metavar='PORT', help='also start the Foxglove viewer on ws://localhost:PORT '
                    f'(default {DEFAULT_VIEWER_PORT}; 0 = a free port)')
    ap.add_argument('--viewer-wait', type=float, default=120.0, metavar='S',
                    help='with --viewer: wall seconds to wait for a Foxglove client before '
                    'the run starts anyway (default 120)')
    return ap


def start_viewer(args: argparse.Namespace, bag: Path, env: dict[str, str]
                 ) -> subprocess.Popen | bool | None:
    """The viewer of ``--viewer``, once it serves and a client subscribed (or
    ``--viewer-wait`` passed); None (after saying why) if it exited; False without
    ``--viewer``."""
    if args.viewer is None:
        return False
    log = bag.parent / f'{bag.name}.viewer.log'
    with open(log, 'w') as out:
        proc = subprocess.Popen(command(viewer(args.viewer)), env=env, stdout=out,
                                stderr=subprocess.STDOUT, text=True, start_new_session=True)
    atexit.register(interrupt, proc)     # whatever ends the demo (Ctrl-C while it waits too)
    said = False
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        text = log.read_text()
        if proc.poll() is not None:
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
    return proc


def interrupt(proc: subprocess.Popen | bool) -> None:
    """SIGINT ``proc`` (if it is one) and wait; kill it after 10 s."""
    if not proc:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()


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

    domain = int(os.environ.get('FOHSSV_DEMO_DOMAIN', 1 + os.getpid() % 200))
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
    view = start_viewer(args, bag, env)          # False without --viewer
    if view is None:
        return 1
    rec_log = bag.parent / f'{bag.name}.recorder.log'
    with open(rec_log, 'w') as log:
        recorder = subprocess.Popen(rec_cmd, env=env, stdout=log,
                                    stderr=subprocess.STDOUT, text=True, start_new_session=True)
    deadline = time.monotonic() + 60
    while 'recording to' not in rec_log.read_text() and time.monotonic() < deadline:
        if recorder.poll() is not None:
            print(f'demo: the recorder exited: {rec_log.read_text()}', file=sys.stderr)
            return 1
        time.sleep(0.05)
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
        interrupt(ctl)
        interrupt(view)
    if code != 0:
        print(f'demo: plant exited with code {code}', file=sys.stderr)
        print(ctl.stdout.read(), file=sys.stderr)
        return 1
    if rec_code != 0:
        print(f'demo: recorder exited with code {rec_code}: {rec_log.read_text()}',
              file=sys.stderr)
        return 1
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
