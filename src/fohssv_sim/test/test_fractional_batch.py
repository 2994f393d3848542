"""Batched steppers equal per-point runs; grouping by alpha; the solver table."""

import numpy as np
import pytest

from fohssv_sim.fractional import (
    ABMStepper,
    BatchABM,
    BatchSOE,
    SOEStepper,
    group_by_alpha,
    solve_abm_fft,
)
from fohssv_sim.fractional.batch import make_batches
from fohssv_sim.params import SOLVERS_BY_MODEL, ModelParameters
from fohssv_sim.solvers import SOLVERS, get_solver

from linear4 import A4
from linear4 import B4 as B4_COL

B4 = B4_COL[:, 0]
P = 6
GAIN = np.linspace(0.5, 1.5, P)                        # a per-point parameter
X0 = np.random.default_rng(1).normal(size=(P, 4))


def point_rhs(i):
    def rhs(t, x, u):
        return GAIN[i] * (A4 @ x) + B4 * u[0] - 0.1 * x ** 3
    return rhs


def batch_rhs(idx):
    g = GAIN[idx][:, None]

    def rhs(t, X, U):
        return g * (X @ A4.T) + U[:, :1] * B4 - 0.1 * X ** 3
    return rhs


def inputs(n, h):
    return np.sin(50.0 * n * h + np.arange(P))[:, None]       # (P, 1), changes every step


@pytest.mark.parametrize('batch_cls,point_cls,kw', [
    (BatchABM, ABMStepper, {}),
    (BatchSOE, SOEStepper, {}),
    (BatchSOE, SOEStepper, {'n_exact': 4, 'tolerance': 1e-8}),
])
def test_batch_equals_per_point(batch_cls, point_cls, kw):
    alpha, h, N = 0.8, 2e-3, 700
    B = batch_cls(batch_rhs(np.arange(P)), alpha, h, X0, **kw)
    singles = [point_cls(point_rhs(i), alpha, h, X0[i], **kw) for i in range(P)]
    for n in range(N):
        U = inputs(n, h)
        X = B.step(U)
        for i, s in enumerate(singles):
            x = s.step(U[i])
            assert np.max(np.abs(X[i] - x)) <= 1e-12 * max(1.0, np.max(np.abs(x)))
    assert B.n == N and B.x.shape == (P, 4)


def test_batch_callable_input_equals_per_point():
    alpha, h, N = 0.9, 5e-3, 300

    def U_fb(t, X):
        return np.sin(3 * t) - 0.5 * X[:, :1]

    B = BatchSOE(batch_rhs(np.arange(P)), alpha, h, X0)
    Xs = [B.step(U_fb) for _ in range(N)][-1]
    for i in range(P):
        s = SOEStepper(point_rhs(i), alpha, h, X0[i])
        x = [s.step(lambda t, x: np.sin(3 * t) - 0.5 * x[:1]) for _ in range(N)][-1]
        assert np.max(np.abs(Xs[i] - x)) <= 1e-12 * max(1.0, np.max(np.abs(x)))


def test_batch_soe_close_to_exact():
    alpha, h, N = 0.7, 1e-3, 3000
    B = BatchSOE(batch_rhs(np.arange(P)), alpha, h, X0)
    U = np.array([inputs(n, h) for n in range(N)])             # (N, P, 1)
    X = np.array([X0] + [B.step(U[n]) for n in range(N)])
    for i in (0, P - 1):
        ref = solve_abm_fft(point_rhs(i), alpha, h, X0[i], N, u=U[:, i]).x
        assert np.max(np.abs(X[:, i] - ref)) <= 1e-8 * np.max(np.abs(ref))


