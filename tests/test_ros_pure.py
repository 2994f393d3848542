"""Unit tests of the pure parts of the ROS layer: ``ros/loop.py`` (command checks, the sampled
plant, the real-time pacer), ``ros/options.py`` (plant options, clock and view sampling) and
``ros/ros_params.py`` (ROS typing of table rows, descriptors, integer-to-double coercion),
``ros/bag_options.py`` (the recorder's and the player's options).
No node, no DDS."""

from __future__ import annotations

import math
import os
import sys

import pytest
from rcl_interfaces.msg import ParameterType

from fohssv_sim.params import PARAMETERS, ModelParameters, ParameterError
from fohssv_sim.ros import host
from fohssv_sim.ros.bag_options import (
    PLAYER_PARAMETERS,
    RECORDER_PARAMETERS,
    PlayerOptions,
    RecorderOptions,
    new_bag_path,
)
from fohssv_sim.ros.docs import ros_type_name
from fohssv_sim.ros.host import (
    CPU_LATENCY_DEVICE,
    NO_LATENCY_LIMIT,
    cpu_latency_limit,
    hold_cpu_latency,
    kernel_preemption,
)
from fohssv_sim.ros.loop import (
    CommandRejected,
    HostedLaw,
    SampledPlant,
    answered_time,
    check_command,
)
from fohssv_sim.ros.options import (
    NODE_PARAMETER_BY_NAME,
    NODE_PARAMETERS,
    CpusSpec,
    PlantOptions,
    check_options,
    clock_samples,
    usable_cpus,
    view_samples,
)
from fohssv_sim.ros.pacing import BurstWait, CommandLag, Pacer
from fohssv_sim.ros.ros_params import _coerce, check_value, descriptor, python_value, ros_type


# -- loop.py ----------------------------------------------------------------------------------
def test_command_lag_stops_only_when_the_lag_stays_above_the_limit():
    """Lag in control periods, counted by hand: a command answering sample k while the plant
    is at sample n lags n - k. Limit 3: a burst of 4 commands over the limit spanning less
    than 3 periods passes; a run over it spanning 3 periods stops at its end."""
    T = 1e-3
    lag = CommandLag(limit=3.0, period=T)
    # answered at once (lag 0), then a burst: samples 10..13 answered at plant samples 14..16
    assert not any(lag.add(n * T, n * T) for n in range(10))
    burst = [(14, 10), (15, 11), (16, 12)]       # lags 4, 4, 4 over plant samples 14..16
    assert [lag.add(n * T, k * T) for n, k in burst] == [False, False, False]
    assert not lag.add(17 * T, 16 * T)           # lag 1: back under the limit, run over
    assert lag.worst == pytest.approx(4.0) and lag.over == 3
    # a sustained run: lag 5 from plant sample 20 on; it has lasted 3 periods at sample 23
    assert [lag.add(n * T, (n - 5) * T) for n in (20, 21, 22)] == [False] * 3
    assert lag.add(23 * T, 18 * T)
    assert lag.over_since == pytest.approx(20 * T) and lag.over_least == pytest.approx(5.0)
    assert lag.count == 10 + 3 + 1 + 4
    assert lag.mean == pytest.approx((3 * 4 + 1 + 4 * 5) / 18)
    assert lag.lagging()
    assert lag.summary()['command_lag_worst'] == pytest.approx(5.0)


@pytest.mark.parametrize('name', ['state_feedback', 'lqr', 'fractional_pid'])
def test_hosted_law_gives_the_controllers_own_commands(name):
    """The scalar form of an affine law (eq. 31, lqr) and the per-sample call of any other give
    (to rounding) what the plugin's own command() gives, clamped, sample after sample."""
    from fohssv_sim import control

    law = HostedLaw(control.make(name))
    ref = control.make(name)
    assert law.affine == (name in ('state_feedback', 'lqr'))   # lqr.affine(): its gains
    for k in range(50):
        t = k * 1e-4
        x = (0.01 * math.sin(k), 0.5 * math.cos(0.3 * k), 0.02 * k, -0.1 * k)
        # the scalar form sums the same products in another order: equal to rounding
        assert law.command(t, x) == pytest.approx(ref.command(t, list(x)), rel=1e-13,
                                                  abs=1e-15)
    big = (100.0, 0.0, 0.0, 0.0)                       # eq. 31 asks 1500 rad: clamped
    assert law.command(50e-4, big) == pytest.approx(ref.command(50e-4, list(big)),
                                                    rel=1e-13, abs=1e-15)


