"""The compiled step of the vectorised environment: N vehicles, one call per control period.

:func:`step` is the whole env step in one call: it checks and holds the actions
(:func:`take_actions`), advances every active vehicle by one control period (:func:`periods`)
and scores it (:func:`score_step`, the default reward
:func:`fohssv_sim.envs.task.default_reward`). The Python around it does what only Python can:
the autoreset draws, a user's reward function and the ``infos`` dict.

The arrays travel in three tuples, built once by the env (:class:`~.vector.HSSVVectorEnv`)
and changed in place:

* ``task`` = (RW, episode_steps, fin, with_fp, with_error): per vehicle ``RW[p]`` =
  [target_depth, depth_scale, planing_weight, rate_weight, max_fin, max_cavitator,
  lost_penalty], the episode length; whether an action is [delta_f, delta_c] (else
  [delta_c]), whether the observation holds Fp, and z - target_depth;
* ``state`` = (X, FP, U, previous, steps, status, ended): state [z, w, theta, q], planing
  force, held inputs [delta_f, delta_c] and those before, periods taken, the last period's
  status (0 done, 1 the state turned non-finite: ``X[p]`` is the last finite state, 2 it left
  the plant's bounds |w| <= V, |theta| <= pi/2), episode ended;
* ``model`` = (kind, hold, smooth, paper, speeds, h, X0, N, CV, fom, rk): the model
  (:data:`FOM`, :data:`DELAY_FREE`, :data:`DELAYED`), steps per period, planing and immersion
  forms, per vehicle V, step, start state, step count and kernel coefficients, and the
  kind's own arrays: ``fom`` = (H, W, fill, eps_k, ET, a0_coef, a0_small, alphas, cp, cc),
  vehicle p's slice of one SOE history with a group per vehicle, advanced by the plant's own
  kernel (:func:`fohssv_sim.kernels.fom_soe_run`); ``rk`` = (HX, HF, LAG, TAU), each
  vehicle's delay history rings (padded to one size: the ring index is taken modulo the
  ring's size, so a larger ring holds the same values) for the RK4 kernels
  (:func:`~fohssv_sim.kernels.delay_free_run`, :func:`~fohssv_sim.kernels.delayed_run`).
  The kind not in use holds empty arrays.

Pure: numpy, numba; no rclpy.
"""

from __future__ import annotations

import math

import numpy as np

from .. import kernels, physics
from .task import default_reward

__all__ = ['FOM', 'DELAY_FREE', 'DELAYED', 'step', 'periods', 'planing', 'first_bad',
           'take_actions', 'score_step']

#: The kinds of compiled vehicles (``model[0]``).
FOM, DELAY_FREE, DELAYED = 0, 1, 2

_PI_2 = math.pi / 2


@physics.jitable
def _status(taken, hold, x, v):
    if taken < hold:
        return 1
    return 0 if -v <= x[1] <= v and -_PI_2 <= x[2] <= _PI_2 else 2


@kernels._njit
def planing(p, x, model):
    """Vehicle p's planing force at its state ``x`` after ``N[p]`` steps (the plant's rule for
    its model and form; before t = 0 a delayed vehicle's history is its start state)."""
    kind, _, smooth, paper, _, h, X0, N, CV, _, rk = model
    c = kernels.unpack_coefficients(CV[p])
    if kind != DELAYED:
        return physics.planing_smooth(x[1], c) if smooth else physics.planing_exact(x[1], c)
    HX, HF, LAG, TAU = rk
    if TAU[p] == 0.0:
        zd, wd, td = x[0], x[1], x[2]
    else:
        zd, wd, td, _ = physics.hermite_delayed(HX[p], HF[p], N[p], 0.0, LAG[p], h[p], X0[p])
    form = 'paper' if paper else 'geometric'
    return physics.planing_delayed(x[0], x[2], zd, wd, td, c, form)


