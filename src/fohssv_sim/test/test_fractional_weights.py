"""ABM weights (docs/model.md §5.4) against 50-digit mpmath, at small and very large indices."""

import mpmath as mp
import numpy as np
import pytest

from fohssv_sim.fractional.weights import (
    WeightTable,
    abm_weights,
    corrector_start_weights,
    corrector_weights,
    predictor_weights,
)

ALPHAS = [0.01, 0.3, 0.5, 0.85, 0.95, 0.999, 1.0]


def _mp_weights(alpha, k):
    """Textbook formulas in 50-digit arithmetic: b(k), c(k), a0(k)."""
    with mp.workdps(50):
        a = mp.mpf(alpha)
        K = mp.mpf(k)
        b = (K + 1) ** a - K ** a
        c = (K + 2) ** (a + 1) - 2 * (K + 1) ** (a + 1) + K ** (a + 1)
        a0 = K ** (a + 1) - (K - a) * (K + 1) ** a
        return b, c, a0


def _rel(got, exact):
    with mp.workdps(50):
        return float(abs((mp.mpf(float(got)) - exact) / exact))


@pytest.mark.parametrize('alpha', ALPHAS)
def test_weights_large_index_match_mpmath(alpha):
    ks = [10**6, 10**7]
    b = predictor_weights(alpha, ks)
    c = corrector_weights(alpha, ks)
    a0 = corrector_start_weights(alpha, ks)
    for i, k in enumerate(ks):
        eb, ec, ea = _mp_weights(alpha, k)
        assert _rel(b[i], eb) < 1e-12, (alpha, k, 'b')
        assert _rel(c[i], ec) < 1e-12, (alpha, k, 'c')
        assert _rel(a0[i], ea) < 1e-12, (alpha, k, 'a0')


@pytest.mark.parametrize('alpha', ALPHAS)
def test_weights_all_regimes_match_mpmath(alpha):
    # small indices, the series switch-over at 64 and huge indices; 1e-14 relative
    ks = [0, 1, 2, 3, 7, 15, 16, 63, 64, 65, 1000, 123457, 10**8, 2**40]
    b = predictor_weights(alpha, ks)
    c = corrector_weights(alpha, ks)
    a0 = corrector_start_weights(alpha, ks)
    for i, k in enumerate(ks):
        eb, ec, ea = _mp_weights(alpha, k) if k else _mp_weights(alpha, 0)
        assert _rel(b[i], eb) < 1e-14, (alpha, k, 'b')
        assert _rel(c[i], ec) < 1e-14, (alpha, k, 'c')
        if k == 0:
            assert a0[i] == pytest.approx(alpha, rel=1e-15)
        else:
            assert _rel(a0[i], ea) < 1e-14, (alpha, k, 'a0')


def test_textbook_form_loses_digits_where_ours_does_not():
    # the naive float64 power difference is visibly wrong at k = 1e7 (this is why the stable
    # forms exist); ours is not
    alpha, k = 0.85, 10**7
    _, ec, _ = _mp_weights(alpha, k)
    naive = (k + 2.0) ** (alpha + 1) - 2 * (k + 1.0) ** (alpha + 1) + float(k) ** (alpha + 1)
    assert _rel(naive, ec) > 1e-6
    assert _rel(corrector_weights(alpha, k), ec) < 1e-14


def test_abm_weights_spec_indexing():
    alpha, n = 0.7, 5
    b, a = abm_weights(alpha, n)
    assert b.shape == (n + 1,) and a.shape == (n + 2,)
    with mp.workdps(40):
        A = mp.mpf(alpha)
        for j in range(n + 1):
            assert _rel(b[j], (n + 1 - j) ** A - (n - j) ** A) < 1e-14
        assert _rel(a[0], mp.mpf(n) ** (A + 1) - (n - A) * (n + 1) ** A) < 1e-14
        for j in range(1, n + 1):
            ex = (n - j + 2) ** (A + 1) + mp.mpf(n - j) ** (A + 1) - 2 * (n - j + 1) ** (A + 1)
            assert _rel(a[j], ex) < 1e-14
    assert a[n + 1] == 1.0


def test_alpha_one_weights_are_trapezoidal():
    b, a = abm_weights(1.0, 4)
    np.testing.assert_allclose(b, 1.0, rtol=1e-15)
    np.testing.assert_allclose(a, [1, 2, 2, 2, 2, 1], rtol=1e-15)


def test_weight_table_grows_by_doubling_and_matches():
    tab = WeightTable(0.6, capacity=16)
    assert tab.capacity == 16
    tab.ensure(100)
    assert tab.capacity == 128
    k = np.arange(tab.capacity)
    np.testing.assert_array_equal(tab.b, predictor_weights(0.6, k))
    np.testing.assert_array_equal(tab.c, corrector_weights(0.6, k))
    np.testing.assert_array_equal(tab.a0, corrector_start_weights(0.6, k))
    with pytest.raises(ValueError):
        tab.bc_rev[0, 0] = 1.0


@pytest.mark.parametrize('bad', [0.0, -0.2, 1.3, float('nan'), 'x'])
def test_weights_reject_bad_alpha(bad):
    with pytest.raises(ValueError, match=r'alpha=.*outside \(0, 1\] \(dimensionless\)'):
        predictor_weights(bad, [1])


def test_weights_reject_bad_index():
    with pytest.raises(ValueError, match='k='):
        corrector_weights(0.5, [-1])
    with pytest.raises(ValueError, match='k='):
        predictor_weights(0.5, [1.5])