def test_hosted_affine_law_refuses_a_non_finite_output():
    from fohssv_sim import control

    law = HostedLaw(control.make('state_feedback'))
    with pytest.raises(control.NonFiniteCommand, match=r'state_feedback: non-finite output '
                       r'at t=0\.5 s'):
        law.command(0.5, (math.inf, 0.0, 0.0, 0.0))




def test_check_command_passes_a_good_command_and_rejects_with_the_reason():
    assert check_command([0.5, 0.1, -0.2], 0.5, 0.5) == (0.5, 0.1, -0.2)
    with pytest.raises(CommandRejected, match='expected 3 values'):
        check_command([0.5, 0.1], 0.5, 0.5)
    with pytest.raises(CommandRejected, match='non-finite'):
        check_command([0.5, math.nan, 0.0], 0.5, 0.5)
    with pytest.raises(CommandRejected, match='non-finite'):
        check_command([math.inf, 0.0, 0.0], 0.5, 0.5)
    with pytest.raises(CommandRejected, match='delta_f=0.6 rad exceeds max_fin_deflection'):
        check_command([0.0, 0.6, 0.0], 0.5, 0.5)
    with pytest.raises(CommandRejected, match='delta_c=-0.7 rad exceeds max_cavitator'):
        check_command([0.0, 0.0, -0.7], 0.5, 0.5)


def test_answered_time_is_the_finite_first_value_or_none():
    assert answered_time([0.25, math.nan]) == 0.25
    assert answered_time([]) is None
    assert answered_time([math.nan, 0.0, 0.0]) is None
    assert answered_time([math.inf]) is None


def test_sampled_plant_holds_the_command_and_advances_one_period():
    params = ModelParameters(model='delay-free')
    sp = SampledPlant(params, 10 * params.step)
    assert sp.hold == 10 and sp.t == 0.0 and sp.command == (0.0, 0.0)
    state, force = [0.0] * 5, [0.0] * 2
    sp.write_sample(state, force)
    assert state[0] == 0.0 and tuple(state[1:]) == tuple(sp.plant.x)
    assert force == [0.0, sp.plant.planing_force]
    assert sp.sample() == (tuple(state), tuple(force))
    sp.command = (0.01, -0.02)
    sp.advance()
    assert sp.samples == 1 and sp.t == pytest.approx(10 * params.step)
    assert sp.reached(10 * params.step) and not sp.reached(20 * params.step)
    assert not sp.reached(0.0)       # 0 = open-ended
    sp.reset()
    assert sp.t == 0.0 and sp.command == (0.0, 0.0) and sp.samples == 0


def test_pacer_counts_misses_and_slips_when_the_backlog_is_too_long():
    p = Pacer(period=1e-3, tolerance=2e-4, max_batch=2, max_backlog=10)
    p.begin(100.0)
    assert p.next_due() == 100.0
    assert p.due(100.0) == 1
    p.published(100.0001)               # on time
    assert (p.produced, p.misses, p.late) == (1, 0, 0)
    p.published(100.0015)               # 0.5 ms late: a miss, not late by a period
    assert (p.misses, p.late) == (1, 0)
    p.published(100.0035)               # 1.5 ms late
    assert (p.misses, p.late) == (2, 1)
    assert p.worst_lateness == pytest.approx(1.5e-3)
    assert p.due(100.1) == 2 and p.slips == 1   # backlog ~98 > 10: moved forward to 2
    assert p.due(p.start - 1.0) == 0


def test_pacer_restart_starts_the_schedule_over_and_keeps_the_runs_counts():
    """A /reset in realtime: the next sample is due at once, the counts are the whole run's
    (they started over before, so the summary gave the part after the reset)."""
    p = Pacer(period=1e-3, tolerance=2e-4, max_batch=2, max_backlog=10)
    p.begin(100.0)
    p.published(100.0)
    p.published(100.0015)               # a miss
    p.restart(200.0)
    assert p.next_due() == pytest.approx(200.0) and p.due(200.0) == 1
    p.published(200.0)                  # on time: the lateness counts from the restart
    assert (p.produced, p.misses, p.late) == (3, 1, 0)
    assert p.worst_lateness == pytest.approx(0.5e-3)



