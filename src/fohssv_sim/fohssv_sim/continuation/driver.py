"""Pseudo-arclength continuation of F(u, p) = 0, with step control and bifurcation tests.

A problem is anything with ``residual(u, p) -> ndarray`` (n equations in the n unknowns u; the
parameter p is a float) and, optionally, ``valid(u_previous, u) -> bool`` (False rejects a
corrected point, as a failed correction: e.g. a jump onto a trivial solution),
``accept(u, p)`` (called at each new point: moves a phase reference) and
``monitors(u, p) -> dict[str, float]``: named test functions whose change of sign between
two consecutive points marks a bifurcation of that name (e.g. ``period_doubling`` for a
Floquet multiplier crossing -1).

Each step predicts along the unit tangent t of the branch in y = (u, p) and corrects on the
extended system (Keller's pseudo-arclength condition), by the chord method with the previous
point's Jacobian (one Jacobian per point, the one its tangent needs anyway; full Newton when
the chord stalls)::

    F(u, p) = 0,      t . (y - y_prev) - ds = 0,

whose Jacobian stays regular at a fold, so a fold is passed, not stopped at. The step ds grows
after an easy correction and halves after a failed one (down to ``ds_min``). A fold is where
the p-component of the tangent changes sign; it is located at the vertex of the parabola
p(s) through the three points around it. Jacobians are by central differences unless the
problem has ``jacobian(u, p)`` (n x (n + 1), columns u then p).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

__all__ = ['BranchPoint', 'Bifurcation', 'ContinuationError', 'Settings', 'continue_branch',
           'newton', 'jacobian', 'fd_jacobian']


class ContinuationError(ValueError):
    """A start that does not converge or a branch that cannot be followed; the message says
    which and where."""


@dataclass
class BranchPoint:
    """One converged point: the unknowns ``u``, the parameter ``p``, the unit tangent and the
    problem's test functions there."""

    u: np.ndarray
    p: float
    tangent: np.ndarray
    monitors: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Bifurcation:
    """A detected bifurcation: its ``kind``, the parameter ``value`` (interpolated) and the
    index of the branch point after it."""

    kind: str
    value: float
    index: int


@dataclass(frozen=True)
class Settings:
    """Step control: initial, smallest and largest arclength step (in the scaled y), Newton
    tolerance (max-norm of the residual) and iteration limit, the most points, and the
    sharpest turn of the tangent accepted between two points."""

    ds: float = 0.02
    ds_min: float = 1e-6
    ds_max: float = 0.1
    tol: float = 1e-9
    max_iter: int = 12
    max_points: int = 500
    #: the least cosine between consecutive tangents; a sharper turn halves the step
    min_cos: float = 0.95


def fd_jacobian(fun: Callable[[np.ndarray], np.ndarray], y: np.ndarray) -> np.ndarray:
    """Central-difference Jacobian of ``fun`` at ``y`` (relative step 1e-7)."""
    cols = []
    for j in range(y.size):
        d = 1e-7 * max(1.0, abs(y[j]))
        yp, ym = y.copy(), y.copy()
        yp[j] += d
        ym[j] -= d
        cols.append((fun(yp) - fun(ym)) / (2.0 * d))
    return np.column_stack(cols)


def jacobian(problem: Any, u: np.ndarray, p: float) -> np.ndarray:
    """dF/d(u, p), n x (n + 1): the problem's own ``jacobian`` or central differences."""
    own = getattr(problem, 'jacobian', None)
    if own is not None:
        return np.asarray(own(u, p), dtype=float)
    return fd_jacobian(lambda y: problem.residual(y[:-1], y[-1]), np.append(u, p))


