"""The plant's real-time lag stop alone, without a node (its room owns its state): the rule
of the ``max_command_lag`` parameter and of ``LAG_WALL``, counted by hand. An external
controller's commands that lag by more than ``max_command_lag`` control periods for that many
periods, and then for as many periods again without falling, stop the run; a lag that falls
gets ``LAG_WALL`` s of wall time to get under the limit; one command under the limit starts
the count again.

The times are multiples of binary fractions (P = 2**-10 s, wall steps of 2**-12 or 2**-7 s),
so the counts below are exact."""

from __future__ import annotations

import pytest

from fohssv_sim.ros.plant.realtime import LAG_WALL, LagStop

pytestmark = pytest.mark.node

P = 2.0 ** -10       # the control period (s)
LIMIT = 20.0         # max_command_lag (control periods)


def _first_stop(lags, walls):
    """Index of the first command for which the stop says True (commands one period apart,
    command k answering the sample ``lags[k]`` periods old, arriving at ``walls[k]``)."""
    stop = LagStop(LIMIT, P)
    prev = None
    for k, (lag, wall) in enumerate(zip(lags, walls, strict=True)):
        now = k * P
        if stop.over(now, now - lag * P, wall, prev):
            return k
        prev = wall
    return None


def test_a_lag_that_stays_over_the_limit_stops_after_twice_the_limit():
    # over since command 0; over for LIMIT periods at command 20 (the span begins); as many
    # periods again without falling at command 40
    n = 100
    assert _first_stop([25.0] * n, [k * 2.0 ** -12 for k in range(n)]) == 40


def test_a_falling_lag_gets_lag_wall_seconds():
    # the lag falls (the controller catching up) but stays over the limit: the span begins at
    # command 20 (wall 20 steps) and the stop comes LAG_WALL s of wall time later
    step = 2.0 ** -7
    n = 400
    k = _first_stop([200.0 - 0.5 * k for k in range(n)], [k * step for k in range(n)])
    assert LAG_WALL == 1.0
    assert k == 20 + round(LAG_WALL / step) == 148


def test_one_command_under_the_limit_starts_the_count_again():
    # over for commands 0-29 (the span began at 20), under at 30, over again from 31: over
    # the limit for LIMIT periods at 51, as many again at 71
    lags = [25.0] * 30 + [5.0] + [25.0] * 69
    assert _first_stop(lags, [k * 2.0 ** -12 for k in range(100)]) == 71


def test_the_silence_that_began_the_lag_is_kept_until_it_falls():
    stop = LagStop(LIMIT, P)
    assert not stop.over(0.0, 0.0, 0.0, None)            # in time: no span, no gap
    assert stop.gap == 0.0
    assert not stop.over(P, P - 25 * P, 0.5, 0.0)         # after 0.5 s of silence, late
    assert stop.gap == 0.5
    assert not stop.over(2 * P, 2 * P - 25 * P, 0.5 + 2.0 ** -12, 0.5)   # the backlog
    assert stop.gap == 0.5
    assert not stop.over(3 * P, 3 * P, 0.75, 0.5 + 2.0 ** -12)   # under the limit again
    assert stop.gap == 0.0