def _wake_ups(b: BurstWait, overshoot: float, seconds: float, start: float = 0.0) -> float:
    """Feed ``b`` the wake-ups of ``seconds`` of wall time whose first sample is ``wait`` plus
    ``overshoot`` late (each wake-up a whole burst apart, as the plant sleeps); the end time."""
    now = start
    while now < start + seconds:
        b.observe(b.wait() + overshoot, now)
        now += b.wait() + b.period
    return now


def test_burst_wait_is_longest_on_a_machine_that_wakes_the_plant_on_time():
    b = BurstWait(period=1e-4, tolerance=1e-3)
    # half the 1 ms tolerance less one period: 4 periods, bursts of 5 samples
    assert b.longest == 4 and b.wait() == pytest.approx(4e-4)
    _wake_ups(b, 0.4e-3, 5.0)                      # 0.4 ms late wake-ups: 0.8 ms < 0.85 ms
    assert b.periods == 4 and b.near_misses == 0
    # at real_time_factor 2 (50 us periods): 9 periods, the same 0.45 ms of wall time
    assert BurstWait(period=5e-5, tolerance=1e-3).longest == 9
    # one sample per wake-up when the tolerance is a single period
    assert BurstWait(period=1e-4, tolerance=1e-4).longest == 0


def test_burst_wait_shortens_for_slow_wake_ups_and_grows_back():
    b = BurstWait(period=1e-4, tolerance=1e-3)
    # every wake-up 0.6 ms late: first samples published wait + 0.6 ms after they were due;
    # under the 0.85 ms near-miss limit for waits of up to 2 periods (0.8 ms), over it from 3
    now = _wake_ups(b, 0.6e-3, 10.0)
    assert b.periods in (2, 3) and b.near_misses > 0
    # the machine is quick again: back to the longest wait, one period per quiet window
    _wake_ups(b, 20e-6, 3.0, start=now)
    assert b.periods == 4


def test_burst_wait_ignores_stalls_no_wait_would_save():
    b = BurstWait(period=1e-4, tolerance=1e-3)
    _wake_ups(b, 2e-3, 5.0)                        # 2 ms stalls: late whatever the wait
    assert b.periods == 4 and b.near_misses == 0


def test_kernel_preemption_from_the_config_the_boot_line_and_debugfs(tmp_path):
    """The running kernel's preemption model as Linux states it: debugfs's bracketed choice
    first, then a preempt= boot parameter (only on a PREEMPT_DYNAMIC kernel: its config or
    uname -v says so), then the build's CONFIG_PREEMPT_* (a config line set to y; '# ... is
    not set' lines are not), from /proc/config.gz or else /boot/config-RELEASE (plain text),
    or uname -v's PREEMPT_RT; the tick from CONFIG_HZ; None for what nothing says. Under
    none and voluntary a SCHED_FIFO thread waits for kernel paths; full, lazy (which defers
    only normal tasks) and rt preempt them."""
    import gzip

    from fohssv_sim.ros.host import PREEMPTIBLE

    def config(*lines: str, gz: bool = True) -> str:
        path = tmp_path / (f'config{len(list(tmp_path.iterdir()))}' + ('.gz' if gz else ''))
        text = '\n'.join(lines) + '\n'
        if gz:
            with gzip.open(path, 'wt') as f:
                f.write(text)
        else:
            path.write_text(text)
        return str(path)

    missing = str(tmp_path / 'missing')

    def model(cfg, cmd=missing, now=missing, boot=missing, version=''):
        return kernel_preemption(cfg, cmd, now, boot_config=boot, version=version)

    none_dynamic = config('CONFIG_PREEMPT_BUILD=y', 'CONFIG_PREEMPT_NONE=y',
                          '# CONFIG_PREEMPT_VOLUNTARY is not set', '# CONFIG_PREEMPT is not set',
                          'CONFIG_PREEMPT_DYNAMIC=y', 'CONFIG_HZ_250=y', 'CONFIG_HZ=250')
    cmdline, debugfs = tmp_path / 'cmdline', tmp_path / 'preempt'
    cmdline.write_text('console=ttyS0 root=/dev/vda rw\n')
    assert model(none_dynamic, str(cmdline)) == ('none', 250)
    cmdline.write_text('console=ttyS0 preempt=full rw\n')
    assert model(none_dynamic, str(cmdline)) == ('full', 250)
    debugfs.write_text('none (voluntary) full lazy\n')
    assert model(none_dynamic, str(cmdline), str(debugfs)) == ('voluntary', 250)
    static = config('CONFIG_PREEMPT_VOLUNTARY=y', 'CONFIG_HZ=1000')
    assert model(static, str(cmdline)) == ('voluntary', 1000)          # not dynamic
    # no config at all: uname -v says the kernel is dynamic, so the boot line counts
    assert model(missing, str(cmdline), version='#1 SMP PREEMPT_DYNAMIC') == ('full', None)
    assert model(missing, str(cmdline)) == (None, None)
    plain = config('CONFIG_PREEMPT_LAZY=y', 'CONFIG_HZ=300', gz=False)  # /boot/config-*
    assert model(missing, boot=plain) == ('lazy', 300)
    assert model(none_dynamic, boot=plain) == ('none', 250)             # /proc's first
    rt = config('CONFIG_PREEMPT=y', 'CONFIG_PREEMPT_RT=y', 'CONFIG_HZ=1000')
    assert model(rt) == ('rt', 1000)
    assert model(missing, version='#1 SMP PREEMPT_RT Tue') == ('rt', None)
    assert model(config('CONFIG_PREEMPT=y')) == ('full', None)
    broken = tmp_path / 'broken.gz'
    broken.write_bytes(b'\x1f\x8b\x08\x00 not gzip')
    assert model(str(broken)) == (None, None)
    assert set(PREEMPTIBLE) == {'full', 'lazy', 'rt'}
    found, hz = kernel_preemption()      # this machine's, where Linux says
    assert found in (None, 'none', 'voluntary', 'full', 'lazy', 'rt') and (hz is None or hz > 0)


