"""Multiple shooting of an open-loop replay: the whole record used, segment by segment.

An open-loop replay of the unstable vehicle leaves the data within tens of milliseconds of any
error, so a single trajectory cannot be fitted to a long record. Here the record is cut into
segments of ``segment`` seconds; each segment starts from its own *node*, the state at its
first sample, estimated from the data, and runs the FOM on the recorded commands to the next.

**The nodes.** At a segment's start the point takes the state of its *follower* (below): the
measured states as sampled, the unmeasured ones as the previous segment left them, plus a
correction; the corrections (4 per segment, nuisance unknowns) are fitted for every parameter
point by Gauss-Newton (``iterations`` steps from zero; each step one batched call of the point
and its 4 perturbed copies, every segment perturbed at once), each segment's correction from
its own samples. The last step's corrections give the residual, so the residual is a smooth,
deterministic function of the parameters (the outer least squares differentiates it).

**Continuity, as a soft constraint.** The jump at each node (its state minus the previous
segment's end there) is a residual row like a sample, in the same units (measured states
only): a model that cannot continue its own segments pays for every jump, and the jumps count
in the noise test as samples do (a right model's jumps are its node errors, about the noise).

**The fractional memory: the measured trajectory.** Beside each point runs its follower: the
same model (same parameters, same commands) restarted at every control instant from the
sample (measured states; the point's own values for the unmeasured ones). The follower's
history of f is therefore f along the measured trajectory, period by period, from t = 0.
At a node the point takes the follower's whole history (its SOE arrays) and its Volterra
constant (x(t) = x0 + I^alpha f(x, u)(t), x0 shifted by each restart), so every segment
continues a memory that reaches back to t = 0 over the data, untruncated, and no segment's
error enters a later one through the memory (with the memory of the model's own pieced
trajectory instead, one segment thrown off by a contact spoils every later one). A restart
adds the difference to x0 from its instant on: the restarts stay outside the fractional
dynamics (D^alpha (x - sum of the restarts) = f(x, u)). Checked against an exact solver:
test/test_fit_shooting.py. Cost: twice a plain replay's (the follower), times
``5 iterations + 1`` calls.

Pure: numpy, numba; never imports rclpy or the CLI.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ... import kernels
from ...coefficients import coefficients
from ...params import ModelParameters
from ..population import _soe_arrays, check_population
from .data import CLIP

#: Default segment length (s): ten control periods of 1e-4 s. Not the unstable mode's
#: e-folding time (65 ms at V = 75): through tail-slap contacts a replay of the FOM at
#: alpha = 0.81 amplifies a difference of 1e-4 of a state's spread to 0.1 within 10 ms, so
#: longer segments make the residual over alpha a comb of narrow basins (at 2.5 ms, 0.87 is
#: worse than 0.9; at 1 ms it rises monotonically on either side of the truth, 0.75 to 1).
SEGMENT = 0.001
#: Gauss-Newton steps for the nodes.
ITERATIONS = 3

if kernels.numba is not None:
    _njit = kernels.numba.njit(cache=True, nogil=True, error_model='numpy')
else:  # pragma: no cover - numba is pinned
    def _njit(fn):
        return fn


@_njit
def _shooting_kernel(X0, CV, smooth, inputs, hold, n_periods, starts, data, reset, delta,
                     H, W, fill, eps_k, ET, a0_coef, a0_small, alphas, cp, cc, speeds,
                     out, jumps, failed):
    """Every point p over ``n_periods`` periods on the held ``inputs`` (its SOE group 2p),
    beside its *follower* (group 2p + 1): the same model restarted every period from the
    sample ``data[k]`` (where ``reset`` and finite; elsewhere from the point's state). At
    period ``starts[b]`` the point takes the follower's memory and state plus ``delta[p, b]``
    (the jump, node minus the state reached, kept in ``jumps[p, b]``); see the module
    docstring."""
    P = X0.shape[0]
    S = starts.shape[0]
    x = np.empty(4)
    x0 = np.empty(4)
    y = np.empty(4)
    y0 = np.empty(4)
    last_f = np.empty(4)
    bad = np.empty(4)
    held = np.zeros(12)
    held[10] = math.inf
    held[11] = math.inf
    for p in range(P):
        gp, gf = 2 * p, 2 * p + 1
        for i in range(4):
            x[i] = X0[p, i]
            x0[i] = X0[p, i]
            y[i] = X0[p, i]
            y0[i] = X0[p, i]
            out[p, 0, i] = x[i]
        n = 0
        b = 0
        for k in range(n_periods):
            if b < S and k == starts[b]:
                for i in range(4):
                    node = y[i] + delta[p, b, i]
                    jumps[p, b, i] = node - x[i]
                    x0[i] = y0[i] + delta[p, b, i]
                    x[i] = node
                    out[p, k, i] = x[i]
                H[gp, :, :] = H[gf, :, :]
                fill[gp] = fill[gf]
                b += 1
            held[8] = inputs[k, 0]
            held[9] = inputs[k, 1]
            taken = kernels.fom_soe_run(
                x, x0, n, hold, CV[p], smooth, held, False, H[gp:gp + 1], W[:, gp:gp + 1],
                fill[gp:gp + 1], eps_k[gp:gp + 1], ET[gp:gp + 1], a0_coef[gp:gp + 1],
                a0_small[gp:gp + 1], alphas[gp], cp[gp], cc[gp], last_f, bad)
            if b < S and taken == hold:
                taken = kernels.fom_soe_run(
                    y, y0, n, hold, CV[p], smooth, held, False, H[gf:gf + 1],
                    W[:, gf:gf + 1], fill[gf:gf + 1], eps_k[gf:gf + 1], ET[gf:gf + 1],
                    a0_coef[gf:gf + 1], a0_small[gf:gf + 1], alphas[gf], cp[gf], cc[gf],
                    last_f, bad)
                for i in range(4):             # restarted from the sample (its memory kept)
                    target = x[i]
                    if reset[i] and math.isfinite(data[k + 1, i]):
                        target = data[k + 1, i]
                    y0[i] += target - y[i]
                    y[i] = target
            n += taken
            v = speeds[p]
            if taken < hold or not (-v <= x[1] <= v and -1.5707963267948966 <= x[2]
                                    <= 1.5707963267948966):
                failed[p] = True
                for j in range(k + 1, n_periods + 1):
                    for i in range(4):
                        out[p, j, i] = np.nan
                for j in range(b, S):
                    for i in range(4):
                        jumps[p, j, i] = np.nan
                break
            for i in range(4):
                out[p, k + 1, i] = x[i]


def run_segments(params: Sequence[ModelParameters], n_periods: int, hold: int,
                 inputs: np.ndarray, starts: np.ndarray, data: np.ndarray,
                 reset: np.ndarray, delta: np.ndarray, *, initial_state: Sequence[float],
                 duration: float | None, threads: int = 1
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(states (P, n_periods + 1, 4), jumps (P, S, 4), failed (P,)) of the points ``params``
    replayed on ``inputs`` with nodes at the periods ``starts``, their followers restarted
    from ``data`` (n_periods + 1, 4; NaN: not measured) (:func:`_shooting_kernel`);
    ``threads`` > 1 splits the points over threads (the same numbers)."""
    params = list(params)
    if threads > 1 and len(params) > 1:
        from concurrent.futures import ThreadPoolExecutor

        m = min(int(threads), len(params))
        cuts = np.linspace(0, len(params), m + 1).round().astype(int)
        with ThreadPoolExecutor(m) as pool:
            parts = list(pool.map(lambda ab: run_segments(
                params[ab[0]:ab[1]], n_periods, hold, inputs, starts, data, reset,
                delta[ab[0]:ab[1]], initial_state=initial_state, duration=duration),
                zip(cuts[:-1], cuts[1:])))
        return tuple(np.concatenate([q[i] for q in parts]) for i in range(3))
    check_population(params)
    P, S = len(params), int(starts.size)
    X0 = np.tile(np.asarray(initial_state, dtype=float), (P, 1))
    CV = np.array([coefficients(p).kernel for p in params], dtype=float)
    hist, alphas, cp, cc = _soe_arrays([p for p in params for _ in range(2)], duration)
    speeds = np.array([p.speed for p in params], dtype=float)
    out = np.empty((P, n_periods + 1, 4))
    jumps = np.zeros((P, S, 4))
    failed = np.zeros(P, dtype=np.bool_)
    _shooting_kernel(X0, CV, params[0].planing_form == 'smooth',
                     np.ascontiguousarray(inputs[:n_periods], dtype=float), int(hold),
                     int(n_periods), np.ascontiguousarray(starts, dtype=np.int64),
                     np.ascontiguousarray(data[:n_periods + 1], dtype=float),
                     np.ascontiguousarray(reset, dtype=np.bool_),
                     np.ascontiguousarray(delta, dtype=float), hist.H, hist.W,
                     np.zeros(2 * P, dtype=np.int64), hist.eps_k, hist.ET, hist.a0_coef,
                     hist.a0_small, alphas, cp, cc, speeds, out, jumps, failed)
    return out, jumps, failed


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
        self.reset = problem.spec.measured.copy()
        c = np.where(self.reset, problem.w / problem.scale, 0.0)
        self.c = c                                   # a jump's weight per state (as a sample)
        self.h = 1e-6 * np.where(self.reset, problem.scale, 1.0)

    def starts(self, n: int) -> np.ndarray:
        """The node periods of a replay over ``n`` periods."""
        return np.arange(self.periods, n, self.periods, dtype=np.int64)

    def shoot(self, params: list[ModelParameters], upto: int, threads: int = 1) -> Shot:
        """The segmented replays of ``params`` over the first ``upto`` samples, their nodes
        fitted."""
        pr, d = self.problem, self.problem.data
        n = int(pr.index[upto - 1])
        starts = self.starts(n)
        S, P = starts.size, len(params)
        data_all = np.where(self.reset, pr.states, np.nan)
        kw = {'initial_state': d.initial_state, 'duration': d.duration, 'threads': threads}
        delta = np.zeros((P, S, 4))
        sel = pr.index[:upto]
        seg = np.searchsorted(starts, sel, side='right') - 1       # -1: from x(0), no node
        free = np.zeros(S, dtype=bool)
        free[np.unique(seg[seg >= 0])] = True         # nodes with samples to fit them
        data = pr.states[sel]
        for _ in range(self.iterations if S else 0):
            pts = [p for p in params for _ in range(5)]
            D = np.repeat(delta, 5, axis=0)
            for j in range(4):
                D[j + 1::5, :, j] += self.h[j]
            out, jumps, failed = run_segments(pts, n, pr.hold, d.inputs, starts, data_all,
                                              self.reset, D, **kw)
            for p in range(P):
                if failed[5 * p:5 * p + 5].any():
                    continue
                base = out[5 * p]
                r = (base[sel] - data) * pr.w / pr.scale                    # (T, 4)
                J = np.stack([(out[5 * p + 1 + j][sel] - base[sel]) * pr.w / pr.scale
                              / self.h[j] for j in range(4)], axis=-1)    # (T, 4, 4)
                A = np.zeros((S, 4, 4))
                g = np.zeros((S, 4))
                ok = seg >= 0
                np.add.at(A, seg[ok], np.einsum('tij,tik->tjk', J[ok], J[ok]))
                np.add.at(g, seg[ok], np.einsum('tij,ti->tj', J[ok], r[ok]))
                c2 = self.c ** 2
                A += np.eye(4)[None] * c2[None, :, None]          # the jump's own row
                g += c2[None] * jumps[5 * p]
                ridge = 1e-12 * np.maximum(np.trace(A, axis1=1, axis2=2), 1e-300)
                A += ridge[:, None, None] * np.eye(4)[None]
                step = -np.linalg.solve(A[free], g[free][..., None])[..., 0]
                delta[p, free] += step
        out, jumps, failed = run_segments(params, n, pr.hold, d.inputs, starts, data_all,
                                          self.reset, delta, **kw)
        jumps[:, ~free] = 0.0                     # a node before the window is not judged
        return Shot(states=out, jumps=jumps, failed=failed, starts=starts)

    def rows(self, shot: Shot) -> np.ndarray:
        """(P, S * 4) continuity rows: each jump in the units of a sample's residual."""
        r = shot.jumps * self.c
        r = np.where(np.isfinite(r), np.clip(r, -CLIP, CLIP), CLIP)
        return r.reshape(r.shape[0], -1)
