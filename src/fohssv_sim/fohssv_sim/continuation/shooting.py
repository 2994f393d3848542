"""Periodic orbits of an autonomous ODE x' = f(x, p) by single shooting, with Floquet
multipliers from the monodromy matrix.

Unknowns u = (x0, T); equations: x(T; x0, p) - x0 = 0 and a phase condition: either
f(x_ref, p_ref) . (x0 - x_ref) = 0 (x0 on the hyperplane through the previous point's start,
normal to the flow there; :meth:`ShootingProblem.accept` moves the reference after each
branch point), or f_k(x0) = 0 (x0 at an extremum of state k: a start that stays away from a
switching surface the orbit crosses, where the flow map is least smooth). The flow and its
variational equations X' = df/dx X, X(0) = I, are integrated with scipy's DOP853; the
monodromy matrix is X(T) and its eigenvalues are the Floquet multipliers, one of which is 1
for any autonomous orbit (the flow direction).

**Piecewise smooth fields.** A field may name switching surfaces (``switches(x, p)``: values
whose sign changes where the field's formula changes, e.g. the tail touching the cavity wall).
The integration stops at each crossing and restarts there, so no step straddles a kink. When
the field is continuous across the surface (as the planing force is: it is zero at contact,
only its slope jumps), the saltation matrix at a crossing is the identity and the monodromy
matrix is the plain product of the smooth pieces' variational flows: no correction is needed.
A field that jumps across a surface would need the saltation matrix and is not supported.

A field may bring its own compiled integrator (``Field(..., integrate=...)``, e.g. the
vehicle's, :mod:`.flow`): shooting then calls it instead of DOP853.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

__all__ = ['Field', 'ShootingProblem', 'floquet_tests']


class Field:
    """An autonomous vector field ``f(x, p)`` with an optional ``switches(x, p)`` (a tuple of
    surface functions) and Jacobian ``dfdx(x, p)`` (default: central differences), and
    optionally its own integrator ``integrate(x0, T, p, variational, count)`` returning x(T),
    X(T) (or None) and ``count`` equally spaced samples over [0, T) (or None)."""

    def __init__(self, f: Callable[[np.ndarray, float], np.ndarray], dim: int,
                 switches: Callable[[np.ndarray, float], tuple] | None = None,
                 dfdx: Callable[[np.ndarray, float], np.ndarray] | None = None,
                 integrate: Callable[..., tuple] | None = None) -> None:
        self.f = f
        self.dim = dim
        self.switches = switches
        self._dfdx = dfdx
        self.integrate = integrate

    def dfdx(self, x: np.ndarray, p: float) -> np.ndarray:
        if self._dfdx is not None:
            return self._dfdx(x, p)
        J = np.empty((self.dim, self.dim))
        for j in range(self.dim):
            d = 1e-7 * max(1.0, abs(x[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += d
            xm[j] -= d
            J[:, j] = (self.f(xp, p) - self.f(xm, p)) / (2.0 * d)
        return J


def _integrate(field: Field, x0: np.ndarray, T: float, p: float, variational: bool,
               rtol: float, count: int = 0) -> tuple[np.ndarray, np.ndarray | None, Any]:
    """x(T), the monodromy X(T) (or None) and ``count`` samples equally spaced over [0, T),
    by the field's own integrator or DOP853 restarted at each switching surface crossing."""
    if field.integrate is not None:
        return field.integrate(np.asarray(x0, dtype=float), T, p, variational, count)
    t_eval = np.linspace(0.0, T, count, endpoint=False) if count else None
    n = field.dim
    if variational:
        def rhs(t, y):
            x = y[:n]
            X = y[n:].reshape(n, n)
            return np.concatenate([field.f(x, p), (field.dfdx(x, p) @ X).ravel()])
        y = np.concatenate([x0, np.eye(n).ravel()])
    else:
        def rhs(t, y):
            return field.f(y, p)
        y = np.array(x0, dtype=float)
    count = 0 if field.switches is None else len(field.switches(y[:n], p))
    directions = [0.0] * count

    def event(k):
        def ev(t, yy):
            return field.switches(yy[:n], p)[k]
        ev.terminal = True
        ev.direction = directions[k]
        return ev

    t = 0.0
    samples: list[np.ndarray] = []
    g_start = field.switches(y[:n], p) if count else ()
    while True:
        sol = solve_ivp(rhs, (t, T), y, method='DOP853', rtol=rtol, atol=rtol * 1e-2,
                        events=[event(k) for k in range(count)] or None,
                        dense_output=t_eval is not None)
        if sol.status == -1:
            raise FloatingPointError(f'integration failed at t = {t:g}: {sol.message}')
        if t_eval is not None:
            inside = t_eval[(t_eval >= t) & (t_eval < sol.t[-1])]
            if inside.size:
                samples.extend(sol.sol(inside)[:n].T)
        y = sol.y[:, -1]
        t = sol.t[-1]
        if sol.status == 0 or t >= T:
            break
        # a crossing: restart on the surface. The next crossing of that surface goes back,
        # so only that direction may fire (the value at the restart is ~0 of either sign).
        fired = next(k for k in range(count) if sol.t_events[k].size)
        up = directions[fired] > 0 if directions[fired] else g_start[fired] < 0.0
        directions = [0.0] * count
        directions[fired] = -1.0 if up else 1.0
        g_start = field.switches(y[:n], p)
    X = y[n:].reshape(n, n) if variational else None
    return y[:n], X, samples