# -- options.py -------------------------------------------------------------------------------


def test_plant_options_validate_and_make_whole_numbers_integers():
    o = PlantOptions()
    assert o.mode == 'lockstep' and isinstance(o.min_state_subscribers, int)
    assert PlantOptions(profile=1.0).profile == 1
    with pytest.raises(ParameterError, match='mode'):
        PlantOptions(mode='fast')
    with pytest.raises(ParameterError, match='whole number'):
        PlantOptions(profile=0.5)
    with pytest.raises(ParameterError, match='initial_state'):
        PlantOptions(initial_state=(0.0, 0.0, 0.0))
    assert o.replace(control_period=2e-4).control_period == 2e-4


def test_clock_and_view_samples():
    o = PlantOptions(mode='realtime', control_period=1e-4)
    assert clock_samples(o.replace(clock_period=0.0)) == 1
    assert clock_samples(o.replace(clock_period=1e-3)) == 10
    assert clock_samples(o.replace(clock_period=1e-3, mode='lockstep')) == 1
    with pytest.raises(ParameterError, match='clock_period'):
        clock_samples(o.replace(clock_period=1.5e-4))
    assert view_samples(o.replace(view_period=0.0)) == 0
    assert view_samples(o.replace(view_period=5e-5)) == 1
    assert view_samples(o.replace(view_period=2e-3)) == 20
    with pytest.raises(ParameterError, match='view_period'):
        view_samples(o.replace(view_period=2.5e-4))


def test_check_options_gives_the_steps_per_sample_or_the_reason():
    model = ModelParameters(model='delay-free')
    assert check_options(model, PlantOptions(control_period=5 * model.step)) == 5
    with pytest.raises(ParameterError):
        check_options(model, PlantOptions(control_period=2.5 * model.step))


