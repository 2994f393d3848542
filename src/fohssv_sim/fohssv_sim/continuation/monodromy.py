"""Floquet multipliers of a periodic orbit of a delay-differential equation, from a discretised
monodromy operator.

Linearised about an orbit x*(t) of period T, the DDE x' = f(x(t), x(t - tau)) gives the linear
periodic DDE

    y'(t) = A(t) y(t) + B(t) y(t - tau),     A = df/dx, B = df/dx_tau at (x*(t), x*(t - tau)).

Its state is a history segment y on [-tau, 0]; the monodromy operator maps the segment at 0 to
the segment at T. Discretised here by the method of steps on a uniform grid of h = T/steps:
the state is y at the grid points t_{k-m}, ..., t_k (m h >= tau plus the interpolation
stencil), one RK4 step advances it by h, and y(t - tau) at a stage time is the cubic Lagrange
interpolant of the four grid values around it (shifted back to the known ones when tau is
under three steps). Where f has a kink along the orbit (the tail touching the cavity wall), A
and B jump: a grid node is moved onto each such time (``breaks``), the grid kept T-periodic,
so no step straddles a jump. One period of steps maps the initial grid values linearly to the final
ones: the matrix of that map is the discretised monodromy operator, built column by column at
once (each grid value carries its dependence on the initial segment), and its eigenvalues
converge to the Floquet multipliers as the grid refines (fourth order for smooth A and B; a
kink in f, as at the cavity wall, lowers the order). One multiplier is 1 (the orbit's own
derivative x*' solves the linear equation) up to the discretisation and the orbit's own error.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ['dde_monodromy', 'dde_multipliers', 'stage_slopes']

#: A, B at the times given: ``coefficients(times) -> (A, B)``, each (len(times), n, n).
Coefficients = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def _lagrange(t: np.ndarray, first: int, s: float) -> np.ndarray:
    """The cubic Lagrange weights of the value at time ``s`` from the nodes t[first:first+4]."""
    nodes = t[first:first + 4]
    w = np.ones(4)
    for i in range(4):
        for j in range(4):
            if i != j:
                w[i] *= (s - nodes[j]) / (nodes[i] - nodes[j])
    return w


def _grid(T: float, steps: int, breaks) -> np.ndarray:
    """Nodes over [0, T): ``steps`` equal intervals, the node nearest each break moved onto it
    (a break where A or B jumps: then no RK4 step straddles it)."""
    t = T * np.arange(steps) / steps
    for b in np.mod(np.asarray(breaks, dtype=float), T):
        i = int(np.rint(b / T * steps)) % steps
        t[i] = b if i or b < 0.5 * T else b - T
    t = np.unique(t)
    return np.concatenate([t[t >= 0.0], t[t < 0.0] + T]) if t[0] < 0.0 else t


def dde_monodromy(coefficients: Coefficients, n: int, T: float, tau: float, steps: int,
                  breaks=()) -> np.ndarray:
    """The discretised monodromy matrix of y' = A(t) y + B(t) y(t - tau) over [0, T], on
    ``steps`` RK4 steps (fewer where two breaks share a node), the nodes T-periodic and placed
    on the ``breaks`` (times where A or B jumps). Square, n (m + 1) with m the nodes kept
    behind the current one (tau plus the interpolation stencil)."""
    base = np.sort(_grid(T, steps, breaks))
    P = base.size
    h_max = float(np.max(np.diff(np.append(base, base[0] + T))))
    reps = int(np.ceil((tau + 4.0 * h_max) / T)) + 1
    t = np.concatenate([base + T * r for r in range(-reps, 2)])   # periodic extension
    zero = reps * P                                  # index of t = 0
    m = zero - int(np.searchsorted(t, -tau - 3.0 * h_max, side='right')) + 1
    size = n * (m + 1)
    # three stage times per step; the ends just inside the step (its side of a break)
    t0, t1 = t[zero:zero + P], t[zero + 1:zero + P + 1]
    h = t1 - t0
    # at a break the end stage is taken 1e-3 h inside the step, clear of the differences
    # that give A and B (elsewhere exactly at the node: the shift would cost an O(h) error)
    marks = np.mod(np.asarray(breaks, dtype=float), T)
    near = np.array([np.any(np.abs(np.mod(v - marks + 0.5 * T, T) - 0.5 * T) < 1e-9 * T)
                     for v in np.mod(np.append(t0, t1[-1]), T)]) if marks.size else \
        np.zeros(P + 1, dtype=bool)
    start, end = 1e-3 * h * near[:-1], 1e-3 * h * near[1:]
    A, B = coefficients(np.stack([t0 + start, t0 + 0.5 * h, t1 - end], axis=1).ravel())
    A, B = A.reshape(P, 3, n, n), B.reshape(P, 3, n, n)
    # Y[i]: dy(t_i) / d(initial segment) for the node i (extended numbering), n x size
    Y = np.zeros((t.size, n, size))
    for i in range(m + 1):
        Y[zero - m + i, :, i * n:(i + 1) * n] = np.eye(n)

    def delayed(k: int, s: float) -> np.ndarray:
        j = int(np.searchsorted(t, s, side='right')) - 1
        first = min(j - 1, k - 3)
        return np.tensordot(_lagrange(t, first, s), Y[first:first + 4], axes=1)

    for q in range(P):
        k = zero + q
        y, hq = Y[k], h[q]
        a, b = A[q], B[q]
        d_half = delayed(k, t[k] + 0.5 * hq - tau)
        k1 = a[0] @ y + b[0] @ delayed(k, t[k] - tau)
        k2 = a[1] @ (y + 0.5 * hq * k1) + b[1] @ d_half
        k3 = a[1] @ (y + 0.5 * hq * k2) + b[1] @ d_half
        k4 = a[2] @ (y + hq * k3) + b[2] @ delayed(k, t[k + 1] - tau)
        Y[k + 1] = y + hq / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return Y[zero + P - m:zero + P + 1].reshape(size, size)


def dde_multipliers(coefficients: Coefficients, n: int, T: float, tau: float, steps: int,
                    breaks=()) -> np.ndarray:
    """The eigenvalues of :func:`dde_monodromy`, the one nearest 1 first, then by modulus."""
    mu = np.linalg.eigvals(dde_monodromy(coefficients, n, T, tau, steps, breaks))
    trivial = int(np.argmin(np.abs(mu - 1.0)))
    rest = np.delete(mu, trivial)
    return np.concatenate([[mu[trivial]], rest[np.argsort(-np.abs(rest))]])


def stage_slopes(rhs: Callable[[np.ndarray, np.ndarray], np.ndarray],
                 x: np.ndarray, xd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A = df/dx and B = df/dx_tau of ``rhs(x, xd)`` (states (n, N) -> derivatives (n, N)) at
    N points by central differences, each (N, n, n)."""
    n = x.shape[0]
    A = np.empty((x.shape[1], n, n))
    B = np.empty_like(A)
    for j in range(n):
        for moved, out in ((x, A), (xd, B)):
            d = 1e-7 * max(1.0, float(np.max(np.abs(moved[j]))))
            plus, minus = moved.copy(), moved.copy()
            plus[j] += d
            minus[j] -= d
            if moved is x:
                f1, f2 = rhs(plus, xd), rhs(minus, xd)
            else:
                f1, f2 = rhs(x, plus), rhs(x, minus)
            out[:, :, j] = ((f1 - f2) / (2.0 * d)).T
    return A, B
