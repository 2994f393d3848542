"""``bench/bench_ros.py``'s target rows (the issues' targets: measured, goal, pass) from the
cases' results, and the machine floor's rows beside them (printed, not held to a goal)."""

from __future__ import annotations


def _attempt_text(s: dict) -> str:
    """For a target row: which attempt of a re-run case it reads (empty for the first)."""
    n = len(s.get('attempts', ()))
    if n < 2:
        return ''
    before = ', '.join(f"{100 * (a['deadline_miss_rate'] or 0):.2f} % late with "
                       f"{1e3 * (a['host_steal_seconds'] or 0):.0f} ms stolen"
                       for a in s['attempts'][:-1])
    return f" [attempt {s['attempt']}; before: {before}]"


def _row(name: str, value: float, goal: str, ok: bool, fmt: str = '{:.3f}') -> dict:
    return {'target': name, 'measured': value, 'goal': goal, 'pass': bool(ok),
            'text': fmt.format(value)}


def floor_rows(start: dict, end: dict) -> list[dict]:
    """The machine floor beside the targets (printed, not held to a goal): the misses of the
    no-work loop with the hosted plant's schedule, at the start and the end of the run."""
    rows = []
    for when, floor in (('start', start), ('end', end)):
        for sched, w in floor.items():
            rows.append(_row(f'machine floor ({when}, {sched}): no-work loop on the hosted '
                             'schedule, misses', 100 * w['miss_rate'], 'printed', True,
                             '{:.2f} %'))
    return rows


def targets(sim_time: float, lockstep: dict, realtime: list[dict], margin: list[dict],
            rate: dict, inplant: dict, pinned: dict | None = None) -> list[dict]:
    rows = []
    for s in realtime:
        name = f"realtime {s['model']} T={s['control_period']:g} s {s['how']}{_attempt_text(s)}"
        if s['how'] == 'hosted' and s['control_period'] < 5e-4:
            rows.append(_row(f'{name}: achieved real-time factor',
                             s['achieved_real_time_factor'], '>= 0.999',
                             s['achieved_real_time_factor'] >= 0.999))
            rows.append(_row(f'{name}: deadline misses', 100 * s['deadline_miss_rate'],
                             '<= 0.1 %', s['deadline_miss_rate'] <= 0.001, '{:.2f} %'))
            rows.append(_row(f'{name}: plant CPU / control period', s['cpu_share_of_period'],
                             '<= 0.35', s['cpu_share_of_period'] <= 0.35, '{:.2f}'))
        elif s['how'] == 'external' and s['control_period'] >= 5e-4:
            rows.append(_row(f'{name}: deadline misses', 100 * s['deadline_miss_rate'],
                             '<= 0.1 %', s['deadline_miss_rate'] <= 0.001, '{:.3f} %'))
            rows.append(_row(f'{name}: ran {sim_time:g} s, no lag stop', s['t'],
                             'completes', s['exit_code'] == 0, 'to t={:g} s'))
    for s in margin:
        rows.append(_row(f"hosted {s['model']} T=1e-4 s real_time_factor 2{_attempt_text(s)}: "
                         'misses',
                         100 * s['deadline_miss_rate'], '<= 1 %',
                         s['deadline_miss_rate'] <= 0.01, '{:.2f} %'))
    best = rate['best_rate_hz']
    rows.append(_row('highest external-node rate sustained (FOM)', best or 0.0, 'printed',
                     True, '{:.0f} Hz'))
    fom = lockstep['fractional']
    rows.append(_row('lockstep FOM external node / bare DDS round trips',
                     fom['ratio_to_echo'], '>= 0.85', fom['ratio_to_echo'] >= 0.85, '{:.2f}'))
    if pinned and not pinned.get('skipped'):   # the same, both loops pinned (case_pinned)
        r = pinned['pinned_ratio_to_echo']
        rows.append(_row(f"the same, loop and echo pinned (cpu_affinity; median of "
                         f"{len(pinned['rounds'])})", r, '>= 0.85', r >= 0.85, '{:.2f}'))
        rows.append(_row('a Python plant with no work (the echo ping) against the same node, '
                         'pinned / echo', pinned['null_plant_ratio_to_echo'], 'printed', True,
                         '{:.2f}'))
    samples = round(sim_time / 1e-4)
    for pair in inplant['realtime_hosted']:
        counts, rec = pair['bag_counts'], pair['recorded']
        got = (counts.get('/state', 0), counts.get('/planing_force', 0),
               counts.get('/command', 0))
        rows.append(_row(f"hosted {pair['model']} T=1e-4 s recorded in-plant: states, forces, "
                         'commands in the bag', got[0], f'{samples + 1}/{samples + 1}/{samples}',
                         got == (samples + 1, samples + 1, samples),
                         f'{got[0]}/{got[1]}/{got[2]}'))
        rows.append(_row(f"hosted {pair['model']} T=1e-4 s recorded in-plant{_attempt_text(rec)}: "
                         'deadline misses',
                         100 * rec['deadline_miss_rate'], '<= 0.1 %',
                         rec['deadline_miss_rate'] <= 0.001, '{:.2f} %'))
    demo = inplant['demo_loop']
    rows.append(_row('demo loop recorded in-plant / unrecorded lockstep loop', demo['ratio'],
                     '<= 1.2', demo['ratio'] <= 1.2, '{:.2f}'))
    return rows