def test_cpu_affinity_takes_taskset_lists_numbers_and_arrays_of_usable_cpus():
    usable = usable_cpus()
    first, last = usable[0], usable[-1]
    spec = NODE_PARAMETER_BY_NAME['cpu_affinity']
    assert PlantOptions().cpu_affinity == ()
    assert spec.validate('') == spec.validate([]) == ()
    assert spec.validate(last) == spec.validate(str(last)) == spec.validate([last]) == (last,)
    assert spec.validate(f' {last} , {first}') == tuple(sorted({first, last}))
    assert spec.validate(f'{first}-{last}') == tuple(range(first, last + 1))
    assert PlantOptions(cpu_affinity=f'{last},{last}').cpu_affinity == (last,)
    beyond = max(os.cpu_count() or 1, last + 1)      # a CPU this process may not use
    for bad, words in [(beyond, f'names CPU {beyond}, which this process may not use'),
                       (f'{first},{beyond}-{beyond + 1}', f'names CPU {beyond}-{beyond + 1},'),
                       (-1, 'is not a CPU number'), ('1-0', 'is not a CPU number'),
                       ('a', 'is not a CPU number'), ('0,,1', 'is not a CPU number'),
                       (True, 'is not a CPU number'), (1.0, 'is not a CPU number'),
                       ([0.0], 'is not a CPU number'), ('\u00b2', 'is not a CPU number'),
                       # refused at once, never built (a range of 4e9 CPUs)
                       (f'{last}-4294967295', f'names CPU {last + 1}-4294967295,')]:
        with pytest.raises(ParameterError) as err:
            PlantOptions(cpu_affinity=bad)
        text = str(err.value)
        assert text.startswith(f'cpu_affinity={bad!r} {words}'), text
        assert f'may use CPU {first}' in text and "allowed: '' (not pinned)" in text, text


def test_cpu_dma_latency_is_whole_microseconds_from_minus_one():
    assert PlantOptions().cpu_dma_latency == -1         # no system-wide request by default
    assert PlantOptions(cpu_dma_latency=-1).cpu_dma_latency == -1
    assert PlantOptions(cpu_dma_latency=250.0).cpu_dma_latency == 250
    for bad, words in [(-2, 'is outside the allowed range [-1, 1e+06] us'),
                       (2_000_000, 'is outside the allowed range [-1, 1e+06] us'),
                       (0.5, 'is not a whole number')]:
        with pytest.raises(ParameterError) as err:
            PlantOptions(cpu_dma_latency=bad)
        assert str(err.value).startswith(f'cpu_dma_latency={bad!r} {words}'), str(err.value)


def test_cpu_latency_request_where_the_device_is_missing_or_not_linux(tmp_path):
    """No device (a container, not Linux): the request raises (the node says so and runs on),
    the limit is unknown. Where this process may read the real device, the limit is the
    kernel's: a whole number of microseconds, 0 to NO_LATENCY_LIMIT (no request held)."""
    missing = str(tmp_path / 'cpu_dma_latency')
    with pytest.raises(FileNotFoundError):
        hold_cpu_latency(0, missing)
    assert cpu_latency_limit(missing) is None
    if os.access(CPU_LATENCY_DEVICE, os.R_OK):
        assert 0 <= cpu_latency_limit() <= NO_LATENCY_LIMIT


def test_cpu_latency_request_writes_a_native_s32_and_keeps_the_file_open(tmp_path):
    """What goes to the device (a regular file stands in for it here; the graph test holds the
    real one): the limit as a 4-byte signed integer in the machine's byte order, the form
    Linux's PM QoS device reads (Documentation/power/pm_qos_interface.rst), and the file
    stays open: the kernel holds a request only while it is."""
    path = tmp_path / 'device'
    path.write_bytes(b'')
    before = list(host._LATENCY_REQUESTS)
    hold_cpu_latency(7, str(path))
    try:
        fd = host._LATENCY_REQUESTS[-1]
        assert host._LATENCY_REQUESTS[:-1] == before
        assert path.read_bytes() == (7).to_bytes(4, sys.byteorder, signed=True)
        assert os.fstat(fd).st_ino == path.stat().st_ino       # still open
        assert cpu_latency_limit(str(path)) == 7
    finally:
        os.close(host._LATENCY_REQUESTS.pop())


# -- ros_params.py ----------------------------------------------------------------------------

_NAMES = {ParameterType.PARAMETER_DOUBLE: 'double', ParameterType.PARAMETER_INTEGER: 'integer',
          ParameterType.PARAMETER_STRING: 'string',
          ParameterType.PARAMETER_NOT_SET: 'string or double',
          ParameterType.PARAMETER_DOUBLE_ARRAY: 'double[]',
          ParameterType.PARAMETER_STRING_ARRAY: 'string[]',
          ParameterType.PARAMETER_BOOL: 'bool'}


@pytest.mark.parametrize('spec', PARAMETERS + NODE_PARAMETERS + RECORDER_PARAMETERS
                         + PLAYER_PARAMETERS, ids=lambda s: s.name)
