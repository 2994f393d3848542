"""Where a real-time plant's late samples come from: the hosted plant under a kernel trace.

A hosted plant at 1e-4 s sleeps between bursts of samples; a burst comes late when the
pacing thread wakes late. Linux's scheduler and timer events (ftrace, ``/sys/kernel/tracing``,
root only) say why, for every late wake-up of the pacing thread:

* **vcpu** (the host held the vCPU): the thread's timer fired late while its CPU had nothing
  else to do. Every timer of that CPU (its own scheduler tick too) fires late with it: the
  virtual CPU was not running, which is the hypervisor's steal, and nothing inside this
  machine (priority, preemption model, the plant's code) changes it;
* **irq** (interrupts held off): the thread's timer fired late while another task ran on its
  CPU (a kernel path with interrupts disabled, or the host stopping the vCPU during it);
* **task** (another task held the CPU): the thread was woken on time and waited, runnable,
  while other tasks ran on its CPU (with the tasks named): the kernel's preemption model or a
  higher priority (woken, and its CPU ran nothing else meanwhile: **vcpu**);
* **work** (its own work): the thread ran without a break for longer than the threshold.
  A host stall while it runs looks the same unless a timer of that CPU came due meanwhile
  and fired late (then **vcpu**, as long as that timer was late, the span beside it): the
  trace cannot tell the rest apart.

Each is listed with when it was due (``at``) and how late it came (``seconds``). Only a
sleeping thread's timers and the scheduler tick are read for lateness (a timer moved forward
in its own callback, as the deadline server's, has no new start to read from). Besides the
pacing thread, every CPU's late timers are listed (``cpu_stalls``): a vCPU not running shows
on all its timers at once, whichever thread was waiting. A trace whose buffer overflowed
says so (``lost_events``).

    sudo python tools/diag/stalls.py [--model delayed] [--runs 3] [--seconds 10] [--out FILE]
                                [--keep DIR]

Prints the bare DDS echo's rate (as ``bench_ros.py``, to scale by) and, per run, the plant's
deadline misses, worst lateness and host steal beside the late wake-ups by cause, and writes
them to ``--out`` (JSON). The tracer's state is restored at the end. The analysis
(:func:`analyse`) reads any ``trace`` text with the events of :data:`EVENTS`.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import sys
from pathlib import Path

TRACING = Path('/sys/kernel/tracing')

#: The events the analysis reads (scheduler switches and wake-ups, high-resolution timers).
EVENTS = ('sched:sched_switch', 'sched:sched_waking', 'timer:hrtimer_start',
          'timer:hrtimer_expire_entry')

#: The timers whose lateness is read: a sleeping thread's and the scheduler tick's (others,
#: e.g. the deadline server's, are moved forward in their callbacks without a new start).
_WITNESSES = ('hrtimer_wakeup', 'tick_nohz_handler', 'tick_sched_timer')

#: A sleep of the pacing thread shorter than this (s) is a burst's: the run is being paced.
_SHORT_SLEEP = 0.005

_LINE = re.compile(r'^\s*(.+?)-(\d+)\s+\[(\d+)\]\s+\S+\s+([\d.]+): (\w+): (.*)$')
_KV = re.compile(r'(\w+)=(\S+)')
_LOST = re.compile(r'\[LOST (\d+) EVENTS\]')


def events(lines, lost: list[int] | None = None):
    """(pid, cpu, seconds, event, fields) of each event line of an ftrace text; the counts
    of ``[LOST n EVENTS]`` lines (a full buffer) are appended to ``lost``."""
    for line in lines:
        m = _LINE.match(line)
        if m is None:
            gone = _LOST.search(line)
            if gone is not None and lost is not None:
                lost.append(int(gone.group(1)))
            continue
        _comm, pid, cpu, ts, name, rest = m.groups()
        # sched_switch: prev_* before '==>', next_* after
        yield int(pid), int(cpu), float(ts), name, dict(_KV.findall(rest))


def pacing_thread(evs: list, prio: int) -> int | None:
    """The thread switched out most often at kernel priority ``prio`` (99 - SCHED_FIFO
    priority): the plant's pacing thread."""
    counts = collections.Counter(
        int(f['prev_pid']) for _, _, _, name, f in evs
        if name == 'sched_switch' and f.get('prev_prio') == str(prio))
    return counts.most_common(1)[0][0] if counts else None


