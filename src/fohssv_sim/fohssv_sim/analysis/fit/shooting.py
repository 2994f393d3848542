"""Multiple shooting of an open-loop replay: the whole record used, segment by segment.

An open-loop replay of the unstable vehicle leaves the data within tens of milliseconds of any
error, so a single trajectory cannot be fitted to a long record. Here the record is cut into
segments of ``segment`` seconds; each segment starts from its own *node*, the state at its
first sample, estimated from the data, and runs the FOM on the recorded commands to the next.

**The nodes.** At a segment's start the point takes the state of its *follower* (below), plus
a correction; the corrections (4 per segment, nuisance unknowns) are fitted for every parameter
point by Gauss-Newton (``iterations`` steps from zero; each step one batched call of the point
and its 4 perturbed copies, every segment perturbed at once), all of them together: a
segment's samples depend on its own node's correction, a jump (below) on its node's and,
through the state the previous segment reached, on the previous node's, so the normal
equations are block tridiagonal and one banded solve gives the step of every node of the
record (:func:`_node_step`). The last step's corrections give the residual, so the residual
is a smooth, deterministic function of the parameters (the outer least squares
differentiates it).

**Continuity, as a soft constraint.** The jump at each node (its state minus the previous
segment's end there) is a residual row like a sample, in the same units (measured states
only): a model that cannot continue its own segments pays for every jump, and the jumps count
in the noise test as samples do (a right model's jumps are its node errors, about the noise).

**The fractional memory: the measured trajectory.** Beside each point runs its follower: the
same model (same parameters, same commands) over the whole record, corrected at every control
instant towards the sample by an extended Kalman filter (:mod:`.observer`), which weighs each
sample against the model's prediction and estimates the unmeasured states from the measured
ones. Taking the samples whole instead put their noise into the memory, where f, nonlinear
through the planing force, biased alpha as the noise squared (docs/fit.md). The follower's
history of f is therefore f along the filtered measured trajectory, period by period, from
t = 0. At a node the point takes the follower's whole history (its SOE arrays) and its
Volterra constant (x(t) = x0 + I^alpha f(x, u)(t), x0 shifted by each correction), so every
segment continues a memory that reaches back to t = 0 over the data, untruncated, and no
segment's error enters a later one through the memory (with the memory of the model's own
pieced trajectory instead, one segment thrown off by a contact spoils every later one). A
correction is added to x0 from its instant on: the corrections stay outside the fractional
dynamics (D^alpha (x - sum of the corrections) = f(x, u)). Checked against an exact solver:
test/test_fit_shooting.py. The point and its perturbed copies (``C`` in all) share one
follower, which does not depend on their corrections, so it runs in the first call only and
its state at each node is kept for the later calls (:class:`Memo`). Cost per parameter
value: ``5 iterations + 1`` replays of the record and one of the follower (17 in all at the
default 3).

Pure: numpy, numba; never imports rclpy or the CLI.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ... import kernels
from ...coefficients import coefficients
from ...params import ModelParameters
from ..population import _soe_arrays, check_population, over_threads
from . import observer
from .data import CLIP

#: Default segment length (s): ten control periods of 1e-4 s. Not the unstable mode's
#: e-folding time (65 ms at V = 75): through tail-slap contacts a replay of the FOM at
#: alpha = 0.81 amplifies a difference of 1e-4 of a state's spread to 0.1 within 10 ms, so
#: longer segments make the residual over alpha a comb of narrow basins (at 2.5 ms, 0.87 is
#: worse than 0.9; at 1 ms it rises monotonically on either side of the truth, 0.75 to 1).
SEGMENT = 0.001
#: Gauss-Newton steps for the nodes.
ITERATIONS = 3
#: The most the followers kept between a shot's calls may take (:class:`Memo`: 4 KB per node
#: and point, 4 MB per point and second of record): a shot of more points runs in groups.
MEMO_BYTES = 64 * 2 ** 20

if kernels.numba is not None:
    _njit = kernels.numba.njit(cache=True, nogil=True, error_model='numpy')
else:  # pragma: no cover - numba is pinned
    def _njit(fn):
        return fn


class Memo(NamedTuple):
    """The followers of P points at their S nodes (SOE history ``H``, its ``fill``, state
    ``y`` and Volterra constant ``y0``), ``have``: complete; kept only when ``keep`` (the
    follower is the same in every call for the same points; not kept where it would take
    more than :data:`MEMO_BYTES`)."""

    H: np.ndarray
    fill: np.ndarray
    y: np.ndarray
    y0: np.ndarray
    have: np.ndarray
    keep: bool

    @classmethod
    def make(cls, P: int, S: int, rows: int, keep: bool) -> Memo:
        """Room for P points, S nodes and histories of ``rows`` rows (none unless ``keep``)."""
        n = S if keep else 0
        return cls(np.zeros((P, n, 4, rows)), np.zeros((P, n), dtype=np.int64),
                   np.zeros((P, n, 4)), np.zeros((P, n, 4)), np.zeros(P, dtype=np.bool_),
                   bool(keep))

    def part(self, a: int, b: int) -> Memo:
        """The points a..b-1 (views: what a call fills in is kept)."""
        return Memo(self.H[a:b], self.fill[a:b], self.y[a:b], self.y0[a:b], self.have[a:b],
                    self.keep)


@_njit
def _memo_node(memo, follow, p, b, gf, y, y0, H, fill):
    """The follower of point p at node ``b``: kept into ``memo`` (``follow``), or taken from
    it."""
    R = H.shape[2]                 # a thread's points may pad fewer modes than all points
    if follow:
        if not memo.keep:
            return
        memo.H[p, b, :, :R] = H[gf]
        memo.fill[p, b] = fill[gf]
        memo.y[p, b] = y
        memo.y0[p, b] = y0
    else:
        H[gf] = memo.H[p, b, :, :R]
        fill[gf] = memo.fill[p, b]
        y[:] = memo.y[p, b]
        y0[:] = memo.y0[p, b]


@_njit
def _take_node(p, b, k, gf, x, x0, y, y0, delta, jumps, out, H, fill):
    """At node ``b`` (period ``k``) every copy c of point p takes the follower's memory
    (group ``gf``) and state plus its correction ``delta[p, c, b]``; the jump is kept."""
    for c in range(x.shape[0]):
        g = gf + 1 + c
        for i in range(4):
            node = y[i] + delta[p, c, b, i]
            jumps[p, c, b, i] = node - x[c, i]
            x0[c, i] = y0[i] + delta[p, c, b, i]
            x[c, i] = node
            out[p, c, k, i] = node
        H[g, :, :] = H[gf, :, :]
        fill[g] = fill[gf]


@_njit
def _shooting_kernel(X0, CV, smooth, inputs, hold, n_periods, starts, data, kf, delta,
                     H, W, fill, eps_k, ET, a0_coef, a0_small, alphas, cp, cc, speeds,
                     out, jumps, failed, memo):
    """Every point p's C copies (SOE groups (C + 1) p + 1 + c) over ``n_periods`` periods on
    the held ``inputs``, beside the point's one *follower* (group (C + 1) p): the same model
    corrected every period towards the sample ``data[k]`` (NaN: none) by the filter ``kf``
    (:func:`.observer.settings`: per point c, Q, R, the measured states). At period
    ``starts[b]`` each copy c takes the follower's memory and state plus ``delta[p, c, b]``
    (the jump, node minus the state the copy reached, kept in ``jumps[p, c, b]``); see the
    module docstring. A copy that leaves the domain stops its point (``failed[p]``, NaN from
    there on). ``memo`` (:class:`Memo`): the follower at each node, kept where it ran to the
    last node and taken from there in a later call (it does not depend on the copies'
    corrections)."""
    P, C = delta.shape[0], delta.shape[1]
    S = starts.shape[0]
    x = np.empty((C, 4))
    x0 = np.empty((C, 4))
    y = np.empty(4)
    y0 = np.empty(4)
    last_f = np.empty(4)
    bad = np.empty(4)
    e = np.empty(4)
    white = np.empty(4)
    m = np.empty(4, dtype=np.bool_)
    Pk = np.empty((4, 4))
    kf_c, Q, R, measured = kf
    held = np.zeros(12)
    held[10] = math.inf
    held[11] = math.inf
    for p in range(P):
        gf = (C + 1) * p
        for i in range(4):
            y[i] = X0[p, i]
            y0[i] = X0[p, i]
            for c in range(C):
                x[c, i] = X0[p, i]
                x0[c, i] = X0[p, i]
                out[p, c, 0, i] = X0[p, i]
        n = 0
        b = 0
        Pk[:, :] = np.diag(Q)                  # the initial state is known
        follow = not memo.have[p]
        for k in range(n_periods):
            if b < S and k == starts[b]:
                _memo_node(memo, follow, p, b, gf, y, y0, H, fill)
                _take_node(p, b, k, gf, x, x0, y, y0, delta, jumps, out, H, fill)
                b += 1
            held[8] = inputs[k, 0]
            held[9] = inputs[k, 1]
            v = speeds[p]
            ok = True
            for c in range(C):
                g = gf + 1 + c
                taken = kernels.fom_soe_run(
                    x[c], x0[c], n, hold, CV[p], smooth, held, False, H[g:g + 1],
                    W[:, g:g + 1], fill[g:g + 1], eps_k[g:g + 1], ET[g:g + 1],
                    a0_coef[g:g + 1], a0_small[g:g + 1], alphas[g], cp[g], cc[g], last_f, bad)
                if taken < hold or not (-v <= x[c, 1] <= v and -1.5707963267948966 <= x[c, 2]
                                        <= 1.5707963267948966):
                    ok = False
                    break
            if ok and follow and b < S:
                taken = kernels.fom_soe_run(
                    y, y0, n, hold, CV[p], smooth, held, False, H[gf:gf + 1],
                    W[:, gf:gf + 1], fill[gf:gf + 1], eps_k[gf:gf + 1], ET[gf:gf + 1],
                    a0_coef[gf:gf + 1], a0_small[gf:gf + 1], alphas[gf], cp[gf], cc[gf],
                    last_f, bad)
                ok = taken == hold
                for i in range(4):             # corrected towards the sample (memory kept)
                    m[i] = measured[i] and math.isfinite(data[k + 1, i])
                    e[i] = data[k + 1, i] - y[i] if m[i] else 0.0
                observer.update(Pk, y, y0, e, kf_c[p], kernels.unpack_coefficients(CV[p]),
                                smooth, Q, R, m, white)
            if not ok:
                failed[p] = True
                out[p, :, k + 1:] = np.nan
                jumps[p, :, b:] = np.nan
                break
            n += hold
            for c in range(C):
                for i in range(4):
                    out[p, c, k + 1, i] = x[c, i]
        if memo.keep and not failed[p]:
            memo.have[p] = True


def run_segments(params: Sequence[ModelParameters], n_periods: int, hold: int,
                 inputs: np.ndarray, starts: np.ndarray, data: np.ndarray,
                 kf: tuple, delta: np.ndarray, *, initial_state: Sequence[float],
                 duration: float | None, threads: int = 1, memo: Memo | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(states (P, C, n_periods + 1, 4), jumps (P, C, S, 4), failed (P,)) of the points
    ``params``, C copies each (their node corrections ``delta`` (P, C, S, 4)), replayed on
    ``inputs`` with nodes at the periods ``starts``, each point's follower corrected towards
    ``data`` (n_periods + 1, 4; NaN: not measured) by the filter ``kf``
    (:func:`.observer.settings`; :func:`_shooting_kernel`); ``threads``
    > 1 splits the points over threads (the same numbers); ``memo``: the followers kept
    between calls for the same points (:class:`Memo`; None: not kept)."""
    params = list(params)
    if threads > 1 and len(params) > 1:
        parts = over_threads(lambda a, b: run_segments(
            params[a:b], n_periods, hold, inputs, starts, data, (kf[0][a:b], *kf[1:]),
            delta[a:b], initial_state=initial_state, duration=duration,
            memo=None if memo is None else memo.part(a, b)), len(params), threads)
        return tuple(np.concatenate([q[i] for q in parts]) for i in range(3))
    check_population(params)
    P, C, S = len(params), delta.shape[1], int(starts.size)
    X0 = np.tile(np.asarray(initial_state, dtype=float), (P, 1))
    CV = np.array([coefficients(p).kernel for p in params], dtype=float)
    # one history per point, its C + 1 groups copies of it (the same arrays, built once)
    hist, alphas, cp, cc = _soe_arrays(params, duration)
    if memo is None:
        memo = Memo.make(P, S, hist.H.shape[2], keep=False)
    H = np.zeros((P * (C + 1), *hist.H.shape[1:]))
    W = np.repeat(hist.W, C + 1, axis=1)
    eps_k, ET, a0_coef, a0_small, alphas, cp, cc = (
        np.repeat(a, C + 1, axis=0)
        for a in (hist.eps_k, hist.ET, hist.a0_coef, hist.a0_small, alphas, cp, cc))
    speeds = np.array([p.speed for p in params], dtype=float)
    out = np.empty((P, C, n_periods + 1, 4))
    jumps = np.zeros((P, C, S, 4))
    failed = np.zeros(P, dtype=np.bool_)
    _shooting_kernel(X0, CV, params[0].planing_form == 'smooth',
                     np.ascontiguousarray(inputs[:n_periods], dtype=float), int(hold),
                     int(n_periods), np.ascontiguousarray(starts, dtype=np.int64),
                     np.ascontiguousarray(data[:n_periods + 1], dtype=float),
                     tuple(np.ascontiguousarray(a, dtype=t)
                           for a, t in zip(kf, (float, float, float, np.bool_))),
                     np.ascontiguousarray(delta, dtype=float), H, W,
                     np.zeros((C + 1) * P, dtype=np.int64), eps_k, ET, a0_coef, a0_small,
                     alphas, cp, cc, speeds, out, jumps, failed, memo)
    return out, jumps, failed