def test_ros_type_and_its_documented_name_agree(spec):
    expected = _NAMES[ros_type(spec)]
    if isinstance(spec, CpusSpec):   # dynamically typed too, and takes arrays: its own name
        assert ros_type(spec) == ParameterType.PARAMETER_NOT_SET
        expected = 'integer, string or integer[]'
    assert ros_type_name(spec) == expected


def test_ros_types_of_typical_rows():
    by_name = {s.name: s for s in PARAMETERS}
    assert ros_type(by_name['speed']) == ParameterType.PARAMETER_DOUBLE
    assert ros_type(by_name['step']) == ParameterType.PARAMETER_NOT_SET     # 'auto' or a number
    assert ros_type(by_name['model']) == ParameterType.PARAMETER_STRING
    assert ros_type(NODE_PARAMETER_BY_NAME['profile']) == ParameterType.PARAMETER_INTEGER
    assert ros_type(NODE_PARAMETER_BY_NAME['initial_state']) == \
        ParameterType.PARAMETER_DOUBLE_ARRAY


def test_descriptor_carries_unit_range_and_read_only():
    spec = next(s for s in PARAMETERS if s.name == 'speed')
    d = descriptor(spec)
    assert d.name == 'speed' and '[m/s]' in d.description
    assert d.additional_constraints.startswith('allowed: ')
    assert d.read_only == spec.needs_reset
    # typed by the one check (check_value), so a wrong type gets the row's words, not rclpy's
    assert d.dynamic_typing


def test_one_check_refuses_a_wrong_type_in_the_rows_words():
    by_name = {s.name: s for s in PARAMETERS + NODE_PARAMETERS}
    cases = [('speed', "'abc'", "speed='abc' is a string, not a number"),
             ('speed', "'1e400'", 'is beyond the range of a double (about 1.8e308), so ROS '
              'passed it as a string'),
             ('profile', '1.5', 'profile=1.5 is not a whole number'),
             ('model', '3', 'model=3 is an integer, not a name'),
             ('step', '[1.0]', 'step=[1.0] is an array'),
             ('step', '0.5', 'step=0.5 is outside the allowed range')]
    for name, text, words in cases:
        spec = by_name[name]
        value = _coerce(ros_type(spec), eval(text))
        with pytest.raises(ParameterError) as err:
            check_value(spec, ros_type(spec), value)
        assert words in str(err.value), (name, str(err.value))
    speed = by_name['speed']
    check_value(speed, ros_type(speed), _coerce(ros_type(speed), 80))   # an int is taken


def test_integers_for_double_rows_become_doubles():
    D, DA = ParameterType.PARAMETER_DOUBLE, ParameterType.PARAMETER_DOUBLE_ARRAY
    assert _coerce(D, 80) == 80.0 and isinstance(_coerce(D, 80), float)
    assert _coerce(D, True) is True
    assert _coerce(DA, [0, 1, 2, 3]) == [0.0, 1.0, 2.0, 3.0]
    mixed = [0, 1.5]
    assert _coerce(DA, mixed) is mixed
    assert _coerce(ParameterType.PARAMETER_INTEGER, 3) == 3
    assert _coerce(ParameterType.PARAMETER_INTEGER, 3.0) == 3 and \
        isinstance(_coerce(ParameterType.PARAMETER_INTEGER, 3.0), int)
    assert _coerce(ParameterType.PARAMETER_INTEGER, 3.5) == 3.5
    assert python_value([1.0, 2.0]) == (1.0, 2.0) and python_value('auto') == 'auto'


# -- bag_options.py ---------------------------------------------------------------------------


def test_player_options_normalise_and_refuse_in_the_tables_words():
    o = PlayerOptions(bag_path='runs/x', mode='COMMANDS', topics=('', '/state'),
                      plant_node='/plant/', min_subscribers=2.0)
    assert (o.mode, o.topics, o.plant_node) == ('commands', ('/state',), 'plant')
    assert o.min_subscribers == 2 and isinstance(o.min_subscribers, int)
    cases = [({'bag_path': ''}, "bag_path='' is empty: bag_path is required; allowed: a bag "
              'directory'),
             ({'rate': -1.0}, 'rate=-1.0 is outside the allowed range [0, inf) (republish:'),
             ({'mode': 'loop'}, "mode='loop' is not valid; choose one of 'republish' | "),
             ({'min_command_subscribers': 0}, 'min_command_subscribers=0 is outside the '
              'allowed range [1, inf) subscriptions ('),
             ({'min_subscribers': 1.5}, 'min_subscribers=1.5 is not a whole number; allowed: '
              '[0, inf) subscribers'),
             ({'clock': 'yes'}, "clock='yes' is not true or false; allowed: true | false")]
    for values, words in cases:
        with pytest.raises(ParameterError) as err:
            PlayerOptions(**{'bag_path': 'runs/x', **values})
        assert words in str(err.value)
    with pytest.raises(AttributeError):
        o.rate = 2.0