def _paced_window(evs: list, tid: int | None, paced: float | None) -> tuple[float, float]:
    """The ``paced`` seconds of the trace in which the pacing thread slept most often for
    less than :data:`_SHORT_SLEEP` (a burst's sleep, every 0.5 ms at the defaults, where
    start-up and shutdown wait 1 ms and more at a time): (first, last) such sleep in it.
    The whole trace when ``paced`` is None."""
    short = [ts for pid, _, ts, name, f in evs if name == 'hrtimer_start' and pid == tid
             and f.get('function') == 'hrtimer_wakeup'
             and int(f['expires']) / 1e9 - ts < _SHORT_SLEEP]
    if paced is None or not short:
        return float('-inf'), float('inf')
    best, first, j = 0, 0, 0
    for i, t in enumerate(short):
        while j < len(short) and short[j] - t <= paced:
            j += 1
        if j - i > best:
            best, first = j - i, i
    return short[first], short[first + best - 1]


class _Thread:
    """The pacing thread's states through the events (sleeping, waiting runnable, running)
    and its late wake-ups by cause."""

    def __init__(self, tid: int | None, threshold: float, begin: float, end: float) -> None:
        self.tid, self.threshold, self.begin, self.end = tid, threshold, begin, end
        self.state, self.since = 'sleeping', None
        self.current: dict[int, str | None] = {}   # CPU -> the task on it (None: idle)
        self.ran_on: dict[int, list] = collections.defaultdict(list)   # while it waited
        self.found: list[dict] = []

    def _add(self, cause: str, at: float, seconds: float, cpu: int, **more) -> None:
        if self.begin <= at <= self.end:
            self.found.append({'cause': cause, 'at': at, 'seconds': seconds, 'cpu': cpu,
                               **more})

    def timer_late(self, cpu: int, ts: float, late: float, idle: bool) -> None:
        """Its timer fired ``late``: while the CPU idled, the vCPU was stopped."""
        self._add('vcpu' if idle else 'irq', ts - late, late, cpu)

    def woken(self, ts: float) -> None:
        if self.state == 'running':     # woken as it runs (a futex it was about to wait on)
            return
        self.state, self.since = 'waiting', ts
        self.ran_on.clear()
        for c, comm in self.current.items():
            self.ran_on[c].append(comm)

    def switch(self, cpu: int, ts: float, f: dict) -> None:
        tid, since = str(self.tid), self.since
        if f['prev_pid'] == tid:
            if self.state == 'running' and since is not None and ts - since > self.threshold:
                self._add('work', since, ts - since, cpu)
            self.state = 'waiting' if f['prev_state'].startswith('R') else 'sleeping'
            self.since = ts
            self.ran_on.clear()
        elif self.state == 'waiting' and f['next_pid'] != tid:
            self.ran_on[cpu].append(f['next_comm'])
        self.current[cpu] = f['next_comm'] if f['next_pid'] != '0' else None
        if f['next_pid'] == tid:
            if self.state == 'waiting' and since is not None and ts - since > self.threshold:
                tasks = sorted({t for t in self.ran_on[cpu] if t})
                # runnable, and its CPU ran nothing else meanwhile: the vCPU did not run
                self._add('task' if tasks else 'vcpu', since, ts - since, cpu, tasks=tasks)
            self.state, self.since = 'running', ts


