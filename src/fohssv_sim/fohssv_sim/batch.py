"""Batched simulation: many parameter points of one model under affine laws, one call.

Points may differ in anything that only changes coefficients (speed, geometry, gains,
initial state); they must share the model, the step, the solver, the planing form and, for the
FOM with the 'abm' / 'abm-fft' solvers, the fractional order; with 'soe' the order may differ
per point (use :func:`group_points` to split a sweep into such groups).

With a compiled solver ('rk4', 'soe') each point runs on its own through the compiled kernel
in long chunks (:func:`fohssv_sim.simulate.simulate`: the law inside the kernel, or sampled
in compiled code at each control instant when the kept rows fall on them), which is faster
per point than stepping all points together in numpy (a Python round per step) and gives each
point's run bit for bit. The exact references 'abm' and 'abm-fft' have no compiled kernel:
their points step together through the batched steppers of :mod:`fohssv_sim.fractional`
(one BLAS product for all points' history sums), equal to the per-point runs to rounding.

Controllers must be affine state feedback, ``u = K x + u0`` clamped to deflection limits
(:meth:`fohssv_sim.control.Controller.affine`); the eq. 31 law and the LQR are.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

import numpy as np

from .coefficients import KernelCoefficients, coefficients
from .params import ModelParameters
from .physics import eq17
from .planing import planing_exact_array, planing_smooth_array
from .simulate import simulate, steps_per_period
from .solvers import SOLVERS

__all__ = ['BatchResult', 'BatchRHS', 'simulate_batch', 'group_points', 'shared_fields',
           'SHARED_FIELDS', 'PER_POINT_FIELDS']

#: Parameters every point of one batch must share (but see :func:`shared_fields`).
SHARED_FIELDS = ('model', 'step', 'solver', 'planing_form', 'fractional_order',
                 'soe_tolerance', 'soe_horizon_steps')

#: Fields that may differ between the points of one batch for the given solver.
PER_POINT_FIELDS = {'soe': ('fractional_order',)}


@dataclass
class BatchResult:
    """Samples of every point: ``states[p, i]`` at ``t[i]``; ``failed[p]`` marks points whose
    state turned non-finite (their remaining samples are NaN)."""

    t: np.ndarray
    states: np.ndarray
    failed: np.ndarray
    params: list[ModelParameters]


class BatchRHS:
    """Vectorised right-hand side of eq. 17 / eq. 26 with per-point coefficients:
    ``rhs(t, X (P, 4), U (P, 2)) -> (P, 4)``."""

    def __init__(self, params: Sequence[ModelParameters]) -> None:
        cs = [coefficients(p) for p in params]
        self.c = SimpleNamespace(**{n: np.array([getattr(c.kernel, n) for c in cs])
                                    for n in KernelCoefficients._fields})
        smooth = params[0].planing_form == 'smooth'
        self._fp = planing_smooth_array if smooth else planing_exact_array

    def planing_force(self, w: np.ndarray) -> np.ndarray:
        return self._fp(w, self.c)

    def __call__(self, t: float, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        c = self.c
        w, th, q = X[:, 1], X[:, 2], X[:, 3]
        uf, uc = U[:, 0], U[:, 1]
        out = np.empty_like(X)
        for i, col in enumerate(eq17(c, w, th, q, uf, uc, self._fp(w, c))):
            out[:, i] = col
        return out


class _AffineLaw:
    """U = clip(K X + u0) for all points at once, from each controller's ``affine()``."""

    def __init__(self, controllers: Sequence[Any]) -> None:
        ks, u0s, lims = [], [], []
        for ctl in controllers:
            aff = getattr(ctl, 'affine', None)
            law = aff() if aff is not None else None
            if law is None:
                raise ValueError(f'{type(ctl).__name__} is not affine state feedback; '
                                 'batched runs need Controller.affine() (use simulate())')
            K, u0 = law
            ks.append(np.asarray(K, dtype=float))
            u0s.append(np.asarray(u0, dtype=float))
            p = ctl.params
            lims.append((getattr(p, 'max_fin_deflection', math.inf),
                         getattr(p, 'max_cavitator_deflection', math.inf)))
        self.K = np.stack(ks)            # (P, 2, 4)
        self.u0 = np.stack(u0s)          # (P, 2)
        self.lim = np.array(lims)        # (P, 2)

    def __call__(self, t: float, X: np.ndarray) -> np.ndarray:
        U = np.einsum('pij,pj->pi', self.K, X) + self.u0
        return np.clip(U, -self.lim, self.lim)


def shared_fields(solver: str) -> tuple[str, ...]:
    """The fields the points of one batch with ``solver`` must share: :data:`SHARED_FIELDS`
    minus :data:`PER_POINT_FIELDS` (the 'soe' batch takes a per-point fractional order)."""
    own = PER_POINT_FIELDS.get(solver, ())
    return tuple(f for f in SHARED_FIELDS if f not in own)


def group_points(params: Sequence[ModelParameters]) -> dict[tuple, list[int]]:
    """Indices of ``params`` grouped by the fields a batch must share (:func:`shared_fields`
    of each point's solver). Keys have one entry per :data:`SHARED_FIELDS` field, None for a
    field the solver takes per point (so an alpha sweep with 'soe' is one group)."""
    groups: dict[tuple, list[int]] = {}
    for i, p in enumerate(params):
        fields = shared_fields(p.solver)
        key = tuple(getattr(p, f) if f in fields else None for f in SHARED_FIELDS)
        groups.setdefault(key, []).append(i)
    return groups