def test_mask_mode_freezes_only_diverging_points():
    def rhs(t, X, U):
        out = -X.copy()
        out[1] = 1e200 * X[1] ** 2                         # point 1 blows up
        return out

    X0b = np.ones((3, 2))
    B = BatchABM(rhs, 0.8, 0.1, X0b, on_nonfinite='mask')
    with np.errstate(all='ignore'):
        for _ in range(20):
            X = B.step()
    assert B.failed_points.tolist() == [False, True, False]
    assert np.all(np.isnan(X[1])) and np.all(np.isfinite(X[[0, 2]]))
    ref = ABMStepper(lambda t, x, u: -x, 0.8, 0.1, [1.0, 1.0])
    for _ in range(20):
        r = ref.step()
    np.testing.assert_allclose(X[0], r, rtol=1e-12)
    B2 = BatchABM(rhs, 0.8, 0.1, X0b)
    with np.errstate(all='ignore'), pytest.raises(FloatingPointError, match=r'points \[1\]'):
        for _ in range(20):
            B2.step()
    assert B2.status == 'failed'


def test_batch_bad_arguments():
    with pytest.raises(ValueError, match='X0|x0'):
        BatchABM(batch_rhs(np.arange(P)), 0.8, 0.1, X0[0])          # 1-D
    with pytest.raises(ValueError, match='on_nonfinite'):
        BatchSOE(batch_rhs(np.arange(P)), 0.8, 0.1, X0, on_nonfinite='ignore')
    with pytest.raises(ValueError, match=r'alpha=1\.5 is outside \(0, 1\]'):
        BatchSOE(batch_rhs(np.arange(P)), 1.5, 0.1, X0)


def test_group_by_alpha_and_make_batches():
    alphas = np.array([0.9, 0.7, 0.9, 0.8, 0.7, 0.9])
    groups = group_by_alpha(alphas)
    assert [a for a, _ in groups] == [0.7, 0.8, 0.9]
    assert [idx.tolist() for _, idx in groups] == [[1, 4], [3], [0, 2, 5]]
    with pytest.raises(ValueError, match=r'alpha=1\.2'):
        group_by_alpha([0.5, 1.2])
    batches = make_batches('soe', batch_rhs, alphas, 1e-2, X0)
    for a, idx, stepper in batches:
        for _ in range(50):
            X = stepper.step(np.zeros((idx.size, 1)))
        for k, i in enumerate(idx):
            s = SOEStepper(point_rhs(i), a, 1e-2, X0[i])
            x = [s.step(np.zeros(1)) for _ in range(50)][-1]
            np.testing.assert_allclose(X[k], x, rtol=1e-12, atol=1e-14)


def test_solver_table():
    assert list(SOLVERS) == ['rk4', 'soe', 'abm', 'abm-fft']
    assert SOLVERS['abm'].stepper is ABMStepper and SOLVERS['abm'].batch is BatchABM
    assert SOLVERS['abm-fft'].offline is solve_abm_fft
    assert SOLVERS['soe'].stepper is SOEStepper and SOLVERS['soe'].batch is BatchSOE
    assert SOLVERS['rk4'].stepper is None and SOLVERS['rk4'].compiled
    for info in SOLVERS.values():
        assert info.accuracy and info.cost and info.name in info.doc
    with pytest.raises(ValueError, match="solver='fft' is not one of 'rk4', 'soe', 'abm', "
                                         "'abm-fft'"):
        get_solver('fft')
    assert SOLVERS.get('nope') is None
    # params and 'auto' read the same table: the first solver serving the model
    assert SOLVERS_BY_MODEL == {'fractional': ('soe', 'abm', 'abm-fft'),
                                'delay-free': ('rk4',), 'delayed': ('rk4',)}
    for model, names in SOLVERS_BY_MODEL.items():
        assert ModelParameters(model=model).solver == names[0]


# -- per-point orders in BatchSOE ------------------------------------------------------------
ALPHAS = np.array([0.6, 0.75, 0.8, 0.9, 0.99, 1.0])      # includes alpha = 1 (a single mode)


