"""``bench/bench_ros.py``'s real-time cases: the external node and the hosted law at 1e-4 s
and 1e-3 s (:func:`case_realtime`), the margin at real_time_factor 2 (:func:`case_margin`),
the highest external-node rate (:func:`case_external_rate`), in-plant recording against
none (:func:`case_inplant_recording`, with the demo's lockstep loop) and the normal scheduler
(:func:`case_fifo`)."""

from __future__ import annotations

from pathlib import Path

from ros_runs import (
    HOSTED,
    MODELS,
    Domains,
    _placement,
    _realtime_line,
    _realtime_params,
    _rt_priority_permitted,
    _timed_loop,
    demo_cpus,
    run_plant,
    run_steady,
)


def run_inplant_recording(domains: Domains, quick: bool) -> dict:
    """In-plant recorded vs unrecorded: the demo's loop (FOM, lockstep, eq. 31 node, placed
    as ``make demo`` places them: :func:`demo_cpus`), pairs of runs side by side (5 pairs, 2
    with ``quick``; unrecorded first in even pairs, recorded first in odd ones, so that
    neither gains from its place): each pair's ratio of the loop times (first sample to bag
    closed / to the run's end) and the median pair's, as the machine's speed drifts between
    pairs; each plant's CPU per sample."""
    import statistics
    import tempfile

    params = {'model': 'fractional', 'fractional_order': 0.85, 'speed': 75.0,
              'mode': 'lockstep', 'duration': 0.5 if quick else 2.0}
    cpus = demo_cpus()
    runs: dict[str, list] = {'recorded': [], 'unrecorded': []}
    ratios = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(2 if quick else 5):
            for key in ('unrecorded', 'recorded')[::1 if i % 2 == 0 else -1]:
                extra = {'record': f'{tmp}/run{i}'} if key == 'recorded' else {}
                wall, s = _timed_loop(domains.env(), {**params, **cpus['plant'], **extra},
                                      timeout=900.0, controller_params=cpus['controller'])
                runs[key].append({'loop_time': wall, 'cpu_per_sample_us': s['cpu_per_sample_us'],
                                  'record_waits': s.get('record_waits'),
                                  'record_lost': s.get('record_lost')})
            ratios.append(runs['recorded'][-1]['loop_time'] / runs['unrecorded'][-1]['loop_time'])
    mean = {k: sum(r['loop_time'] for r in v) / len(v) for k, v in runs.items()}
    out = {'runs': runs, 'mean_loop_time': mean, 'pair_ratios': ratios,
           'ratio': statistics.median(ratios), 'duration': params['duration'],
           'cpu_affinity': {k: v.get('cpu_affinity') for k, v in cpus.items()}}
    cpu = {k: sum(r['cpu_per_sample_us'] for r in v) / len(v) for k, v in runs.items()}
    print(f"record    in-plant recorded vs unrecorded lockstep FOM loop ({params['duration']:g} s"
          f" simulated, {len(ratios)} pairs, {_placement(cpus)}): mean {mean['recorded']:.2f} s"
          " / "
          f"{mean['unrecorded']:.2f} s; pair ratios " + ', '.join(f'{r:.2f}' for r in ratios)
          + f", median {out['ratio']:.2f}; plant CPU {cpu['recorded']:.0f} / "
          f"{cpu['unrecorded']:.0f} us/sample", flush=True)
    return out


def case_realtime(domains: Domains, sim_time: float) -> list[dict]:
    """External node and hosted law, real time, 1e-4 s and 1e-3 s, each model."""
    runs = []
    for model in MODELS:
        for period in (1e-4, 1e-3):
            for how, extra in (('external', {}), ('hosted', HOSTED)):
                # the targets: hosted at 1e-4 s, external at 1e-3 s, each <= 0.1 % late
                held = (how == 'hosted') == (period < 5e-4)
                s = run_steady(domains, lambda _, m=model, p=period, e=extra:
                               _realtime_params(m, p, sim_time, **e),
                               f'{model:10s} T={period:g} s {how:8s}',
                               miss_target=0.001 if held else None)
                s['how'] = how
                runs.append(s)
    return runs


