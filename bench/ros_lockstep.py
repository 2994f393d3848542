"""``bench/bench_ros.py``'s lockstep cases: the bare echo beside Fast DDS's default writer
timings (:func:`case_echo`), the loop through the controller node against the hosted law
(:func:`case_lockstep`), ``cpu_affinity`` (:func:`case_pinned`) and ``cpu_dma_latency``
(:func:`case_latency`), each measured against a bare echo run beside it."""

from __future__ import annotations

import os
import statistics
from pathlib import Path

from ros_runs import (
    HOSTED,
    MODEL_PARAMS,
    MODELS,
    STEAL_LIMIT,
    STEAL_RETRIES,
    Domains,
    _steal_text,
    run_echo,
    run_null_plant,
    run_plant,
)


def default_writer_times_profile(folder: str) -> str:
    """A copy of the package's Fast DDS profile without its default DataWriter profile (Fast
    DDS's own writer timings, nack_supression_duration 0): what the writer timing it sets
    saves, measured on the bare echo."""
    import re

    from fohssv_sim.ros.startup import localhost_profile

    text = Path(localhost_profile()).read_text()
    stripped = re.sub(r'\s*<data_writer .*?</data_writer>', '', text, flags=re.S)
    if stripped == text:
        raise RuntimeError('the package profile has no default DataWriter profile')
    path = Path(folder) / 'fastdds_default_writer_times.xml'
    path.write_text(stripped)
    return str(path)


def case_echo(domains: Domains, quick: bool) -> dict:
    """The bare echo with the package's profile (the figure every ratio uses), and beside it,
    alternately, with Fast DDS's default writer timings: what the profile's
    nack_supression_duration saves on a round trip (3 pairs, 1 with ``quick``)."""
    import statistics
    import tempfile

    count = 5000 if quick else 20000
    echo = run_echo(domains, count)
    print(f"echo      bare DDS round trip: {echo['round_trips_per_second']:.0f} round trips/s "
          f"({1e6 / echo['round_trips_per_second']:.0f} us each, {echo['round_trips']})",
          flush=True)
    pairs = []
    with tempfile.TemporaryDirectory() as tmp:
        plain = default_writer_times_profile(tmp)
        for _ in range(1 if quick else 3):
            a = run_echo(domains, count, profile=plain)['round_trips_per_second']
            b = run_echo(domains, count)['round_trips_per_second']
            pairs.append((b / a, a, b))
        echo['writer_times'] = {'pairs': [{'fast_dds_defaults': a, 'package_profile': b}
                                          for _, a, b in pairs],
                                'median_speed_up': statistics.median(p[0] for p in pairs)}
        print('echo      package profile vs Fast DDS default writer times (nack_supression_'
              'duration 5 ms vs 0), round trips/s side by side: ' + ', '.join(
                  f'{b:.0f} vs {a:.0f}' for _, a, b in pairs)
              + f"; median speed-up {echo['writer_times']['median_speed_up']:.2f}", flush=True)
        echo['writer_times']['lockstep'] = _writer_times_lockstep(domains, quick, plain)
    return echo


def _writer_times_lockstep(domains: Domains, quick: bool, plain: str) -> list[dict]:
    """The FOM lockstep loop with the eq. 31 node under Fast DDS's default writer timings
    (``plain``) and under the package profile, alternately (3 pairs, 1 with ``quick``; 3 s
    simulated, 0.5 s with ``quick``), each pair beside a bare echo measured before it. With
    ``plain`` a node keeps the profile it was given and leaves the discovery range as set, so
    both sides run with the range the nodes give rcl with their own profile (SUBNET)."""
    params = {'mode': 'lockstep', 'duration': 0.5 if quick else 3.0,
              **MODEL_PARAMS['fractional'], 'model': 'fractional'}
    pairs = []
    for _ in range(1 if quick else 3):
        rate = run_echo(domains, 5000 if quick else 20000)['round_trips_per_second']
        got = {}
        for key, extra in (('fast_dds_defaults', {'FASTDDS_DEFAULT_PROFILES_FILE': plain}),
                           ('package_profile', {})):
            s = run_plant(domains, params, timeout=600.0,
                          env_extra={'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', **extra})
            got[key] = {k: s.get(k) for k in ('samples_per_second', 'cpu_per_sample_us',
                                              'controller_cpu_per_sample_us')}
        pairs.append({'echo_beside': rate, **got})
        a, b = got['fast_dds_defaults'], got['package_profile']
        print(f"lockstep  FOM, Fast DDS default writer times vs package profile (echo {rate:.0f} "
              f"round trips/s beside): {a['samples_per_second']:.0f} -> "
              f"{b['samples_per_second']:.0f} samples/s, plant CPU {a['cpu_per_sample_us']:.0f} "
              f"-> {b['cpu_per_sample_us']:.0f} us/sample, controller "
              f"{a.get('controller_cpu_per_sample_us') or 0:.0f} -> "
              f"{b.get('controller_cpu_per_sample_us') or 0:.0f}", flush=True)
    return pairs