@pytest.mark.parametrize('kw', [{}, {'n_exact': 4, 'tolerance': 1e-8}])
def test_batch_soe_per_point_alpha_equals_per_point_runs(kw):
    # 1100 steps: many folds of the mode sums and past the first block of f_0 weights (1024)
    h, N = 2e-3, 1100
    B = BatchSOE(batch_rhs(np.arange(P)), ALPHAS, h, X0, **kw)
    singles = [SOEStepper(point_rhs(i), ALPHAS[i], h, X0[i], **kw) for i in range(P)]
    assert isinstance(B.modes, tuple) and B.modes[-1].n_modes == 1
    assert B.alpha.tolist() == ALPHAS.tolist()
    for n in range(N):
        U = inputs(n, h)
        X = B.step(U)
        for i, s in enumerate(singles):
            x = s.step(U[i])
            assert np.max(np.abs(X[i] - x)) <= 1e-12 * max(1.0, np.max(np.abs(x)))
    assert B.n == N and B.x.shape == (P, 4)
    B.reset(X0)                       # a reset run repeats the first steps exactly
    singles[0].reset(X0[0])
    for n in range(40):
        X = B.step(inputs(n, h))
        x = singles[0].step(inputs(n, h)[0])
    assert np.max(np.abs(X[0] - x)) <= 1e-12 * max(1.0, np.max(np.abs(x)))


def test_batch_soe_per_point_alpha_callable_input():
    h, N = 5e-3, 300

    def U_fb(t, X):
        return np.sin(3 * t) - 0.5 * X[:, :1]

    B = BatchSOE(batch_rhs(np.arange(P)), ALPHAS, h, X0)
    Xs = [B.step(U_fb) for _ in range(N)][-1]
    for i in range(P):
        s = SOEStepper(point_rhs(i), ALPHAS[i], h, X0[i])
        x = [s.step(lambda t, x: np.sin(3 * t) - 0.5 * x[:1]) for _ in range(N)][-1]
        assert np.max(np.abs(Xs[i] - x)) <= 1e-12 * max(1.0, np.max(np.abs(x)))


def test_batch_soe_equal_alphas_take_the_scalar_path():
    h = 2e-3
    B = BatchSOE(batch_rhs(np.arange(P)), np.full(P, 0.8), h, X0)
    S = BatchSOE(batch_rhs(np.arange(P)), 0.8, h, X0)
    assert B.alpha == 0.8 and B.modes is S.modes and B.alphas.tolist() == [0.8] * P
    for n in range(100):
        X, Y = B.step(inputs(n, h)), S.step(inputs(n, h))
    assert np.array_equal(X, Y)


def test_batch_soe_per_point_alpha_mask_and_errors():
    def rhs(t, X, U):
        out = -X.copy()
        out[1] = 1e200 * X[1] ** 2                         # point 1 blows up
        return out

    X0b = np.ones((3, 2))
    B = BatchSOE(rhs, [0.7, 0.8, 0.9], 0.1, X0b, on_nonfinite='mask')
    with np.errstate(all='ignore'):
        for _ in range(60):
            X = B.step()
    assert B.failed_points.tolist() == [False, True, False]
    for i, a in ((0, 0.7), (2, 0.9)):
        ref = SOEStepper(lambda t, x, u: -x, a, 0.1, [1.0, 1.0])
        for _ in range(60):
            r = ref.step()
        np.testing.assert_allclose(X[i], r, rtol=1e-12)
    B2 = BatchSOE(rhs, [0.7, 0.8, 0.9], 0.1, X0b)
    with np.errstate(all='ignore'), pytest.raises(FloatingPointError,
                                                  match=r'alpha=\[0\.8\]\) for points \[1\]'):
        for _ in range(20):
            B2.step()
    with pytest.raises(ValueError, match='alpha has 2 entries but X0 has 6 rows'):
        BatchSOE(batch_rhs(np.arange(P)), [0.7, 0.8], 0.1, X0)
    with pytest.raises(ValueError, match=r'alpha=1\.5 is outside \(0, 1\]'):
        BatchSOE(batch_rhs(np.arange(P)), [0.7, 1.5, 0.8, 0.8, 0.8, 0.8], 0.1, X0)
    with pytest.raises(ValueError, match='1-D array of per-point orders'):
        BatchSOE(batch_rhs(np.arange(P)), np.full((P, 1), 0.8), 0.1, X0)