def case_margin(domains: Domains, sim_time: float) -> list[dict]:
    """The hosted law at real_time_factor 2, 1e-4 s: the margin."""
    runs = []
    for model in MODELS:
        s = run_steady(domains, lambda _, m=model: _realtime_params(
            m, 1e-4, sim_time, real_time_factor=2.0, **HOSTED),
            f'{model:10s} T=1e-4 s hosted, real_time_factor 2', miss_target=0.01)
        runs.append(s)
    return runs


#: Control periods the external-node search tries, shortest first: 10 kHz down to 1 kHz
#: (multiples of the FOM's 2e-5 s step that divide the default view_period 0.01 s).
RATE_LADDER = (1e-4, 2e-4, 4e-4, 5e-4, 1e-3)


def case_external_rate(domains: Domains, sim_time: float) -> dict:
    """The shortest period of :data:`RATE_LADDER` at which the FOM with the external node
    runs the whole ``sim_time`` in real time with misses <= 1 % and no lag stop."""
    tried = []
    best = None
    for period in RATE_LADDER:
        s = run_plant(domains, _realtime_params('fractional', period, sim_time),
                      timeout=900.0)
        ok = s['exit_code'] == 0 and s['deadline_miss_rate'] <= 0.01
        tried.append({'control_period': period, 'sustained': ok, 'summary': s})
        print(_realtime_line(f'search    fractional T={period:g} s external', s)
              + (' -> sustained' if ok else ''), flush=True)
        if ok:
            best = period
            break
    if best is None:
        print('search    no period of the ladder sustained real time', flush=True)
    else:
        print(f'search    highest external-node rate sustained: {1 / best:.0f} Hz '
              f'(control_period {best:g} s)', flush=True)
    return {'ladder': list(RATE_LADDER), 'tried': tried, 'best_period': best,
            'best_rate_hz': 1.0 / best if best else None}


def _bag_counts(bag: Path) -> dict[str, int]:
    """Messages per topic in a rosbag2 bag, read with rosbags (an independent reader)."""
    from rosbags.rosbag2 import Reader

    with Reader(bag) as reader:
        return {c.topic: c.msgcount for c in reader.connections}


def case_inplant_recording(domains: Domains, sim_time: float, quick: bool) -> dict:
    """In-plant recording (``record:=PATH``): the hosted plant at 1e-4 s in real time, each
    model, recorded against unrecorded (RTF, misses, CPU share, the bag's message counts);
    and the demo's lockstep loop recorded in-plant against unrecorded (loop time ratio)."""
    import tempfile

    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for model in MODELS:
            pair = {}
            for key in ('unrecorded', 'recorded'):
                def params(attempt: int, m: str = model, k: str = key) -> dict:
                    extra = {'record': f'{tmp}/{m}-{attempt}'} if k == 'recorded' else {}
                    return _realtime_params(m, 1e-4, sim_time, **HOSTED, **extra)

                s = run_steady(domains, params, f'{model:10s} T=1e-4 s hosted {key:10s}',
                               miss_target=0.001)
                s['how'] = f'hosted, {key}'
                pair[key] = s
            # the bag of the recorded attempt the figures read
            counts = _bag_counts(Path(tmp) / f"{model}-{pair['recorded']['attempt'] - 1}")
            pair['bag_counts'] = counts
            pair['model'] = model
            print(f'record    {model:10s} in-plant bag: ' + ', '.join(
                f'{t} {n}' for t, n in sorted(counts.items())), flush=True)
            runs.append(pair)
    return {'realtime_hosted': runs, 'demo_loop': run_inplant_recording(domains, quick)}


def case_fifo(domains: Domains, sim_time: float) -> list[dict]:
    """The same runs with the normal scheduler (``realtime_priority:=0``; the plant's default
    is SCHED_FIFO 50 where permitted): the hosted law at 1e-4 s and the external node at
    1e-3 s, each model: how much of the real-time margin the priority buys."""
    if not _rt_priority_permitted():
        print('realtime  (SCHED_FIFO not permitted here: every run above used the normal '
              'scheduler)')
        return []
    runs = []
    for model in MODELS:
        for how, period, extra in (('hosted', 1e-4, HOSTED), ('external', 1e-3, {})):
            s = run_plant(domains, _realtime_params(model, period, sim_time,
                                                    realtime_priority=0, **extra),
                          timeout=900.0)
            s['how'] = how
            runs.append(s)
            print(_realtime_line(f'{model:10s} T={period:g} s {how}, normal scheduler', s),
                  flush=True)
    return runs

