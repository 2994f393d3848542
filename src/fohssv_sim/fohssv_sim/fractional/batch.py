"""Helpers for batched runs: grouping points by fractional order.

:class:`~.abm.BatchABM` and :class:`~.soe.BatchSOE` advance P systems that share the order
alpha and the step h. A sweep over alpha (e.g. a bifurcation diagram) is split into such groups
with :func:`group_by_alpha`; :func:`make_batches` builds one batched stepper per group.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ._validate import check_alpha, check_state

__all__ = ['group_by_alpha', 'make_batches']


def group_by_alpha(alphas) -> list[tuple[float, np.ndarray]]:
    """Group point indices by their (exactly equal) fractional order.

    Returns a list of ``(alpha, indices)`` sorted by alpha, where ``indices`` is an int array
    into ``alphas``; every point appears in exactly one group. Cost O(P log P).

    Raises:
        ValueError: an alpha outside (0, 1] (message names the value, range and unit), or
            ``alphas`` not 1-D.
    """
    arr = np.asarray(alphas, dtype=float)
    if arr.ndim != 1:
        raise ValueError(f"alphas must be a 1-D array of orders in (0, 1], got shape {arr.shape}")
    for a in np.unique(arr):
        check_alpha(a)
    values, inverse = np.unique(arr, return_inverse=True)
    return [(float(v), np.flatnonzero(inverse == i)) for i, v in enumerate(values)]


def make_batches(solver: str, rhs_for: Callable[[np.ndarray], Callable], alphas, step: float,
                 X0, **kwargs) -> list[tuple[float, np.ndarray, object]]:
    """One batched stepper per distinct alpha.

    ``solver`` is a fractional solver's name in :data:`fohssv_sim.solvers.SOLVERS` ('abm' /
    'abm-fft' -> BatchABM, 'soe' -> BatchSOE); ``rhs_for(indices)`` returns the batched
    rhs(t, X, U) for the points ``indices`` (so per-point parameters can be sliced); X0 is
    (P, d). Returns a list of ``(alpha, indices, stepper)``; stepper.x[i] is point
    indices[i]. Accuracy and cost: those of the batched class.

    Raises:
        ValueError: unknown solver (lists the valid ones), invalid alphas, step or X0, or
            len(alphas) != len(X0).
    """
    from ..solvers import get_solver

    info = get_solver(solver)
    if info.batch is None:
        raise ValueError(f'solver={solver!r} is not a fractional solver')
    X0 = check_state(X0, 'X0', ndim=2)
    groups = group_by_alpha(alphas)
    if sum(idx.size for _, idx in groups) != X0.shape[0]:
        raise ValueError(f"alphas has {sum(i.size for _, i in groups)} entries but X0 has "
                         f"{X0.shape[0]} rows (one per point)")
    return [(a, idx, info.batch(rhs_for(idx), a, step, X0[idx], **kwargs))
            for a, idx in groups]