def newton(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], np.ndarray],
           y: np.ndarray, tol: float, max_iter: int, xtol: float = 1e-10,
           frozen: np.ndarray | None = None) -> tuple[np.ndarray, int] | None:
    """Newton's method on a square system: ``(root, iterations)`` once the max-norm of the
    residual is below ``tol`` or of the last step below ``xtol`` (1 + max |y|) (round-off
    bounds a residual of large terms above zero); None when neither within ``max_iter``.

    ``frozen``: a matrix used in place of the Jacobian at every iteration (the chord method:
    factored once, ``jac`` not called); it gives up as soon as a step fails to shrink the
    residual by half, so the caller can fall back to full Newton. Its convergence is linear,
    so it stops at ``tol`` / 100: as close as Newton's last, quadratic, step lands."""
    y = np.array(y, dtype=float)
    solve = None
    if frozen is not None:
        tol = 1e-2 * tol
        try:
            lu = scipy.linalg.lu_factor(frozen, check_finite=True)
        except (ValueError, np.linalg.LinAlgError):
            return None

        def solve(r):
            return scipy.linalg.lu_solve(lu, r)
    previous = math.inf
    for it in range(max_iter + 1):
        r = fun(y)
        if not np.all(np.isfinite(r)):
            return None
        norm = float(np.max(np.abs(r)))
        if norm < tol:
            return y, it
        if it == max_iter or (solve is not None and norm > 0.5 * previous):
            return None
        previous = norm
        try:
            dy = solve(-r) if solve is not None else np.linalg.solve(jac(y), -r)
        except np.linalg.LinAlgError:
            return None
        y = y + dy
        if np.max(np.abs(dy)) < xtol * (1.0 + np.max(np.abs(y))) and \
                np.all(np.isfinite(fun(y))):
            return y, it + 1
    return None


class _Scaled:
    """``problem`` in the coordinates y / scale, where a unit step means as much in every
    unknown and the parameter (the arclength norm sees them alike)."""

    def __init__(self, problem: Any, scale: np.ndarray, bounds: tuple[float, ...] = ()
                 ) -> None:
        self.problem = problem
        self.su, self.sp = scale[:-1], float(scale[-1])
        self.bounds = bounds

    def residual(self, z: np.ndarray, zp: float) -> np.ndarray:
        return self.problem.residual(z * self.su, zp * self.sp)

    def jacobian(self, z: np.ndarray, zp: float) -> np.ndarray:
        own = getattr(self.problem, 'jacobian', None)
        if own is None:
            return fd_jacobian(lambda y: self.residual(y[:-1], y[-1]), np.append(z, zp))
        return np.asarray(own(z * self.su, zp * self.sp)) * np.append(self.su, self.sp)

    def point(self, q: BranchPoint) -> BranchPoint:
        t = q.tangent * np.append(self.su, self.sp)
        return BranchPoint(q.u * self.su, _snapped(q.p * self.sp, self.bounds),
                           t / np.linalg.norm(t), q.monitors)

    def monitors(self, z: np.ndarray, zp: float) -> dict[str, float]:
        return _monitors(self.problem, z * self.su, zp * self.sp)


