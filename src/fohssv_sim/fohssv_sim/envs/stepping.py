"""The compiled calls of the vectorised environment: N vehicles, one call per control period.

:func:`fom_periods` advances FOM vehicles through the plant's own kernel
(:func:`fohssv_sim.kernels.fom_soe_run`) on each vehicle's slice of one SOE history with a group
per vehicle; :func:`int_periods` the integer models through theirs
(:func:`~fohssv_sim.kernels.delay_free_run`, :func:`~fohssv_sim.kernels.delayed_run`, each
vehicle with its own history rings, padded to one size: the ring index is taken modulo the
ring's size, so a larger ring holds the same values). Both leave each vehicle's planing force
and status (0 done, 1 the state turned non-finite, 2 it left the plant's bounds |w| <= V,
|theta| <= pi/2). :func:`take_actions` and :func:`score_step` are the env's per-step checks
and bookkeeping (the default reward, :func:`fohssv_sim.envs.task.default_reward`).

Pure: numpy, numba; no rclpy.
"""

from __future__ import annotations

import math

import numpy as np

from .. import kernels, physics
from .task import default_reward

__all__ = ['fom_periods', 'int_periods', 'take_actions', 'score_step']

_PI_2 = math.pi / 2


@physics.jitable
def _status(taken, hold, x, v):
    if taken < hold:
        return 1
    return 0 if -v <= x[1] <= v and -_PI_2 <= x[2] <= _PI_2 else 2


@kernels._njit
def fom_periods(X, X0, N, hold, CV, smooth, U, active, H, W, fill, eps_k, ET, a0_coef,
                a0_small, alphas, cp, cc, speeds, FP, status):
    """One control period of ``hold`` steps for every vehicle p with ``active[p]``, input
    ``U[p]`` held: the plant's kernel on p's slice of the arrays (state ``X[p]``, start
    ``X0[p]``, step count ``N[p]``, history group p, whose weights ``W[p]`` are stored
    together: the history's (steps, group, ...) table regrouped by vehicle, so each vehicle's
    period reads one contiguous block). ``status[p]``: 0 done, 1 the state turned non-finite
    (``X[p]`` is the last finite state), 2 it left the plant's bounds |w| <= ``speeds[p]``,
    |theta| <= pi/2 (0 for a vehicle not active); ``FP[p]``: Fp at X[p]."""
    held = np.zeros(12)
    held[10] = math.inf
    held[11] = math.inf
    last_f = np.empty(4)
    bad = np.empty(4)
    for p in range(X.shape[0]):
        if not active[p]:
            status[p] = 0
            continue
        held[8] = U[p, 0]
        held[9] = U[p, 1]
        x = X[p]
        k = kernels.fom_soe_run(x, X0[p], N[p], hold, CV[p], smooth, held, False, H[p:p + 1],
                                W[p], fill[p:p + 1], eps_k[p:p + 1], ET[p:p + 1],
                                a0_coef[p:p + 1], a0_small[p:p + 1], alphas[p], cp[p], cc[p],
                                last_f, bad)
        N[p] += k
        c = kernels._coefficients(CV[p])
        FP[p] = physics.planing_smooth(x[1], c) if smooth else physics.planing_exact(x[1], c)
        status[p] = _status(k, hold, x, speeds[p])


@kernels._njit
def int_periods(X, N, hold, H, CV, smooth, delayed, HX, HF, LAG, TAU, X0, paper, U, active,
                speeds, FP, status):
    """One control period of ``hold`` steps for every integer-model vehicle p with
    ``active[p]``, input ``U[p]`` held: RK4 of eq. 17 (``delayed`` False) or of eqs. 22-25
    with the rings ``HX[p]``, ``HF[p]``, delay ``TAU[p]`` (``LAG[p]`` steps) and the history
    before t = 0 ``X0[p]``; step ``H[p]``, step count ``N[p]``. Fp and status as
    :func:`fom_periods`."""
    held = np.zeros(12)
    held[10] = math.inf
    held[11] = math.inf
    bad = np.empty(4)
    for p in range(X.shape[0]):
        if not active[p]:
            status[p] = 0
            continue
        held[8] = U[p, 0]
        held[9] = U[p, 1]
        x = X[p]
        c = kernels._coefficients(CV[p])
        if delayed:
            k = kernels.delayed_run(x, N[p], hold, H[p], CV[p], HX[p], HF[p], LAG[p], TAU[p],
                                    X0[p], paper, held, False, bad)
            N[p] += k
            if TAU[p] == 0.0:
                zd, wd, td = x[0], x[1], x[2]
            else:
                zd, wd, td, _ = physics.hermite_delayed(HX[p], HF[p], N[p], 0.0, LAG[p], H[p],
                                                        X0[p])
            if paper:
                FP[p] = physics.planing_delayed(x[0], x[2], zd, wd, td, c, 'paper')
            else:
                FP[p] = physics.planing_delayed(x[0], x[2], zd, wd, td, c, 'geometric')
        else:
            k = kernels.delay_free_run(x, hold, H[p], CV[p], smooth, held, False, bad)
            N[p] += k
            FP[p] = physics.planing_smooth(x[1], c) if smooth else physics.planing_exact(x[1], c)
        status[p] = _status(k, hold, x, speeds[p])


@kernels._njit
def take_actions(A, lim, fin, active, U, previous):
    """Hold the actions ``A`` of the ``active`` vehicles in ``U`` (``fin``: A is [delta_f,
    delta_c], else [delta_c]), the inputs before in ``previous``; returns -1, or the first
    active vehicle whose action is non-finite or beyond its limit ``lim`` (nothing written)."""
    n, k = A.shape
    for p in range(n):
        if active[p]:
            for j in range(k):
                if not (abs(A[p, j]) <= lim[p, j]):
                    return p
    for p in range(n):
        previous[p, 0] = U[p, 0]
        previous[p, 1] = U[p, 1]
        if active[p]:
            if fin:
                U[p, 0] = A[p, 0]
                U[p, 1] = A[p, 1]
            else:
                U[p, 1] = A[p, 0]
    return -1


@kernels._njit
def score_step(X, U, previous, FP, RW, active, status, steps, episode_steps, R, lost,
               truncated, ended):
    """After a period: each active vehicle's default reward (``RW[p]`` = [target_depth,
    depth_scale, planing_weight, rate_weight, max_fin, max_cavitator, lost_penalty]; less
    the penalty when ``status[p]`` says it was lost), its step count, and the lost,
    truncated and ended flags (all False and reward 0 for a vehicle not active)."""
    for p in range(X.shape[0]):
        if not active[p]:
            R[p] = 0.0
            lost[p] = False
            truncated[p] = False
            ended[p] = False
            continue
        w = RW[p]
        r = default_reward(X[p, 0], FP[p], U[p, 0], U[p, 1], previous[p, 0], previous[p, 1],
                           w[0], w[1], w[2], w[3], w[4], w[5])
        steps[p] += 1
        lost[p] = status[p] > 0
        R[p] = r - w[6] if lost[p] else r
        truncated[p] = not lost[p] and steps[p] >= episode_steps[p]
        ended[p] = lost[p] or truncated[p]
