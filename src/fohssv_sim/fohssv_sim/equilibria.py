"""Closed-loop equilibria, linearisation and Matignon stability (docs/model.md §5.3, eq. 30).

For the commensurate FOM  D^alpha x = f(x),  an equilibrium x* (f(x*) = 0) is locally
asymptotically stable iff every eigenvalue lambda of the Jacobian J = df/dx(x*) satisfies
|arg lambda| > alpha pi / 2 (Matignon 1996). The critical order is
alpha_c = min |arg lambda| / (pi/2): stable for alpha < alpha_c. A zero eigenvalue gives
alpha_c = 0 (stable for no alpha).

The right-hand side is eq. 17 with the planing form of the parameters (smooth for the FOM by
default); the delayed model shares the delay-free model's equilibria (x(t - tau) = x there).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import root

from .coefficients import coefficients
from .control import as_law
from .params import ModelParameters
from .physics import eq17
from .planing import planing_exact, planing_smooth

__all__ = ['Equilibrium', 'closed_loop_rhs', 'find_equilibria', 'jacobian',
           'matignon_stable', 'critical_order']


@dataclass(frozen=True)
class Equilibrium:
    """A closed-loop equilibrium with its linearisation."""

    state: np.ndarray          # [z, w, theta, q]
    inputs: tuple[float, float]
    jacobian: np.ndarray
    eigenvalues: np.ndarray
    residual: float

    @property
    def critical_order(self) -> float:
        """alpha_c = min |arg lambda| / (pi/2); Matignon-stable for alpha < alpha_c."""
        return critical_order(self.eigenvalues)

    def stable(self, alpha: float) -> bool:
        """Matignon's test at order ``alpha`` (eq. 30)."""
        return matignon_stable(self.eigenvalues, alpha)


def closed_loop_rhs(params: ModelParameters, controller: Any = None
                    ) -> Callable[[np.ndarray], np.ndarray]:
    """f(x) = A x + B u(x) + G + D Fp(w) with u from ``controller`` (``command(t, x)``, a
    callable ``(t, x)``, or ``None`` for open loop); the planing form of ``params``."""
    c = coefficients(params).kernel     # the scalars eq. 17 reads, as plain attributes
    fp = planing_smooth if params.planing_form == 'smooth' else planing_exact
    law = as_law(controller)[0]

    def f(x: np.ndarray) -> np.ndarray:
        z, w, th, q = (float(v) for v in x)
        uf, uc = law(0.0, (z, w, th, q))
        return np.array(eq17(c, w, th, q, uf, uc, fp(w, c)))

    return f


def jacobian(f: Callable[[np.ndarray], np.ndarray], x: Sequence[float],
             rel_step: float = 1e-7) -> np.ndarray:
    """Central-difference Jacobian of ``f`` at ``x`` (error O(step^2), about 1e-9 relative
    for the smooth planing force)."""
    x = np.asarray(x, dtype=float)
    n = x.size
    J = np.empty((n, n))
    for j in range(n):
        d = rel_step * max(1.0, abs(x[j]))
        xp, xm = x.copy(), x.copy()
        xp[j] += d
        xm[j] -= d
        J[:, j] = (f(xp) - f(xm)) / (2.0 * d)
    return J


def critical_order(eigenvalues: Sequence[complex]) -> float:
    """alpha_c = min |arg lambda| / (pi/2) over the eigenvalues (may exceed 1)."""
    args = [abs(math.atan2(complex(v).imag, complex(v).real)) for v in eigenvalues]
    return min(args) / (math.pi / 2.0)


def matignon_stable(eigenvalues: Sequence[complex], alpha: float) -> bool:
    """True iff every eigenvalue has |arg lambda| > alpha pi/2 (eq. 30)."""
    return all(abs(math.atan2(complex(v).imag, complex(v).real)) > alpha * math.pi / 2.0
               for v in eigenvalues)


def find_equilibria(params: ModelParameters, controller: Any = None,
                    guesses: Sequence[Sequence[float]] | None = None,
                    tol: float = 1e-10) -> list[Equilibrium]:
    """All closed-loop equilibria reached from ``guesses`` (default: q = 0, theta = w/V and
    w on a grid over +-3 contact velocities, z = 0), deduplicated, sorted by w.

    Each is a root of f to ``tol`` (max-norm residual), with its Jacobian and eigenvalues.
    """
    f = closed_loop_rhs(params, controller)
    law = as_law(controller)[0]
    c = coefficients(params)
    if guesses is None:
        wc = c.contact_velocity
        guesses = [(0.0, w, w / c.V, 0.0) for w in np.linspace(-3 * wc, 3 * wc, 31)]
    found: list[Equilibrium] = []
    for g in guesses:
        # Powell's hybrid method, then Levenberg-Marquardt where it stalls at a planing kink.
        for method in ('hybr', 'lm'):
            x = root(f, np.asarray(g, dtype=float), method=method, tol=1e-14).x
            res = float(np.max(np.abs(f(x))))
            if np.all(np.isfinite(x)) and res <= tol:
                break
        else:
            continue
        if any(np.allclose(x, e.state, rtol=1e-7, atol=1e-9) for e in found):
            continue
        J = jacobian(f, x)
        u = law(0.0, tuple(x))
        found.append(Equilibrium(state=x, inputs=(float(u[0]), float(u[1])), jacobian=J,
                                 eigenvalues=np.linalg.eigvals(J), residual=res))
    found.sort(key=lambda e: e.state[1])
    return found
