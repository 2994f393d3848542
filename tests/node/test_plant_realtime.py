"""The real-time plant node in the test process: the watchdog, commands from the future and
stale ones, a state that turns non-finite or leaves its bounds (exit 1), an integer for a
double parameter. The plant is paced as its process paces it (its spin loop); the probe that
answers it spins in its own thread, as a controller process would. (A late controller
process, stopped processes and the scheduler are the process tests'.)"""

from __future__ import annotations

import re

import pytest

from fohssv_controller.state_feedback import StateFeedback

import rosproc

pytestmark = pytest.mark.node

ALONE = {'min_state_subscribers': 0, 'min_command_publishers': 0}


def test_realtime_watchdog_warns_once_and_holds_the_command(graph, capfd):
    # the delayed model: with no command it stays within |w| <= V for more than 0.5 s (the
    # delay-free one leaves it after 0.26 s, and the plant then stops with exit 1)
    plant = graph.plant(model='delayed', mode='realtime', control_period=1e-3,
                        watchdog_timeout=0.2, duration=0.5, **ALONE)
    assert graph.run(plant) == 0
    out = capfd.readouterr().err
    warnings = [ln for ln in out.splitlines() if 'watchdog: no command for' in ln]
    assert len(warnings) == 1, out
    assert 'holding delta_f=0.0 rad, delta_c=0.0 rad' in warnings[0]
    s = rosproc.summary(out)
    assert s['samples_paced'] == 501 and s['t'] == pytest.approx(0.5)
    assert 0.0 <= s['deadline_miss_rate'] <= 1.0


def test_realtime_rejects_commands_from_the_future_and_stale_ones(graph, capfd):
    """Issue 12, defect 14: answers at samples 3, 4, 5 claim t + 1 s (the future), t - 1 s
    and -1e300 s (older than max_command_age); each is rejected, counted and logged, and the
    largest command lag stays that of the good answers."""
    bad = {3: lambda t: t + 1.0, 4: lambda t: t - 1.0, 5: lambda t: -1e300}
    law = StateFeedback()

    def answer(t, x):
        k = round(t / 1e-3)
        return [bad[k](t) if k in bad else t, *law.command(t, x)]

    graph.probe(answer, thread=True)      # as a controller process: served at once
    # 0.1 s of simulated time: the vehicle cannot leave its bounds within it even open loop
    # (it does at 0.26 s), however late the answers come
    plant = graph.plant(model='delay-free', mode='realtime', control_period=1e-3,
                        duration=0.1, max_command_age=0.5, real_time_factor=0.1)
    assert graph.run(plant) == 0
    out = capfd.readouterr().err
    s = rosproc.summary(out)
    rejected = [ln for ln in out.splitlines() if 'rejected command' in ln]
    assert s['stale_commands'] == 3 and s['rejected_commands'] == 3, out
    assert len(rejected) == 3, out
    assert ("stale command: it answers t=1.00" in rejected[0]
            and "after the plant's current sample" in rejected[0]), rejected
    assert 'older than max_command_age=0.5 s' in rejected[1]
    assert 'it answers t=-1e+300 s' in rejected[2]
    assert 0.0 <= s['max_command_lag'] <= 0.5


def test_non_finite_state_stops_the_run_with_exit_1_naming_time_and_state(graph, capfd):
    plant = graph.plant(model='delay-free', mode='realtime', duration=1.0,
                        initial_state=[0.0, 1e307, 0.0, 0.0], **ALONE)
    assert graph.run(plant) == 1
    out = capfd.readouterr().err
    assert re.search(r'simulation failed: state became non-finite at t=1e-05 s: '
                     r'\[z, w, theta, q\] = \[nan, nan, nan, nan\] \(from \[0\.0, 1e\+307',
                     out), out


def test_state_beyond_physical_bounds_stops_the_run_with_exit_1(graph, capfd):
    """Issue 12, defect 7: the largest allowed step (0.01 s) is unstable for RK4 on eq. 17;
    the run used to end at duration with exit 0 and w in the millions."""
    plant = graph.plant(model='delay-free', step=0.01, control_period=0.01, mode='realtime',
                        real_time_factor=100.0, duration=5.0,
                        initial_state=[0.0, 1.0, 0.0, 0.0], **ALONE)
    assert graph.run(plant) == 1
    out = capfd.readouterr().err
    assert re.search(r'simulation failed: state beyond physical bounds at t=\S+ s: '
                     r'\[z, w, theta, q\] = \[.*\] \(\|w\| must stay <= V = 75 m/s', out), out
    assert 'stopping cleanly' not in out


def test_integer_for_a_double_parameter_is_accepted(graph, capfd):
    plant = graph.plant(model='delay-free', speed=80, mode='realtime', control_period=1e-3,
                        duration=0.05, **ALONE)
    assert graph.run(plant) == 0
    assert 'V=80 m/s' in capfd.readouterr().err