def _merged(late: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """(fire time, lateness) of late timers, those fired within 1 ms of each other as one
    stall (its worst lateness)."""
    merged: list[list[float]] = []
    for ts, seconds in sorted(late):
        if merged and ts - merged[-1][0] < 1e-3:
            merged[-1][1] = max(merged[-1][1], seconds)
        else:
            merged.append([ts, seconds])
    return [(ts, seconds) for ts, seconds in merged]


def analyse(lines, prio: int = 49, threshold: float = 1e-3,
            paced: float | None = None) -> dict:
    """The pacing thread's (:func:`pacing_thread`) late wake-ups longer than ``threshold``
    seconds by cause (module docstring; ``at``: when it was due, ``seconds``: how late),
    every CPU's late timers (``cpu_stalls``: the fire time and the worst lateness of the
    timers that fired within 1 ms of each other) and ``lost_events`` (a full trace buffer
    drops events: then some causes are missing). ``paced``: the run's wall time (the
    plant's summary): wake-ups count within the paced window only (:func:`_paced_window`)."""
    lost: list[int] = []
    evs = list(events(lines, lost))
    tid = pacing_thread(evs, prio)
    thread = _Thread(tid, threshold, *_paced_window(evs, tid, paced))
    timers: dict[str, tuple[int, int, str]] = {}   # hrtimer -> (expires ns, starter, function)
    late_by_cpu: dict[int, list] = collections.defaultdict(list)   # (fire time, lateness)
    for pid, cpu, ts, name, f in evs:
        if name == 'hrtimer_start':
            timers.pop(f['hrtimer'], None)
            if f.get('function') in _WITNESSES:
                timers[f['hrtimer']] = (int(f['expires']), pid, f['function'])
        elif name == 'hrtimer_expire_entry':
            started = timers.pop(f.get('hrtimer'), None)
            if started is None:        # not a witness (every start drops the address's last)
                continue
            late = (int(f['now']) - started[0]) / 1e9
            if threshold < late < 1e3:
                late_by_cpu[cpu].append((ts, late))
                # the thread's own sleep (a tick re-armed in an interrupt while it ran
                # carries its pid too, and is not)
                if started[1] == tid and started[2] == 'hrtimer_wakeup':
                    thread.timer_late(cpu, ts, late, idle=pid == 0)
        elif name == 'sched_waking' and tid is not None and int(f['pid']) == tid:
            thread.woken(ts)
        elif name == 'sched_switch':
            thread.switch(cpu, ts, f)
    for f in thread.found:   # a span of work through which a timer of its CPU came due and
        if f['cause'] != 'work':         # fired late: the vCPU stopped as it ran
            continue
        stopped = [(ts - late, late) for ts, late in late_by_cpu.get(f['cpu'], ())
                   if f['at'] <= ts - late <= f['at'] + f['seconds']]
        if stopped:
            due, late = max(stopped, key=lambda d: d[1])
            f.update(cause='vcpu', at=due, seconds=late, span=f['seconds'])
    return {'pacing_thread': tid, 'late_wakeups': _one_per_stall(thread.found),
            'cpu_stalls': {cpu: _merged(late) for cpu, late in sorted(late_by_cpu.items())},
            'lost_events': sum(lost)}


def _one_per_stall(found: list[dict]) -> list[dict]:
    """The late wake-ups in time order, overlapping ones of one cause as one, the longest
    (a stop of the vCPU as the thread ran shows both as a span of work through a late
    timer and as its own timer firing late)."""
    out: list[dict] = []
    for f in sorted(found, key=lambda f: f['at']):
        last = out[-1] if out else None
        if (last is not None and f['cause'] == last['cause'] and f['cpu'] == last['cpu']
                and f['at'] < last['at'] + last['seconds']):
            if f['seconds'] > last['seconds']:
                out[-1] = dict(f)
        else:
            out.append(dict(f))
    return out


def by_cause(found: list[dict]) -> dict[str, dict]:
    """Count, total and longest seconds of the late wake-ups per cause."""
    out: dict[str, dict] = {}
    for f in found:
        c = out.setdefault(f['cause'], {'count': 0, 'seconds': 0.0, 'longest': 0.0})
        c['count'] += 1
        c['seconds'] += f['seconds']
        c['longest'] = max(c['longest'], f['seconds'])
    return out


def _write(name: str, text: str, append: bool = False) -> None:
    fd = os.open(TRACING / name, os.O_WRONLY | (os.O_APPEND if append else os.O_TRUNC))
    try:
        os.write(fd, text.encode())
    finally:
        os.close(fd)


def _read(name: str) -> str:
    return (TRACING / name).read_text()


def _saved() -> dict[str, str]:
    """What :func:`_start` changes, to put back: tracing on or off, the clock (the bracketed
    one of ``trace_clock``), the enabled events and the buffer size."""
    clock = _read('trace_clock')
    return {'tracing_on': _read('tracing_on').strip(),
            'trace_clock': clock.split('[', 1)[1].split(']', 1)[0] if '[' in clock else 'local',
            'set_event': _read('set_event'),
            'buffer_size_kb': _read('buffer_size_kb').split()[0]}


def _start() -> None:
    _write('tracing_on', '0')
    _write('trace', '')
    _write('buffer_size_kb', '65536')
    _write('set_event', '')
    for ev in EVENTS:
        _write('set_event', ev, append=True)
    _write('trace_clock', 'mono')
    _write('tracing_on', '1')


def _restore(saved: dict[str, str]) -> None:
    _write('tracing_on', '0')
    _write('trace', '')
    _write('set_event', '')
    for ev in saved['set_event'].split():
        _write('set_event', ev, append=True)
    _write('trace_clock', saved['trace_clock'])
    _write('buffer_size_kb', saved['buffer_size_kb'])
    _write('tracing_on', saved['tracing_on'])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--model', default='delayed', choices=('delay-free', 'delayed',
                                                           'fractional'))
    ap.add_argument('--runs', type=int, default=3)
    ap.add_argument('--seconds', type=float, default=10.0, help='simulated time of each run')
    ap.add_argument('--threshold', type=float, default=1e-3,
                    help='a wake-up later than this (s) is listed')
    ap.add_argument('--priority', type=int, default=50,
                    help="the plant's realtime_priority (SCHED_FIFO, 1-99)")
    ap.add_argument('--out', type=Path)
    ap.add_argument('--keep', type=Path, help='a folder to keep each run\'s trace text in '
                    '(run-N.txt, about 20 MB each), to read again with analyse()')
    args = ap.parse_args()
    if not (TRACING / 'set_event').exists() or not os.access(TRACING / 'set_event', os.W_OK):
        print(f'stalls: needs write access to {TRACING} (root, tracefs mounted)',
              file=sys.stderr)
        return 2
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'bench'))
    import ros_runs as b  # bench/ros_runs.py: bench_ros.py's processes

    saved = _saved()
    domains, runs = b.Domains(), []
    # the bare DDS echo of this machine now, beside the runs (as bench_ros.py prints it)
    echo = b.run_echo(domains, 20000)['round_trips_per_second']
    print(f'echo      bare DDS round trip: {echo:.0f} round trips/s', flush=True)
    try:
        for i in range(args.runs):
            _start()
            params = b._realtime_params(args.model, 1e-4, args.seconds,
                                        realtime_priority=args.priority, **b.HOSTED)
            s = b.run_plant(domains, params, timeout=60 + 3 * args.seconds)
            _write('tracing_on', '0')
            text = (TRACING / 'trace').read_text(errors='replace')
            if args.keep:
                args.keep.mkdir(parents=True, exist_ok=True)
                (args.keep / f'run-{i + 1}.txt').write_text(text)
            found = analyse(text.splitlines(), prio=99 - args.priority,
                            threshold=args.threshold, paced=s.get('wall_time'))
            causes = by_cause(found['late_wakeups'])
            runs.append({'summary': s, **found, 'by_cause': causes})
            print(b._realtime_line(f'run {i + 1} {args.model}', s), flush=True)
            for cause in ('vcpu', 'irq', 'task', 'work'):
                c = causes.get(cause)
                if c:
                    print(f"          {cause}: {c['count']} late wake-ups, "
                          f"{1e3 * c['seconds']:.1f} ms in all, longest "
                          f"{1e3 * c['longest']:.1f} ms", flush=True)
            if found['lost_events']:
                print(f"          the trace buffer lost {found['lost_events']} events: some "
                      'late wake-ups may be missing or misread', flush=True)
            for cpu, stalls in found['cpu_stalls'].items():
                print(f'          cpu {cpu}: {len(stalls)} stalls > {1e3 * args.threshold:g} '
                      'ms (every timer late): ' + ', '.join(
                          f'{1e3 * late:.1f} ms at {at:.3f}' for at, late in stalls[:8]),
                      flush=True)
    finally:
        _restore(saved)
    if args.out:
        args.out.write_text(json.dumps({'model': args.model, 'echo_round_trips_per_second':
                                        echo, 'runs': runs}, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