def _check_shared(params: Sequence[ModelParameters]) -> None:
    solvers = {p.solver for p in params}
    fields = shared_fields(params[0].solver) if len(solvers) == 1 else SHARED_FIELDS
    for f in fields:
        values = {getattr(p, f) for p in params}
        if len(values) > 1:
            raise ValueError(f'all points of a batch must share {f}; got {sorted(map(str, values))}'
                             ' (split them with group_points)')


def simulate_batch(params: Sequence[ModelParameters], controllers: Sequence[Any],
                   duration: float, *, control_period: float | None = None,
                   initial_states: np.ndarray | None = None, sample_every: int = 1,
                   record_from: float = 0.0,
                   progress: Callable[[float], None] | None = None) -> BatchResult:
    """Advance every point of ``params`` under its controller for ``duration`` seconds.

    Args:
        controllers: one affine controller per point (or one shared by all).
        control_period: None = continuous feedback; else zero-order hold (a whole multiple of
            the step), as in :func:`fohssv_sim.simulate.simulate`.
        initial_states: (P, 4), default zeros.
        sample_every: keep every k-th step; record_from: keep only samples with t >= this.
        progress: called with the fraction done (of the points, and within a point).

    A point whose run fails (a non-finite state; with a compiled solver also a state beyond
    the physical bounds, :class:`fohssv_sim.models.StateOutOfBounds`) is marked in
    ``failed``: its samples are NaN (with 'abm' / 'abm-fft' from the failing step on).

    Raises:
        ValueError: points that do not share :func:`shared_fields`, a non-affine controller,
            a bad duration, control period or sample interval.
    """
    params = list(params)
    if not params:
        raise ValueError('simulate_batch needs at least one point')
    _check_shared(params)
    P = len(params)
    if len(controllers) == 1 and P > 1:
        controllers = list(controllers) * P
    if len(controllers) != P:
        raise ValueError(f'{len(controllers)} controllers for {P} points')
    X0 = np.zeros((P, 4)) if initial_states is None else np.array(initial_states, dtype=float)
    if X0.shape != (P, 4) or not np.isfinite(X0).all():
        raise ValueError(f'initial_states must be a finite ({P}, 4) array, got {X0.shape}')
    h = params[0].step
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f'duration={duration!r} s must be a positive number of seconds')
    if int(sample_every) != sample_every or sample_every < 1:
        raise ValueError(f'sample_every={sample_every!r} must be a whole number >= 1')
    law = _AffineLaw(controllers)          # refuses a controller that is not affine
    n_steps = int(math.ceil(duration / h - 1e-9))
    first = -(-int(math.ceil(record_from / h - 1e-9)) // sample_every)   # the first kept row
    t_out = np.arange(first * sample_every, n_steps + 1, sample_every, dtype=float) * h
    states = np.full((P, t_out.size, 4), np.nan)
    if SOLVERS[params[0].solver].compiled:
        failed = _each_point(params, controllers, duration, control_period, X0, sample_every,
                             first, states, progress)
    else:
        failed = _together(params, law, duration, control_period, X0, sample_every, first,
                           states, progress)
    return BatchResult(t=t_out, states=states, failed=failed, params=params)


def _each_point(params, controllers, duration, control_period, X0, every, first, states,
                progress) -> np.ndarray:
    """Each point through :func:`fohssv_sim.simulate.simulate` (its compiled kernel); rows
    ``first``.. of its samples into ``states``; the points that failed."""
    failed = np.zeros(len(params), dtype=bool)
    for i, (p, ctl) in enumerate(zip(params, controllers)):
        within = None if progress is None else (
            lambda f, i=i: progress((i + f) / len(params)))
        try:
            r = simulate(p, ctl, duration, control_period=control_period,
                         initial_state=X0[i], sample_every=every, progress=within)
        except FloatingPointError:
            failed[i] = True
            continue
        states[i] = r.state[first:]
    return failed


def _together(params, law, duration, control_period, X0, every, first, states,
              progress) -> np.ndarray:
    """All points stepped together by the batched stepper of an interpreted solver ('abm',
    'abm-fft'), rows ``first``.. of every ``every``-th step into ``states``; the points whose
    state turned non-finite (NaN from there on)."""
    p = params[0]
    h = p.step
    solver = SOLVERS[p.solver]
    rhs = BatchRHS(params)
    stepper = solver.batch(rhs, p.fractional_order, h, X0, on_nonfinite='mask')
    hold = 0 if control_period is None else steps_per_period(control_period, h)
    n_steps = int(math.ceil(duration / h - 1e-9))
    report = max(1, n_steps // 100)
    X = X0
    U = law(0.0, X)
    for n in range(n_steps + 1):
        if n % every == 0 and n // every >= first:
            states[:, n // every - first] = X
        if n == n_steps:
            break
        if hold:
            if n % hold == 0:
                U = law(n * h, X)
            X = stepper.step(U)
        else:
            X = stepper.step(law)
        if progress is not None and n % report == 0:
            progress(n / n_steps)
    return np.asarray(stepper.failed_points, dtype=bool)