def case_lockstep(domains: Domains, quick: bool, echo: dict, sim_time: float) -> dict:
    """External node against hosted law, lockstep, at the default control period, each model
    over the same simulated time as the real-time cases (a short run weighs its start, the
    matching and the first samples, and understated the FOM's rate); each external run with
    the mean of bare echoes measured just before and just after it (``echo_beside``, its
    ratio ``ratio_to_echo``), as the machine's speed drifts within a run; the FOM's runs with
    more than :data:`STEAL_LIMIT` host steal are run again (at most :data:`STEAL_RETRIES`
    more), each printed. Then the node-side cost with one RK4 step per
    sample (external)."""
    out = {}
    cases = []
    for model in MODELS:
        params = {'model': model, 'duration': sim_time, **MODEL_PARAMS[model]}
        cases += [(model, params), (f'{model}, hosted', {**params, **HOSTED})]
    cases.append(('delay-free, 1 step/sample', {'model': 'delay-free', 'control_period': 1e-5,
                                                'duration': 0.1 if quick else 0.3}))
    for key, params in cases:
        rate = echo['round_trips_per_second']
        if 'controller' in params:     # hosted: no DDS in the loop
            s = run_plant(domains, {'mode': 'lockstep', **params}, timeout=900.0)
        else:   # external: each run between two echoes, against their mean
            count = 5000 if quick else 20000
            pairs, tried = [], 0
            before = run_echo(domains, count)['round_trips_per_second']
            while len(pairs) < LOCKSTEP_REPEATS.get(key, 1):
                tried += 1
                s = run_plant(domains, {'mode': 'lockstep', **params}, timeout=900.0)
                after = run_echo(domains, count)['round_trips_per_second']
                rate = (before + after) / 2
                steal = s.get('host_steal_share') or 0.0
                if (steal > STEAL_LIMIT and key in LOCKSTEP_REPEATS
                        and tried < LOCKSTEP_REPEATS[key] + STEAL_RETRIES):
                    print(f"          ({key}: {s['samples_per_second'] / rate:.2f} of the "
                          f'echo with host steal {100 * steal:.1f} % > '
                          f'{100 * STEAL_LIMIT:g} %: the host, not the loop; again)',
                          flush=True)
                else:
                    pairs.append((s['samples_per_second'] / rate, rate, s))
                before = after
            # the median pair: the machine's speed drifts between and within runs
            pairs.sort(key=lambda p: p[0])
            _, rate, s = pairs[len(pairs) // 2]
            s['ratios_to_echo'] = [round(p[0], 4) for p in pairs]
            s['runs_tried'] = tried
        s['echo_beside'] = rate
        s['ratio_to_echo'] = s['samples_per_second'] / rate
        s['cost_over_round_trip_us'] = 1e6 / s['samples_per_second'] - 1e6 / rate
        out[key] = s
        more = (f" (median of {len(s['ratios_to_echo'])}: " + ', '.join(
            f'{r:.2f}' for r in s['ratios_to_echo']) + ')'
            if len(s.get('ratios_to_echo', ())) > 1 else '')
        print(f"lockstep  {key:26s} T={s['control_period']:g} s: "
              f"{s['samples_per_second']:.0f} samples/s ({s['ratio_to_echo']:.2f} of the echo"
              f"{more}, {rate:.0f} round trips/s beside it), solver {s['solver']}, plant CPU "
              f"{s['cpu_per_sample_us']:.0f} us/sample"
              + (f", controller {s['controller_cpu_per_sample_us']:.0f}"
                 if 'controller_cpu_per_sample_us' in s else '')
              + f" over {s['t']:g} s simulated" + _steal_text(s.get('host_steal_share')),
              flush=True)
    return out


#: External lockstep runs repeated, each beside its own echo, the median pair reported: the
#: FOM's ratio is a target, and one pair varied by 0.1 between runs on a machine with steal.
LOCKSTEP_REPEATS = {'fractional': 3}


def case_pinned(domains: Domains, quick: bool) -> dict:
    """``cpu_affinity`` in lockstep, side by side: each round the bare echo and the lockstep FOM
    loop (eq. 31 node) unpinned, then both pinned (ping and plant on CPU 0, pong and
    controller on CPU 1: ``--cpu`` / ``cpu_affinity``), 3 rounds (1 with ``quick``), which
    pair goes first alternating; each loop against the echo run just before it; a round in
    which either loop had more than :data:`STEAL_LIMIT` host steal is run again (at most
    :data:`STEAL_RETRIES` times, printed, kept as ``rejected_rounds``). Pinning
    speeds the echo too, so the loop is compared with the echo pinned the same way; the gain
    of pinning is the pinned loop's rate over the unpinned one's in the same round, and the
    CPU per sample of both processes. After each pinned loop, :func:`run_null_plant` (a plant
    with no work against the same node, pinned) puts beside it what the loop / echo ratio
    would be with a Python plant whose callback cost nothing (the plant's compiled take of
    the command skips rclpy's path that this plant pays, so the loop may pass it). Skipped
    where this process may not use CPUs 0 and 1."""
    usable = set(os.sched_getaffinity(0))
    if not {0, 1} <= usable:
        print(f'pinned    skipped: this process may use CPUs {sorted(usable)}, not 0 and 1',
              flush=True)
        return {'skipped': True}
    count = 5000 if quick else 20000
    params = {'mode': 'lockstep', 'model': 'fractional', 'duration': 1.0 if quick else 3.0,
              **MODEL_PARAMS['fractional']}
    rounds, rejected, n = [], [], 0
    while len(rounds) < (1 if quick else 3):
        n += 1
        row = {}
        order = (('unpinned', None), ('pinned', (0, 1)))
        for key, cpus in order if n % 2 == 0 else order[::-1]:   # each first in turn
            echo = run_echo(domains, count, cpus=cpus)['round_trips_per_second']
            s = run_plant(domains, {**params, **({'cpu_affinity': 0} if cpus else {})},
                          timeout=600.0,
                          controller_params={'cpu_affinity': 1} if cpus else None)
            row[key] = {'echo': echo, 'samples_per_second': s['samples_per_second'],
                        'ratio_to_echo': s['samples_per_second'] / echo,
                        'plant_cpu_per_sample_us': s['cpu_per_sample_us'],
                        'controller_cpu_per_sample_us': s.get('controller_cpu_per_sample_us'),
                        'host_steal_share': s.get('host_steal_share')}
            if cpus:     # beside it: a Python plant with no work, the same controller node
                null = run_null_plant(domains, count, cpus)['round_trips_per_second']
                row[key].update(null_plant=null, null_plant_ratio_to_echo=null / echo)
        row['gain'] = row['pinned']['samples_per_second'] / row['unpinned']['samples_per_second']
        steal = max(row[k]['host_steal_share'] or 0.0 for k in ('unpinned', 'pinned'))
        again = steal > STEAL_LIMIT and len(rejected) < STEAL_RETRIES   # the host, not the loop
        (rejected if again else rounds).append(row)
        print('pinned    lockstep FOM ' + '; '.join(
            f"{k}: echo {r['echo']:.0f}/s, loop {r['samples_per_second']:.0f}/s "
            f"({r['ratio_to_echo']:.2f} of it), CPU plant {r['plant_cpu_per_sample_us']:.0f} / "
            f"controller {r['controller_cpu_per_sample_us'] or 0:.0f} us/sample"
            + _steal_text(r['host_steal_share'])
            + (f"; no-work plant {r['null_plant']:.0f}/s ({r['null_plant_ratio_to_echo']:.2f})"
               if 'null_plant' in r else '')
            for k, r in ((k, row[k]) for k in ('unpinned', 'pinned')))
            + f"; pinned loop / unpinned {row['gain']:.2f}"
            + (f' (host steal {100 * steal:.1f} % > {100 * STEAL_LIMIT:g} %: the host, not the '
               'loop; again)' if again else ''),
            flush=True)
    out = {'rounds': rounds, 'rejected_rounds': rejected,
           'gain': statistics.median(r['gain'] for r in rounds)}
    for key in ('unpinned', 'pinned'):
        out[f'{key}_ratio_to_echo'] = statistics.median(r[key]['ratio_to_echo'] for r in rounds)
    out['null_plant_ratio_to_echo'] = statistics.median(
        r['pinned']['null_plant_ratio_to_echo'] for r in rounds)
    print(f"pinned    median of {len(rounds)}: pinned loop / unpinned loop {out['gain']:.2f}; "
          f"loop / echo unpinned {out['unpinned_ratio_to_echo']:.2f}, pinned "
          f"{out['pinned_ratio_to_echo']:.2f}; a plant with no work against the same node, "
          f"pinned, {out['null_plant_ratio_to_echo']:.2f} of the echo (a Python plant through "
          "rclpy's executor)", flush=True)
    return out


def case_latency(domains: Domains, quick: bool) -> dict:
    """``cpu_dma_latency`` in lockstep, side by side: each round the bare echo and the lockstep
    FOM loop (eq. 31 node) with the nodes' default limit held (0 us: idle CPUs poll) and with
    no request (-1, the echo likewise), 3 rounds (1 with ``quick``), which goes first
    alternating, each loop against the echo run just before it. The gain is the loop's rate
    with the limit over without it in the same round. Skipped where this process may not
    write ``/dev/cpu_dma_latency`` (the nodes then hold nothing either)."""
    from fohssv_sim.ros.host import CPU_LATENCY_DEVICE, NO_LATENCY_LIMIT, cpu_latency_limit

    if not os.access(CPU_LATENCY_DEVICE, os.W_OK):
        print(f'latency   skipped: {CPU_LATENCY_DEVICE} is not writable here', flush=True)
        return {'skipped': True}
    count = 5000 if quick else 20000
    params = {'mode': 'lockstep', 'model': 'fractional', 'duration': 1.0 if quick else 3.0,
              **MODEL_PARAMS['fractional']}
    rounds = []
    for n in range(1 if quick else 3):
        row = {}
        order = (('none', -1), ('held', 0))
        for key, us in order if n % 2 == 0 else order[::-1]:   # each first in turn
            # the limit is system-wide: another process holding one makes "none" a held run
            before = cpu_latency_limit()
            e = run_echo(domains, count, latency=us)
            echo = e['round_trips_per_second']
            s = run_plant(domains, {**params, 'cpu_dma_latency': us}, timeout=600.0,
                          controller_params={'cpu_dma_latency': us})
            after = cpu_latency_limit()
            expected = None if us < 0 else us
            if e.get('cpu_dma_latency') != expected or s.get('cpu_dma_latency') != expected:
                print(f'latency   {key}: the echo held {e.get("cpu_dma_latency")}, the plant '
                      f'{s.get("cpu_dma_latency")}, not {expected}', flush=True)
            if us < 0 and any(x is not None and x < NO_LATENCY_LIMIT for x in (before, after)):
                print(f'latency   none: another process held a limit ({before} us before, '
                      f'{after} us after): this round does not measure "none"', flush=True)
            row[key] = {'echo': echo, 'samples_per_second': s['samples_per_second'],
                        'limit_before_us': before, 'limit_after_us': after,
                        'echo_cpu_dma_latency': e.get('cpu_dma_latency'),
                        'ratio_to_echo': s['samples_per_second'] / echo,
                        'plant_cpu_per_sample_us': s['cpu_per_sample_us'],
                        'controller_cpu_per_sample_us': s.get('controller_cpu_per_sample_us'),
                        'cpu_dma_latency': s.get('cpu_dma_latency'),
                        'host_steal_share': s.get('host_steal_share')}
        row['gain'] = row['held']['samples_per_second'] / row['none']['samples_per_second']
        row['echo_gain'] = row['held']['echo'] / row['none']['echo']
        rounds.append(row)
        print('latency   lockstep FOM ' + '; '.join(
            f"{label}: echo {r['echo']:.0f}/s, loop {r['samples_per_second']:.0f}/s "
            f"({r['ratio_to_echo']:.2f} of it), CPU plant {r['plant_cpu_per_sample_us']:.0f} / "
            f"controller {r['controller_cpu_per_sample_us'] or 0:.0f} us/sample"
            + _steal_text(r['host_steal_share'])
            for label, r in (('no request', row['none']), ('0 us held', row['held'])))
            + f"; loop held / none {row['gain']:.2f}, echo {row['echo_gain']:.2f}", flush=True)
    out = {'rounds': rounds, 'gain': statistics.median(r['gain'] for r in rounds),
           'echo_gain': statistics.median(r['echo_gain'] for r in rounds)}
    for key in ('none', 'held'):
        out[f'{key}_ratio_to_echo'] = statistics.median(r[key]['ratio_to_echo'] for r in rounds)
        out[f'{key}_samples_per_second'] = statistics.median(r[key]['samples_per_second']
                                                             for r in rounds)
    print(f"latency   median of {len(rounds)}: loop held / none {out['gain']:.2f}, echo "
          f"{out['echo_gain']:.2f}; loop / echo: none {out['none_ratio_to_echo']:.2f}, held "
          f"{out['held_ratio_to_echo']:.2f}", flush=True)
    return out