def _tangent(J: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """Unit null vector of the n x (n + 1) Jacobian, oriented like ``previous``."""
    A = np.vstack([J, previous])
    b = np.zeros(A.shape[0])
    b[-1] = 1.0
    t = np.linalg.solve(A, b)
    t /= np.linalg.norm(t)
    return t if t @ previous >= 0 else -t


def _monitors(problem: Any, u: np.ndarray, p: float) -> dict[str, float]:
    """The problem's test functions at a new point (after moving its phase reference there,
    if it has one: ``accept(u, p)``)."""
    if isinstance(problem, _Scaled):
        return problem.monitors(u, p)
    accept = getattr(problem, 'accept', None)
    if accept is not None:
        accept(u, p)
    fn = getattr(problem, 'monitors', None)
    return dict(fn(u, p)) if fn is not None else {}


def _fold_value(a: BranchPoint, b: BranchPoint, c: BranchPoint) -> float:
    """The extreme p of the parabola through three consecutive points (by arclength)."""
    s1 = np.linalg.norm(np.append(b.u - a.u, b.p - a.p))
    s2 = s1 + np.linalg.norm(np.append(c.u - b.u, c.p - b.p))
    coef = np.polyfit([0.0, s1, s2], [a.p, b.p, c.p], 2)
    if coef[0] == 0.0:
        return b.p
    s = -coef[1] / (2.0 * coef[0])
    return float(np.polyval(coef, min(max(s, 0.0), s2)))


def continue_branch(problem: Any, start: tuple[np.ndarray, float], end: float, *,
                    scale: np.ndarray | None = None, direction: np.ndarray | None = None,
                    limit: float | None = None, settings: Settings = Settings(),
                    on_point: Callable[[BranchPoint, list[Bifurcation]], None] | None = None,
                    ) -> tuple[list[BranchPoint], list[Bifurcation]]:
    """Follow the branch through ``start`` = (u0, p0) (converged to ``settings.tol`` first)
    until p reaches ``end`` or, on the other side, ``limit`` (a branch turning back), the last
    point corrected onto that value exactly; or until the step falls below ``ds_min`` or
    ``max_points`` are taken.

    ``scale``: a typical size of each unknown and of p (n + 1 values, default ones); steps
    and tolerances apply to y / scale. ``direction``: a vector in y = (u, p) the first tangent
    should point along (default: towards ``end``). ``on_point(point, bifurcations)`` is called
    after each point (progress output, checkpoints).

    Raises:
        ContinuationError: the start does not converge.
    """
    u0 = np.asarray(start[0], dtype=float)
    scale = np.ones(u0.size + 1) if scale is None else np.asarray(scale, dtype=float)
    sc = _Scaled(problem, scale, tuple(b for b in (end, limit) if b is not None))
    sp = sc.sp

    def unscaled(bifs: list[Bifurcation]) -> list[Bifurcation]:
        return [Bifurcation(b.kind, b.value * sp, b.index) for b in bifs]

    report = None
    if on_point is not None:
        def report(q: BranchPoint, bifs: list[Bifurcation]) -> None:
            on_point(sc.point(q), unscaled(bifs))

    points, bifs = _follow(sc, (u0 / sc.su, float(start[1]) / sp), end / sp,
                           None if direction is None else np.asarray(direction) / scale,
                           None if limit is None else limit / sp, settings, report)
    return [sc.point(q) for q in points], unscaled(bifs)


def _snapped(p: float, bounds: tuple[float, ...]) -> float:
    """``p``, or the bound it equals to rounding (a point landed on the end of the range)."""
    return next((b for b in bounds if abs(p - b) <= 1e-12 * max(1.0, abs(b))), p)


def _follow(problem: _Scaled, start: tuple[np.ndarray, float], end: float,
            direction: np.ndarray | None, limit: float | None, settings: Settings,
            on_point: Callable[[BranchPoint, list[Bifurcation]], None] | None
            ) -> tuple[list[BranchPoint], list[Bifurcation]]:
    """:func:`continue_branch` in scaled coordinates."""
    s = settings
    u0 = np.asarray(start[0], dtype=float)
    p0 = float(start[1])
    n = u0.size
    got = newton(lambda u: problem.residual(u, p0), lambda u: jacobian(problem, u, p0)[:, :n],
                 u0, s.tol, s.max_iter)
    if got is None:
        res = float(np.max(np.abs(problem.residual(u0, p0))))
        raise ContinuationError(f'the start at p = {p0:g} is not near a solution: Newton '
                                f'did not converge (initial residual {res:.3g})')
    u0 = got[0]
    sign = 1.0 if end >= p0 else -1.0
    if direction is None:
        direction = np.zeros(n + 1)
        direction[-1] = sign
    J = jacobian(problem, u0, p0)
    t = _tangent(J, np.asarray(direction, dtype=float))
    points = [BranchPoint(u0, p0, t, _monitors(problem, u0, p0))]
    bifs: list[Bifurcation] = []
    if on_point:
        on_point(points[0], bifs)
    ds = s.ds
    while len(points) < s.max_points:
        prev = points[-1]
        got = _step(problem, prev, J, ds, end, limit, sign, s)
        if got is None:      # a failed correction: a smaller step
            ds *= 0.5
            if ds < s.ds_min:
                break
            continue
        y, easy = got
        J_new = jacobian(problem, y[:-1], y[-1])
        tangent = _tangent(J_new, prev.tangent)
        if tangent @ prev.tangent < s.min_cos and ds > s.ds_min:
            ds *= 0.5        # the branch turned too sharply: it may have jumped to another
            continue
        J = J_new
        point = BranchPoint(y[:-1], float(y[-1]), tangent, _monitors(problem, y[:-1], y[-1]))
        points.append(point)
        bifs.extend(_detected(points))
        if on_point:
            on_point(point, bifs)
        if point.p == end or point.p == limit:
            break
        ds = min(ds * (1.5 if easy else 1.0), s.ds_max)
    return points, bifs


def _step(problem: _Scaled, prev: BranchPoint, J_prev: np.ndarray, ds: float, end: float,
          limit: float | None, sign: float, s: Settings) -> tuple[np.ndarray, bool] | None:
    """The next point ``(y, easy)`` at arclength ``ds`` from ``prev``, landed on p = ``end``
    or ``limit`` if it passed one; None when the correction fails or the problem refuses it.
    The corrector is the chord method on ``prev``'s Jacobian ``J_prev`` (no new Jacobian per
    iteration), full Newton if that stalls; ``easy``: the chord converged within 5
    iterations."""
    y_prev = np.append(prev.u, prev.p)
    tp = prev.tangent

    def fun(y):
        return np.append(problem.residual(y[:-1], y[-1]), tp @ (y - y_prev) - ds)

    def jac(y):
        return np.vstack([jacobian(problem, y[:-1], y[-1]), tp])

    y0 = y_prev + ds * tp
    got = newton(fun, jac, y0, s.tol, s.max_iter, frozen=np.vstack([J_prev, tp]))
    easy = got is not None and got[1] <= 5
    if got is None:
        got = newton(fun, jac, y0, s.tol, s.max_iter)
    if got is None:
        return None
    y = got[0]
    valid = getattr(problem.problem, 'valid', None)
    if valid is not None and not valid(prev.u * problem.su, y[:-1] * problem.su):
        return None          # e.g. a jump onto a trivial solution
    if (y[-1] - end) * sign > 0.0:
        bound = end
    elif limit is not None and (y[-1] - limit) * sign < 0.0:
        bound = limit
    else:
        return y, easy
    n = prev.u.size
    landed = newton(lambda u: problem.residual(u, bound),
                    lambda u: jacobian(problem, u, bound)[:, :n],
                    prev.u + (bound - prev.p) / (y[-1] - prev.p) * (y[:-1] - prev.u),
                    s.tol, s.max_iter)
    return None if landed is None else (np.append(landed[0], bound), easy)


def _detected(points: list[BranchPoint]) -> list[Bifurcation]:
    """Bifurcations between the last two points: a fold where dp/ds changes sign, and each
    monitor that changes sign (located by linear interpolation in p)."""
    prev, point = points[-2], points[-1]
    k = len(points) - 1
    out = []
    if point.tangent[-1] * prev.tangent[-1] < 0.0 and k >= 2:
        out.append(Bifurcation('fold', _fold_value(points[-3], prev, point), k))
    for name, value in point.monitors.items():
        before = prev.monitors.get(name)
        if before is not None and math.isfinite(before) and math.isfinite(value) and \
                (before < 0.0) != (value < 0.0):
            frac = before / (before - value) if before != value else 0.5
            out.append(Bifurcation(name, prev.p + frac * (point.p - prev.p), k))
    return out