class ShootingProblem:
    """Periodic orbits of ``field`` by single shooting; unknowns u = (x0, T)."""

    def __init__(self, field: Field, rtol: float = 1e-11, extremum_of: int | None = None
                 ) -> None:
        self.field = field
        self.rtol = rtol
        #: None: the moving orthogonal hyperplane; k: x0 at an extremum of state k (f_k = 0)
        self.extremum_of = extremum_of
        self.ref: tuple[np.ndarray, np.ndarray] | None = None
        self._last: tuple[bytes, float, np.ndarray] | None = None   # (u, p, monodromy)

    def valid(self, previous: np.ndarray, u: np.ndarray) -> bool:
        """Refuse a step that shrinks the period below half (x(0) = x0 holds trivially at
        T = 0, and at any point of an equilibrium: degenerate solutions)."""
        return float(u[-1]) > 0.5 * float(previous[-1])

    def accept(self, u: np.ndarray, p: float) -> None:
        """Put the phase condition's hyperplane through this point (called per point)."""
        x0 = np.asarray(u[:-1], dtype=float)
        self.ref = (x0.copy(), np.asarray(self.field.f(x0, p), dtype=float))

    def residual(self, u: np.ndarray, p: float) -> np.ndarray:
        x0, T = u[:-1], float(u[-1])
        xT, _, _ = _integrate(self.field, x0, T, p, False, self.rtol)
        return np.append(xT - x0, self._phase(x0, p))

    def _phase(self, x0: np.ndarray, p: float) -> float:
        if self.extremum_of is not None:
            return float(self.field.f(np.asarray(x0, dtype=float), p)[self.extremum_of])
        if self.ref is None:
            self.accept(np.append(x0, 0.0), p)
        xr, fr = self.ref
        return float(fr @ (x0 - xr))

    def jacobian(self, u: np.ndarray, p: float) -> np.ndarray:
        """Columns x0, T, p: M - I, f(x(T)), dx(T)/dp (central difference in p)."""
        n = self.field.dim
        x0, T = u[:-1], float(u[-1])
        xT, M, _ = _integrate(self.field, x0, T, p, True, self.rtol)
        self._last = (np.asarray(u, dtype=float).tobytes(), float(p), M)
        d = 1e-6 * max(1.0, abs(p))
        xp = _integrate(self.field, x0, T, p + d, False, self.rtol)[0]
        xm = _integrate(self.field, x0, T, p - d, False, self.rtol)[0]
        J = np.zeros((n + 1, n + 2))
        J[:n, :n] = M - np.eye(n)
        J[:n, n] = self.field.f(xT, p)
        J[:n, n + 1] = (xp - xm) / (2.0 * d)
        if self.extremum_of is None:
            self._phase(x0, p)
            J[n, :n] = self.ref[1]
        else:
            J[n, :n] = self.field.dfdx(np.asarray(x0, dtype=float), p)[self.extremum_of]
            J[n, n + 1] = (self._phase(x0, p + d) - self._phase(x0, p - d)) / (2.0 * d)
        return J

    def monodromy(self, u: np.ndarray, p: float) -> np.ndarray:
        """X(T), the variational flow over one period (reused from the last Jacobian at the
        same point)."""
        if self._last is not None and self._last[0] == np.asarray(u, dtype=float).tobytes() \
                and self._last[1] == float(p):
            return self._last[2]
        return _integrate(self.field, u[:-1], float(u[-1]), p, True, self.rtol)[1]

    def multipliers(self, u: np.ndarray, p: float) -> np.ndarray:
        """Floquet multipliers, the one nearest 1 (the trivial one) first."""
        mu = np.linalg.eigvals(self.monodromy(u, p))
        order = np.argsort(np.abs(mu - 1.0))
        return mu[order]

    def samples(self, u: np.ndarray, p: float, count: int = 400) -> np.ndarray:
        """The orbit at ``count`` equally spaced times over one period, shape (count, n)."""
        return np.array(_integrate(self.field, u[:-1], float(u[-1]), p, False, self.rtol,
                                   count)[2])

    def monitors(self, u: np.ndarray, p: float) -> dict[str, float]:
        """:func:`floquet_tests`, and for each switching surface k the largest and smallest
        value of its function over the orbit (``grazing:k:max``, ``grazing:k:min``, from 400
        samples): one of them through zero is an orbit grazing the surface."""
        out = floquet_tests(self.multipliers(u, p)[1:])
        if self.field.switches is not None:
            g = np.array([self.field.switches(x, p) for x in self.samples(u, p, 400)])
            for k in range(g.shape[1]):
                out[f'grazing:{k}:max'] = float(g[:, k].max())
                out[f'grazing:{k}:min'] = float(g[:, k].min())
        return out


def floquet_tests(nontrivial: Any) -> dict[str, float]:
    """Test functions of the nontrivial multipliers, each changing sign at its bifurcation:
    ``period_doubling`` prod(mu + 1) (a real multiplier through -1) and ``torus``
    prod over pairs i < j of (mu_i mu_j - 1) (a complex pair through the unit circle; it is
    continuous where a pair turns real, and a real pair with product 1, a neutral saddle, also
    zeroes it: such a sign change is reported as torus too and needs the multipliers to tell).
    A multiplier through +1 is a fold of the branch, which the driver finds from its
    tangent."""
    mu = np.asarray(nontrivial, dtype=complex)
    pairs = [mu[i] * mu[j] - 1.0 for i in range(mu.size) for j in range(i + 1, mu.size)]
    return {'period_doubling': float(np.prod(mu + 1.0).real),
            'torus': float(np.prod(pairs).real) if pairs else 1.0}
