"""Two versions of the plant and controller side by side in the pinned lockstep FOM loop
(a diagnostic tool).

    git worktree add /tmp/before REV
    scripts/in-env python tools/diag/ab_lockstep.py /tmp/before --rounds 6

Each round runs the installed plant and eq. 31 controller node ("new") and those of the
source tree given ("old": its ``src/fohssv_sim`` and ``src/fohssv_controller`` first on
``PYTHONPATH``), pinned as ``bench_ros.py``'s pinned case pins them (plant and ping on CPU 0,
controller and pong on CPU 1), 3 s of FOM each, in the order old-new-new-old or
new-old-old-new (alternating), between two pinned bare echoes. Prints per round both loops'
rates, each over the mean of the two echoes beside it, and new / old; then the medians. A
change of either node's per-sample path is measured so on a machine whose speed drifts
between runs.

``--demo`` compares instead the demo's loop recorded in-plant and unrecorded (plant and
controller placed as ``make demo`` places them, ``ros_runs.demo_cpus``) for both trees,
beside the bare echo (:func:`demo`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'bench'))
import ros_runs as b  # noqa: E402  (bench/ros_runs.py: bench_ros.py's processes)


def _env(domains: b.Domains, old_src: str | None) -> dict:
    env = domains.env()
    if old_src is not None:
        env['PYTHONPATH'] = (f'{old_src}/src/fohssv_sim:{old_src}/src/fohssv_controller:'
                             + env.get('PYTHONPATH', ''))
    return env


def _loop(domains: b.Domains, old_src: str | None) -> float:
    env = _env(domains, old_src)
    args = b.ros_args({'mode': 'lockstep', 'model': 'fractional', 'duration': 3.0,
                       'cpu_affinity': 0, **b.MODEL_PARAMS['fractional']})
    ctl = subprocess.Popen([b._exe('fohssv_controller', 'state_feedback'), '--ros-args', '-p',
                            'cpu_affinity:=1'], env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.STDOUT, start_new_session=True)
    try:
        out = subprocess.run([sys.executable, '-c', 'from fohssv_sim.ros.plant_node import '
                              'main; main()', *args], env=env, capture_output=True, text=True,
                             timeout=600)
    finally:
        b._stop(ctl)
    lines = [ln for ln in out.stderr.splitlines() if 'summary: ' in ln]
    if out.returncode != 0 or not lines:
        raise RuntimeError(f'plant exited {out.returncode}:\n{out.stderr[-3000:]}')
    return json.loads(lines[-1].split('summary: ', 1)[1])['samples_per_second']


def demo(domains: b.Domains, old_src: str, rounds: int) -> None:
    """``--demo``: the demo's loop (``ros_realtime.run_inplant_recording``'s: FOM, lockstep, 2 s,
    placed as the demo places it) recorded in-plant and unrecorded, for both trees, each
    round in alternated order, the bare echo before and after it; per tree the mean loop
    times and the median of the rounds' recorded / unrecorded ratios (the ``make demo``
    target's figure)."""
    import tempfile

    params = {'model': 'fractional', 'fractional_order': 0.85, 'speed': 75.0,
              'mode': 'lockstep', 'duration': 2.0}
    cpus = b.demo_cpus()
    times = {w: {'recorded': [], 'unrecorded': []} for w in ('old', 'new')}
    with tempfile.TemporaryDirectory() as tmp:
        for n in range(rounds):
            before = b.run_echo(domains, 20000)['round_trips_per_second']
            trees = ('old', 'new') if n % 2 == 0 else ('new', 'old')
            kinds = ('unrecorded', 'recorded') if n // 2 % 2 == 0 else ('recorded',
                                                                         'unrecorded')
            for which in trees:
                env = _env(domains, old_src if which == 'old' else None)
                for kind in kinds:
                    extra = {'record': f'{tmp}/{which}{n}'} if kind == 'recorded' else {}
                    wall, _ = b._timed_loop(env, {**params, **cpus['plant'], **extra},
                                            timeout=900.0, controller_params=cpus['controller'])
                    times[which][kind].append(wall)
            after = b.run_echo(domains, 20000)['round_trips_per_second']
            print(f"round {n + 1}: echo {before:.0f} / {after:.0f} round trips/s; " + '; '.join(
                f"{w} recorded {times[w]['recorded'][-1]:.2f} s, unrecorded "
                f"{times[w]['unrecorded'][-1]:.2f} s" for w in ('old', 'new')), flush=True)
    for w in ('old', 'new'):
        t = times[w]
        ratios = [r / u for r, u in zip(t['recorded'], t['unrecorded'])]
        print(f"{w}: mean recorded {statistics.mean(t['recorded']):.2f} s, unrecorded "
              f"{statistics.mean(t['unrecorded']):.2f} s; recorded / unrecorded per round "
              + ', '.join(f'{r:.2f}' for r in ratios)
              + f', median {statistics.median(ratios):.2f}', flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('old_src', help='the other version: a source tree (e.g. a git worktree)')
    ap.add_argument('--rounds', type=int, default=6)
    ap.add_argument('--demo', action='store_true',
                    help='compare the demo loop recorded in-plant / unrecorded instead')
    a = ap.parse_args()
    if not (Path(a.old_src) / 'src' / 'fohssv_sim' / 'fohssv_sim').is_dir():
        ap.error(f'old_src={a.old_src!r}: no src/fohssv_sim/fohssv_sim in it')
    domains = b.Domains()
    if a.demo:
        demo(domains, a.old_src, a.rounds)
        return 0
    ratios: dict[str, list[float]] = {'old': [], 'new': []}
    gains = []
    for n in range(a.rounds):
        before = b.run_echo(domains, 20000, cpus=(0, 1))['round_trips_per_second']
        order = ('old', 'new', 'new', 'old') if n % 2 == 0 else ('new', 'old', 'old', 'new')
        rates: dict[str, list[float]] = {'old': [], 'new': []}
        for which in order:
            rates[which].append(_loop(domains, a.old_src if which == 'old' else None))
        after = b.run_echo(domains, 20000, cpus=(0, 1))['round_trips_per_second']
        echo = (before + after) / 2
        mean = {k: statistics.mean(v) for k, v in rates.items()}
        for k in mean:
            ratios[k].append(mean[k] / echo)
        gains.append(mean['new'] / mean['old'])
        print(f"round {n + 1}: pinned echo {before:.0f} / {after:.0f} round trips/s; old "
              f"{mean['old']:.0f} samples/s ({ratios['old'][-1]:.3f} of the echo), new "
              f"{mean['new']:.0f} ({ratios['new'][-1]:.3f}); new / old {gains[-1]:.3f}",
              flush=True)
    print(f"median new / old {statistics.median(gains):.3f}; loop / echo old "
          f"{statistics.median(ratios['old']):.3f}, new {statistics.median(ratios['new']):.3f}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