@kernels._njit
def periods(active, state, model):
    """One control period of ``hold`` steps for every vehicle p with ``active[p]``, its input
    ``U[p]`` held: its model's kernel on its slice of the arrays; then ``FP[p]`` and
    ``status[p]`` (0 for a vehicle not active). The benchmark times this call alone."""
    X, FP, U, _, _, status, _ = state
    kind, hold, smooth, paper, speeds, h, X0, N, CV, fom, rk = model
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
        if kind == FOM:
            H, W, fill, eps_k, ET, a0_coef, a0_small, alphas, cp, cc = fom
            k = kernels.fom_soe_run(x, X0[p], N[p], hold, CV[p], smooth, held, False,
                                    H[p:p + 1], W[p], fill[p:p + 1], eps_k[p:p + 1],
                                    ET[p:p + 1], a0_coef[p:p + 1], a0_small[p:p + 1],
                                    alphas[p], cp[p], cc[p], last_f, bad)
        elif kind == DELAY_FREE:
            k = kernels.delay_free_run(x, hold, h[p], CV[p], smooth, held, False, bad)
        else:
            HX, HF, LAG, TAU = rk
            k = kernels.delayed_run(x, N[p], hold, h[p], CV[p], HX[p], HF[p], LAG[p], TAU[p],
                                    X0[p], paper, held, False, bad)
        N[p] += k
        FP[p] = planing(p, x, model)
        status[p] = _status(k, hold, x, speeds[p])


@kernels._njit
def first_bad(A, active, task):
    """The first ``active`` vehicle whose action is non-finite or beyond its limit, or -1."""
    RW = task[0]
    n, k = A.shape
    for p in range(n):
        if active[p]:
            for j in range(k):
                if not (abs(A[p, j]) <= RW[p, 6 - k + j]):     # max_fin, max_cavitator
                    return p
    return -1


@kernels._njit
def take_actions(A, active, task, state):
    """Hold the actions ``A`` of the ``active`` vehicles in ``U``, the inputs before in
    ``previous``; returns -1, or :func:`first_bad` (then nothing is written)."""
    bad = first_bad(A, active, task)
    if bad >= 0:
        return bad
    fin = task[2]
    _, _, U, previous, _, _, _ = state
    for p in range(A.shape[0]):
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
def score_step(active, task, state, model, out):
    """After a period, into ``out`` = (obs, F, B): each vehicle's observation ``obs[p]``
    ([z, w, theta, q], then Fp and z - target_depth as the task asks), ``F[:, p]`` = [reward,
    t, Fp, delta_f, delta_c] and ``B[:, p]`` = [lost, truncated]; an active vehicle's reward
    is the default one (less the penalty when its status says it was lost), its t = n h (n
    the steps taken, as the plant counts them); its step count and ``ended`` flag. A vehicle
    not active (just reset: Gymnasium's next-step autoreset) gets reward 0, no flags, t = 0.
    Returns (vehicles lost, vehicles whose episode ended)."""
    RW, episode_steps, _, with_fp, with_error = task
    X, FP, U, previous, steps, status, ended = state
    hold, h = model[1], model[5]
    obs, F, B = out
    n_lost = n_ended = 0
    for p in range(X.shape[0]):
        obs[p, :4] = X[p]
        j = 4
        if with_fp:
            obs[p, j] = FP[p]
            j += 1
        if with_error:
            obs[p, j] = X[p, 0] - RW[p, 0]
        F[2, p] = FP[p]
        F[3, p] = U[p, 0]
        F[4, p] = U[p, 1]
        if not active[p]:
            F[0, p] = 0.0
            F[1, p] = 0.0
            B[0, p] = False
            B[1, p] = False
            continue
        w = RW[p]
        r = default_reward(X[p, 0], FP[p], U[p, 0], U[p, 1], previous[p, 0], previous[p, 1],
                           w[0], w[1], w[2], w[3], w[4], w[5])
        steps[p] += 1
        lost = status[p] > 0
        truncated = not lost and steps[p] >= episode_steps[p]
        F[0, p] = r - w[6] if lost else r
        F[1, p] = (steps[p] * hold) * h[p]
        B[0, p] = lost
        B[1, p] = truncated
        ended[p] = lost or truncated
        n_lost += lost
        n_ended += ended[p]
    return n_lost, n_ended


@kernels._njit
def step(A, active, task, state, model, out):
    """The env step of every vehicle in one call: :func:`take_actions`, :func:`periods`,
    :func:`score_step`. Returns (-1, vehicles lost, vehicles whose episode ended), or
    (the first active vehicle whose action is bad, 0, 0) and nothing is stepped."""
    bad = take_actions(A, active, task, state)
    if bad >= 0:
        return bad, 0, 0
    periods(active, state, model)
    n_lost, n_ended = score_step(active, task, state, model, out)
    return -1, n_lost, n_ended
