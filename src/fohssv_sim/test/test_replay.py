"""The player's pure replay logic (fohssv_sim.bag.replay): pacing and the plant comparison."""

import pytest

from fohssv_sim.bag.replay import compare_plant, pacing_schedule, replay_timeline


def test_pacing_follows_the_log_times_forward_steps_at_the_rate():
    logs = [0, 1_000_000, 1_000_000, 3_000_000]        # ns
    assert pacing_schedule(logs, 1.0) == pytest.approx([0.0, 1e-3, 1e-3, 3e-3])
    assert pacing_schedule(logs, 2.0) == pytest.approx([0.0, 5e-4, 5e-4, 1.5e-3])


def test_pacing_plays_a_reset_at_once_and_rate_zero_all_at_once():
    assert pacing_schedule([0, 2_000_000, 0, 1_000_000], 1.0) == pytest.approx(
        [0.0, 2e-3, 2e-3, 3e-3])
    assert pacing_schedule([0, 5, 10], 0.0) == [0.0, 0.0, 0.0]
    assert pacing_schedule([], 1.0) == []


def test_compare_plant_resolves_model_parameters_and_compares_lists():
    recorded = {'speed': 75.0, 'step': 'auto', 'control_period': 1e-4,
                'initial_state': [0.0, 0.0, 0.0, 0.0]}
    live = {'speed': 75.0, 'step': 2e-5, 'control_period': 1e-4,
            'initial_state': (0.0, 0.0, 0.0, 0.0)}
    assert compare_plant(recorded, live) == []
    live['speed'] = 80.0
    live['initial_state'] = (0.0, 0.1, 0.0, 0.0)
    diffs = compare_plant(recorded, live)
    assert any(d.startswith('speed: recorded 75.0, plant 80.0') for d in diffs), diffs
    assert any(d.startswith('initial_state: ') for d in diffs), diffs


def test_timeline_clock_never_steps_back_on_interleaved_topics():
    """Arrival order: the command answering t_n after the state t_(n+1) (issue 21.2: the
    replayed /clock stepped back about 2000 times per simulated second)."""
    ms = 1_000_000
    order = [('s', 0), ('c', 0), ('s', 1 * ms), ('s', 2 * ms), ('c', 1 * ms), ('c', 2 * ms),
             ('s', 3 * ms), ('c', 3 * ms)]
    dues, clocks = replay_timeline(order, 1.0)
    assert clocks == [0, None, ms, 2 * ms, None, None, 3 * ms, None]
    # each simulated millisecond counted once: 3 ms of run take 3 ms at rate 1
    assert dues == pytest.approx([0, 0, 1e-3, 2e-3, 2e-3, 2e-3, 3e-3, 3e-3])
    assert replay_timeline(order, 0.0)[0] == [0.0] * len(order)


def test_timeline_a_reset_restarts_the_clock_and_old_messages_do_not_move_it():
    ms = 1_000_000
    order = [('s', 0), ('s', 5 * ms), ('s', 0), ('c', 5 * ms), ('s', 1 * ms), ('c', 0),
             ('c', 1 * ms)]
    dues, clocks = replay_timeline(order, 1.0)
    assert clocks == [0, 5 * ms, 0, None, ms, None, None]
    assert dues == pytest.approx([0, 5e-3, 5e-3, 5e-3, 6e-3, 6e-3, 6e-3])
    assert replay_timeline([], 1.0) == ([], [])