def _node_step(J: np.ndarray, r: np.ndarray, seg: np.ndarray, dj: np.ndarray,
               jump: np.ndarray, free: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step (S, 4) of the node corrections of one point: the least squares
    of the samples' rows ``r`` + ``J`` step (a sample of segment ``seg`` depends on its own
    node's correction only) and the jumps' rows c (jump_b + step_b - E_{b-1} step_{b-1}),
    ``c2`` = c^2 (a jump depends on its node's correction and, through the state reached at
    it, on the previous node's: E_{b-1} = I - d jump_b / d all, ``dj`` being the jumps'
    response to every node perturbed at once). Both couplings kept, the normal equations are
    block tridiagonal (bandwidth 7), solved by banded Cholesky: the nodes of the whole record
    at once (the nodes outside ``free`` stay 0, their jumps unjudged)."""
    from scipy.linalg import solveh_banded

    S = jump.shape[0]
    ok = seg >= 0
    A = np.zeros((S, 4, 4))
    g = np.zeros((S, 4))
    np.add.at(A, seg[ok], np.einsum('tij,tik->tjk', J[ok], J[ok]))
    np.add.at(g, seg[ok], np.einsum('tij,ti->tj', J[ok], r[ok]))
    A += np.diag(c2)[None]                                # each jump's own node
    g += c2 * jump
    E = np.zeros((S, 4, 4))                               # E[b]: state at node b + 1 / node b
    E[:-1] = np.eye(4)[None] - dj[1:]
    E[:-1] *= (free[:-1] & free[1:])[:, None, None]       # both judged, else no coupling
    A += np.einsum('bki,k,bkj->bij', E, c2, E)
    g[:-1] -= np.einsum('bki,k,bk->bi', E[:-1], c2, jump[1:])
    ridge = 1e-12 * np.maximum(np.trace(A, axis1=1, axis2=2), 1e-300)
    A += ridge[:, None, None] * np.eye(4)[None]
    A[~free] = np.eye(4)
    g[~free] = 0.0
    ab = np.zeros((8, 4 * S))                 # upper band: row 7 + i - j holds a[i, j]
    for i in range(4):
        for j in range(4):
            if i <= j:
                ab[7 + i - j, j::4] = A[:, i, j]
            ab[3 + i - j, 4 + j::4] = -(c2[j] * E[:-1, j, i])   # block (b - 1, b) = -E^T C^2
    return -solveh_banded(ab, g.reshape(-1), check_finite=False).reshape(S, 4)


@dataclass
class Shot:
    """The segmented replay of some points: ``states`` (P, n + 1, 4), ``jumps`` (P, S, 4) at
    the node periods ``starts``, ``failed`` (P,)."""

    states: np.ndarray
    jumps: np.ndarray
    failed: np.ndarray
    starts: np.ndarray


class Segments:
    """The nodes of one problem: where they are and how they are fitted (see the module
    docstring). ``problem`` is a :class:`.problem.Problem` of an open-loop replay."""

    def __init__(self, problem: Any, segment: float, iterations: int = ITERATIONS) -> None:
        self.problem = problem
        d = problem.data
        self.periods = max(2, int(round(segment / d.control_period)))
        self.iterations = int(iterations)
        self.measured = problem.spec.measured.copy()
        c = np.where(self.measured, problem.w / problem.scale, 0.0)
        self.c = c                                   # a jump's weight per state (as a sample)
        self.h = 1e-6 * np.where(self.measured, problem.scale, 1.0)

    def starts(self, n: int) -> np.ndarray:
        """The node periods of a replay over ``n`` periods."""
        return np.arange(self.periods, n, self.periods, dtype=np.int64)

    def shoot(self, params: list[ModelParameters], upto: int, threads: int = 1) -> Shot:
        """The segmented replays of ``params`` over the first ``upto`` samples, their nodes
        fitted; the followers kept (:class:`Memo`) for as many points at a time as
        :data:`MEMO_BYTES` holds (none where one point's exceed it)."""
        pr = self.problem
        S = self.starts(int(pr.index[upto - 1])).size
        rows = _soe_arrays(params, pr.data.duration)[0].H.shape[2]
        per_point = max(1, S * rows * 4 * 8)
        keep = per_point <= MEMO_BYTES
        size = max(1, MEMO_BYTES // per_point) if keep else len(params)
        shots = [self._shoot(params[i:i + size], upto, threads,
                             Memo.make(len(params[i:i + size]), S, rows, keep))
                 for i in range(0, len(params), size)]
        if len(shots) == 1:
            return shots[0]
        return Shot(*(np.concatenate([getattr(q, f) for q in shots])
                      for f in ('states', 'jumps', 'failed')), starts=shots[0].starts)

    def _shoot(self, params: list[ModelParameters], upto: int, threads: int, memo: Memo
               ) -> Shot:
        pr, d = self.problem, self.problem.data
        n = int(pr.index[upto - 1])
        starts = self.starts(n)
        S, P = starts.size, len(params)
        sel = pr.index[:upto]
        seg = np.searchsorted(starts, sel, side='right') - 1       # -1: from x(0), no node
        free = np.zeros(S, dtype=bool)
        free[np.unique(seg[seg >= 0])] = True         # nodes with samples to fit them
        wr = pr.w / pr.scale
        kf = pr.filter_settings(params)
        delta = np.zeros((P, 1, S, 4))
        for _ in range(self.iterations if S else 0):
            D = np.repeat(delta, 5, axis=1)           # the point and its 4 perturbed copies
            for j in range(4):
                D[:, j + 1, :, j] += self.h[j]
            out, jumps, failed = run_segments(params, n, pr.hold, d.inputs, starts, pr.follow,
                                              kf, D, initial_state=d.initial_state,
                                              duration=d.duration, threads=threads, memo=memo)
            for p in np.flatnonzero(~failed):
                J = np.stack([(out[p, j + 1, sel] - out[p, 0, sel]) * wr / self.h[j]
                              for j in range(4)], axis=-1)          # (T, 4, 4): d row / d node
                dj = np.stack([(jumps[p, j + 1] - jumps[p, 0]) / self.h[j] for j in range(4)],
                              axis=-1)                              # (S, 4, 4): d jump / d all
                r = (out[p, 0, sel] - pr.states[sel]) * wr
                delta[p, 0] += _node_step(J, r, seg, dj, jumps[p, 0], free, self.c ** 2)
        out, jumps, failed = run_segments(params, n, pr.hold, d.inputs, starts, pr.follow,
                                          kf, delta, initial_state=d.initial_state,
                                          duration=d.duration, threads=threads, memo=memo)
        jumps = jumps[:, 0]
        jumps[:, ~free] = 0.0                     # a node before the window is not judged
        return Shot(states=out[:, 0], jumps=jumps, failed=failed, starts=starts)

    def rows(self, shot: Shot) -> np.ndarray:
        """(P, S * 4) continuity rows: each jump in the units of a sample's residual."""
        r = shot.jumps * self.c
        r = np.where(np.isfinite(r), np.clip(r, -CLIP, CLIP), CLIP)
        return r.reshape(r.shape[0], -1)


def warm_up() -> None:
    """Compile (or load from numba's cache) :func:`_shooting_kernel` with the argument types
    a fit passes (``make test`` calls it once, before the test workers start)."""
    n, hold = 4, 5
    run_segments([ModelParameters(model='fractional')], n, hold, np.zeros((n, 2)),
                 np.array([2], dtype=np.int64), np.zeros((n + 1, 4)),
                 (np.ones(1), np.ones(4), np.ones(4), np.ones(4, dtype=bool)),
                 np.zeros((1, 2, 1, 4)), initial_state=(0.0, 0.0, 0.0, 0.0), duration=None)
