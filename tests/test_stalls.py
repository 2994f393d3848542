"""tools/diag/stalls.py's reading of a kernel trace: which late wake-up of the pacing thread has
which cause. The trace (examples/ftrace_stalls.txt) is in ftrace's format, lines as this
machine's kernel writes them (times and addresses edited); the expected causes and durations
are read off its lines by hand."""

import importlib.util
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / 'tools' / 'diag' / 'stalls.py'
_spec = importlib.util.spec_from_file_location('bench_stalls', _PATH)
stalls = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(stalls)

# the pacing thread (plant-700, SCHED_FIFO 50: kernel priority 49) on CPU 1, sleeping 0.5 ms
# between bursts; a DDS thread (plant-701) on CPU 0; a kworker on CPU 1
TRACE = (Path(__file__).parent / 'examples' / 'ftrace_stalls.txt').read_text()


def _causes(found):
    return [(f['cause'], round(f['seconds'], 6)) for f in found['late_wakeups']]


def test_each_late_wake_up_of_the_pacing_thread_gets_its_cause():
    found = stalls.analyse(TRACE.splitlines(), prio=49, threshold=1e-3)
    assert found['pacing_thread'] == 700
    # timer due 100.001000, fired 100.004700 on the idle CPU (its tick late with it): the
    # vCPU; woken 100.005000, the kworker ran until 100.007000: another task (the tick the
    # thread's interrupt re-armed, due .005500, fired .006800 while the kworker ran: not the
    # thread's timer); running 100.007505-100.009110 (woken at .008 as it ran): its own work
    # (1.605 ms); running 100.010105-100.013655 while the CPU's tick, due 100.012000, fired
    # at 100.013600: the vCPU stopped as it ran, 1.6 ms
    assert _causes(found) == [('vcpu', 0.0037), ('task', 0.002), ('work', 0.001605),
                              ('vcpu', 0.0016)]
    assert [f['at'] for f in found['late_wakeups']] == pytest.approx(
        [100.001, 100.005, 100.007505, 100.012])
    assert found['late_wakeups'][1]['tasks'] == ['kworker/1:1']
    assert found['late_wakeups'][3]['span'] == pytest.approx(0.00355)
    # CPU 1's late timers (the thread's, 3.7 ms, with the tick, 0.7005 ms, under the
    # threshold: one stall; the re-armed tick, 1.3 ms; the tick, 1.6 ms); CPU 0's deadline
    # server timer is not read (moved forward in its callback, it would read 8.7 ms late)
    assert found['cpu_stalls'] == {1: [(100.0047, 0.0037), (100.0068, 0.0013),
                                       (100.0136, 0.0016)]}
    assert found['lost_events'] == 12
    summary = stalls.by_cause(found['late_wakeups'])
    assert summary['vcpu'] == {'count': 2, 'seconds': pytest.approx(0.0053),
                               'longest': pytest.approx(0.0037)}
    assert summary['work']['count'] == 1


def test_a_higher_threshold_lists_only_the_longer_ones():
    # 1.6 ms of the tick is under it: nothing says the last span was not the thread's work
    found = stalls.analyse(TRACE.splitlines(), prio=49, threshold=0.0019)
    assert _causes(found) == [('vcpu', 0.0037), ('task', 0.002), ('work', 0.00355)]
    assert found['cpu_stalls'] == {1: [(100.0047, 0.0037)]}


def test_late_wake_ups_count_within_the_paced_window_only():
    # the thread's short sleeps start at 100.000100, .000560, .004760, .007060, .009105,
    # .013650: the 4.5 ms holding the most of them are .004760-.009105 (three)
    found = stalls.analyse(TRACE.splitlines(), prio=49, threshold=1e-3, paced=0.0045)
    assert _causes(found) == [('task', 0.002), ('work', 0.001605)]
    # the 1 ms holding the most are .000100-.000560 (two), before any of them
    found = stalls.analyse(TRACE.splitlines(), prio=49, threshold=1e-3, paced=0.001)
    assert _causes(found) == []


def _line(pid: int, cpu: int, ts: float, event: str, fields: str) -> str:
    comm = 'plant' if pid else '<idle>'
    return f'{comm:>16s}-{pid:<7d} [{cpu:03d}] d..2. {ts:.6f}: {event}: {fields}'


def test_a_vcpu_stopped_as_the_thread_ran_is_one_stall():
    # running from 100.020000, the thread arms its timer for 100.020500 and is switched out
    # only at 100.024000: the vCPU stopped; the timer fires at 100.024010, 3.51 ms late
    lines = [
        _line(0, 1, 100.0199, 'sched_waking', 'comm=plant pid=700 prio=49 target_cpu=001'),
        _line(0, 1, 100.02, 'sched_switch', 'prev_comm=swapper/1 prev_pid=0 prev_prio=120 '
              'prev_state=R ==> next_comm=plant next_pid=700 next_prio=49'),
        _line(700, 1, 100.0201, 'hrtimer_start', 'hrtimer=00000000aaaa0009 '
              'function=hrtimer_wakeup expires=100020500000 softexpires=100020500000 mode=ABS'),
        _line(700, 1, 100.024, 'sched_switch', 'prev_comm=plant prev_pid=700 prev_prio=49 '
              'prev_state=S ==> next_comm=swapper/1 next_pid=0 next_prio=120'),
        _line(0, 1, 100.02401, 'hrtimer_expire_entry', 'hrtimer=00000000aaaa0009 '
              'function=hrtimer_wakeup now=100024010000'),
    ]
    found = stalls.analyse(lines, prio=49, threshold=1e-3)
    assert found['pacing_thread'] == 700
    # its timer due 100.020500 fired 3.51 ms late, inside the span: one stop, not two
    assert _causes(found) == [('vcpu', 0.00351)]
    assert found['late_wakeups'][0]['span'] == pytest.approx(0.004)
    assert found['cpu_stalls'] == {1: [(100.02401, pytest.approx(0.00351))]}


def test_a_trace_without_the_priority_finds_no_pacing_thread():
    found = stalls.analyse(TRACE.splitlines(), prio=10, threshold=1e-3)
    assert found['pacing_thread'] is None
    assert found['late_wakeups'] == []
    assert found['cpu_stalls'] == {1: [(100.0047, 0.0037), (100.0068, 0.0013),
                                       (100.0136, 0.0016)]}
