"""Orbit classification on signals whose nature is known in closed form."""

import numpy as np
import pytest

from fohssv_sim.analysis.orbits import classify, local_maxima, zero_one_test

T = np.linspace(0.0, 1.0, 200_001)


def test_local_maxima_are_refined_to_the_true_peak():
    f = 37.3
    t, peaks = local_maxima(T, np.sin(2 * np.pi * f * T + 0.3))
    expected_t = (0.25 - 0.3 / (2 * np.pi) + np.arange(60)) / f
    expected_t = expected_t[(expected_t > 0) & (expected_t < 1)]
    assert np.allclose(peaks, 1.0, atol=1e-9)
    assert np.allclose(t, expected_t, atol=1e-7)


def test_period_one_and_period_two_and_three():
    assert classify(T, np.sin(2 * np.pi * 40 * T))[0].label == 'periodic-1'
    y2 = np.sin(2 * np.pi * 40 * T) + 0.6 * np.sin(2 * np.pi * 20 * T)
    assert classify(T, y2)[0].label == 'periodic-2'
    y3 = np.sin(2 * np.pi * 60 * T) + 0.7 * np.sin(2 * np.pi * 20 * T)
    assert classify(T, y3)[0].label == 'periodic-3'


def test_steady_is_one_class_settled_or_converging():
    assert classify(T, 1.8 + 1e-8 * np.sin(2 * np.pi * 40 * T))[0].kind == 'steady'
    decaying = np.exp(-2.0 * T) * np.sin(2 * np.pi * 40 * T)
    cls = classify(T, decaying)[0]
    assert cls.kind == 'steady' and cls.converging
    algebraic = (1.0 + 50 * T) ** -0.85 * np.sin(2 * np.pi * 40 * T)   # fractional-like decay
    assert classify(T, algebraic)[0].kind == 'steady'


def test_the_steady_tolerance_is_relative_to_the_state_scale():
    # the same relative motion (1e-6 of the level) is steady at any level and in any unit;
    # an absolute tolerance would call it steady at one scale and periodic at another
    ripple = np.sin(2 * np.pi * 40 * T)
    for level in (1e-3, 1.87, 1e4):
        y = level * (1.0 + 1e-6 * ripple)
        cls = classify(T, y)[0]
        assert cls.kind == 'steady', level
        assert cls.tolerance == pytest.approx(1e-4 * level * (1 + 1e-6))
        assert classify(T, level * (1.0 + 1e-3 * ripple))[0].label == 'periodic-1'
    # an explicit scale (a state whose steady value is 0)
    assert classify(T, 1e-6 * ripple, scale=1.0)[0].kind == 'steady'
    assert classify(T, 1e-6 * ripple)[0].label == 'periodic-1'


def logistic(n, r=4.0, x=0.3):
    out = np.empty(n)
    for i in range(n):
        x = r * x * (1 - x)
        out[i] = x
    return out


def test_zero_one_test_separates_chaos_from_regular_motion():
    assert zero_one_test(logistic(2000)) > 0.9                        # chaotic map
    n = np.arange(2000)
    assert abs(zero_one_test(np.sin(2 * np.pi * n / 7))) < 0.1        # periodic
    assert abs(zero_one_test(np.sin(0.7 * n) + np.sin(np.sqrt(2) * n))) < 0.1   # quasi-periodic
    assert np.isnan(zero_one_test(np.ones(5)))


def test_aperiodic_signal_reports_k():
    # a signal whose maxima follow the logistic map: no period, K near 1
    x = logistic(400)
    t = np.arange(400 * 10) / 4000.0
    y = np.repeat(x, 10) * np.sin(np.pi * (np.arange(4000) % 10) / 10) ** 2
    cls, peaks = classify(t, y)
    assert cls.kind == 'aperiodic' and cls.k01 > 0.8
    assert peaks.size > 300


@pytest.mark.parametrize('p', [1, 2, 4])
def test_period_of_a_sampled_map_orbit(p):
    # logistic map in its period-p windows: r = 3.2 (2), 3.5 (4), 2.8 (1)
    r = {1: 2.8, 2: 3.2, 4: 3.5}[p]
    x = logistic(3000, r)[-400:]
    t = np.arange(400 * 10) / 4000.0
    y = np.repeat(x, 10) * np.sin(np.pi * (np.arange(4000) % 10) / 10) ** 2
    assert classify(t, y)[0].label == f'periodic-{p}'


def test_a_window_without_maxima_is_steady_only_below_the_tolerance_or_shrinking():
    # steady: the peak-to-peak range below steady_rtol of the state's scale, or a range that
    # still shrinks. A monotone algebraic approach (alpha = 0.70 at V = 84.5: range 1.6e-4 m/s
    # over the window, above 1e-5 of w's scale 1.87 m/s) has no local maxima and shrinks.
    t = np.linspace(1.5, 2.0, 12501)
    shape = t ** -0.7 - 2.0 ** -0.7          # decreasing, derivative shrinking
    amp = 1.5 ** -0.7 - 2.0 ** -0.7          # its range over the window, by hand
    slow = 1.87 + 1.6e-4 * shape / amp
    cls, peaks = classify(t, slow, steady_rtol=1e-5)
    assert peaks.size == 0 and abs(cls.amplitude - 1.6e-4) < 1e-12
    assert cls.kind == 'steady' and cls.converging
    settled = 1.87 + 5e-6 * shape / amp      # the same approach, below the tolerance
    cls = classify(t, settled, steady_rtol=1e-5)[0]
    assert cls.kind == 'steady' and not cls.converging
    ramp = 1.87 + 1e-3 * (t - 1.5)           # no maxima, range not shrinking
    cls, _ = classify(t, ramp, steady_rtol=1e-5)
    assert cls.kind == 'drifting' and cls.label == 'drifting'