def test_recorder_options_refuse_what_a_range_cannot_say(tmp_path):
    o = RecorderOptions(bag_path=str(tmp_path / 'new'))
    assert o.chunk_size == 65536 and [t.name for _, t in o.recorded()][:2] == ['state',
                                                                                 'planing_force']
    cases = [({'topics': ['speed']}, "topics=['speed'] is not valid: 'speed' is not a contract "
              'topic; allowed: state, planing_force'),
             ({'topics': []}, 'topics=[] is empty'),
             ({'flush_period': 0.0}, 'flush_period=0.0 is outside the allowed range (0, 60] s '
              '(wall time'),
             ({'chunk_size': 10}, 'chunk_size=10 is outside the allowed range [1024, inf) bytes'),
             ({'command_publishers': 1, 'topics': ['state']},
              'command_publishers=1 needs the command topic recorded')]
    for values, words in cases:
        with pytest.raises(ParameterError) as err:
            RecorderOptions(**values)
        assert words in str(err.value)
    assert RecorderOptions(command_publishers=1, topics=['/ns/state', '/ns/command'])
    assert new_bag_path(o) == tmp_path / 'new'
    with pytest.raises(ParameterError, match="bag_path='.*' exists already: the recorder never "
                       'overwrites a bag; allowed: a path that does not exist'):
        new_bag_path(RecorderOptions(bag_path=str(tmp_path)))


@pytest.mark.parametrize('spec', RECORDER_PARAMETERS + PLAYER_PARAMETERS, ids=lambda s: s.name)
def test_recorder_and_player_rows_are_read_only_with_unit_and_allowed_values(spec):
    d = descriptor(spec)
    assert d.read_only and d.additional_constraints == (
        f'allowed: {spec.range_text()}' + (f' [{spec.unit}]' if spec.unit != '-' else ''))
    assert d.description.startswith(spec.description)


def test_log_lines_give_simulated_time_as_a_person_writes_it():
    from fohssv_sim.ros.loop import time_text

    assert 0.1 + 0.2 != 0.3 and time_text(0.1 + 0.2) == '0.3'    # not 0.30000000000000004
    assert time_text(3 * 0.1) == '0.3' and time_text(1.0) == '1.0' and time_text(2e-5) == '2e-05'
    assert time_text(1234.5678) == '1234.5678'


@pytest.mark.parametrize(('var', 'value', 'expected'), [
    *(('FOHSSV_FAULT_REFUSE_STATE', v, 'expected N or N:M') for v in
      ['x', '-1', '5:0', '1:2:3', '1e3']),
    *(('FOHSSV_FAULT_STALL_STATE', v, 'expected N:S, a whole number 0 <= N <= 1e12 and '
       '0 < S <= 3600 s') for v in ['100', '100:0', '-1:1.5']),
])
def test_a_bad_fault_injection_value_is_refused_naming_it(var, value, expected):
    """The plant's testing aids (ros/faults.py) read from its environment; a bad value is a
    ParameterError (the plant's exit 2, tests/test_graph_publish_failure.py) naming the
    variable, its value and what is allowed."""
    from fohssv_sim.ros.faults import StateFault

    with pytest.raises(ParameterError) as refused:
        StateFault.from_environment({var: value})
    assert f'{var}={value!r}: {expected}' in str(refused.value)


def test_fault_injection_values_that_are_taken():
    from fohssv_sim.ros.faults import refused_publishes, stalled_publish

    assert refused_publishes({}) is None and stalled_publish({'x': '1'}) is None
    assert refused_publishes({'FOHSSV_FAULT_REFUSE_STATE': ' 600 '}) == (600, None)
    assert refused_publishes({'FOHSSV_FAULT_REFUSE_STATE': '300:50'}) == (300, 50)
    assert stalled_publish({'FOHSSV_FAULT_STALL_STATE': '100:1.5'}) == (100, 1.5)
