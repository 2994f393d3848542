"""``HSSV-v0`` vectorised: N vehicles, one compiled call per control period.

:class:`HSSVVectorEnv` is a :class:`gymnasium.vector.VectorEnv` whose sub-environment ``i``
is the ``HSSV-v0`` built from the shared keyword arguments updated with ``vehicles[i]`` (each
vehicle its own model parameters, e.g. ``vehicles=[{'speed': 70}, {'speed': 80}]``) and
seeded with ``seed + i``, as :class:`gymnasium.vector.SyncVectorEnv` seeds its copies: its
observations equal those of that single environment (tested to 1e-12).

One compiled call per control period advances every vehicle by its integration steps
(:mod:`.stepping`): for the fractional model with its compiled 'soe' solver (the default)
the plant's own kernel on each vehicle's slice of one SOE history with a group per vehicle,
the layout of :mod:`fohssv_sim.analysis.population` (the vehicles then share the step, the
planing form and the 'soe' settings; an alpha drawn from ``order_range`` gets its group's
weights anew, padded to the modes the range's ends need); for the delay-free and delayed
models their RK4 kernels, each vehicle with its own history rings (the vehicles share the
model and its planing and immersion forms). The vehicles share ``control_period / step``.
Anything else (an interpreted solver, mixed models) steps each vehicle's plant in turn.

Autoreset: Gymnasium's next-step mode (``AutoresetMode.NEXT_STEP``): the step after a
vehicle's episode ended resets it (its action is ignored) and returns its first observation
with reward 0.

Pure: numpy, numba, Gymnasium and the core; no rclpy.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .. import kernels, physics
from ..analysis.population import _soe_arrays, check_population
from ..coefficients import coefficients
from ..models import make_plant
from ..params import ParameterError
from .single import spaces_of
from .stepping import fom_periods, int_periods, score_step, take_actions
from .task import make_task

__all__ = ['HSSVVectorEnv']


def _kind(params) -> str | None:
    """How the vehicles step together: 'fom' (the compiled 'soe' FOM), 'delay-free' or
    'delayed' (all of that model and planing or immersion form), else None (each vehicle's
    plant in turn: an interpreted solver, or mixed models)."""
    models = {p.model for p in params}
    if models == {'fractional'}:
        return 'fom' if all(p.solver == 'soe' for p in params) else None
    forms = {(p.planing_form, p.immersion_form) for p in params}
    return models.pop() if len(models) == 1 and len(forms) == 1 else None


class HSSVVectorEnv(VectorEnv):
    """N ``HSSV-v0`` vehicles stepped together; see the module docstring.

    Args:
        num_envs: N >= 1.
        vehicles: None, or N mappings of per-vehicle keyword arguments (model parameters or
            any other ``HSSV-v0`` keyword) applied over ``kwargs``.
        kwargs: the ``HSSV-v0`` keyword arguments shared by every vehicle.

    ``infos`` holds ``t``, ``planing_force``, ``delta_f``, ``delta_c`` arrays (and ``lost``,
    an object array of texts, when a vehicle was lost), with Gymnasium's ``_name`` masks.

    Raises:
        ParameterError: a bad keyword argument, ``vehicles`` of the wrong length, or FOM
            vehicles that cannot share one compiled call.
    """

    metadata = {'render_modes': [], 'autoreset_mode': AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, vehicles: Sequence[Mapping[str, Any]] | None = None,
                 **kwargs: Any) -> None:
        if isinstance(num_envs, bool) or int(num_envs) != num_envs or num_envs < 1:
            raise ParameterError(f'num_envs={num_envs!r} is not valid; allowed: a whole '
                                 'number >= 1')
        self.num_envs = n = int(num_envs)
        if vehicles is not None and len(vehicles) != n:
            raise ParameterError(f'vehicles has {len(vehicles)} entries; allowed: one mapping '
                                 f'per vehicle (num_envs={n})')
        self.tasks = [make_task({**kwargs, **(vehicles[i] if vehicles else {})})
                      for i in range(n)]
        t0 = self.tasks[0]
        self.single_observation_space, self.single_action_space = spaces_of(t0)
        for t in self.tasks[1:]:
            if (t.observation_size, t.action_size) != (t0.observation_size, t0.action_size):
                raise ParameterError('vehicles must share fin, observe_planing_force and '
                                     'observe_depth_error (one observation and action space)')
        ts = self.tasks
        # the per-vehicle task values of the default reward (score_step)
        self._rw = np.array([[t.target_depth, t.depth_scale, t.planing_weight, t.rate_weight,
                              *t.limits.tolist(), t.lost_penalty] for t in ts])
        limits = np.stack([t.limits for t in ts])
        self._act_limits = np.ascontiguousarray(limits if t0.fin else limits[:, 1:])
        self._episode_steps = np.array([t.episode_steps for t in ts], dtype=np.int64)
        self._holds = np.array([t.hold for t in ts])
        self._h = np.array([t.params.step for t in ts])
        self._user_reward = any(t.reward is not None for t in ts)
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        params = [t.params for t in self.tasks]
        if len({t.hold for t in ts}) > 1:
            raise ParameterError('vehicles must share control_period / step (the integration '
                                 'steps of one env step)')
        self._kind = _kind(params)
        if self._kind == 'fom':
            try:
                check_population(params)
            except ValueError as exc:
                raise ParameterError(f'vehicles of one vectorised FOM env: {exc}') from None
            self._build_fom(params)
        elif self._kind is not None:
            self._build_int(params)
        self._plants = [None] * n
        self._params = params
        self._rngs = [np.random.default_rng() for _ in range(n)]
        self.X = np.zeros((n, 4))
        self.FP = np.zeros(n)
        self.U = np.zeros((n, 2))
        self._previous = np.zeros((n, 2))
        self._speed = np.array([p.speed for p in params])
        self._steps = np.zeros(n, dtype=np.int64)
        self._ended = np.ones(n, dtype=bool)
        self._status = np.zeros(n, dtype=np.int64)
        self._every = np.ones(n, dtype=bool)
        self._why: dict[int, str] = {}
        self._started = False

    def _build_fom(self, params) -> None:
        n = self.num_envs
        # the ends of each order_range join the layout as groups of their own (dropped below),
        # so that the history holds as many modes as any alpha a reset may draw needs: the
        # count falls as alpha rises (checked at each draw)
        ends = [p.replace(fractional_order=a) for t, p in zip(self.tasks, params)
                if t.order_range is not None for a in t.order_range]
        hist, alphas, cp, cc = _soe_arrays([*params, *ends], self.tasks[0].duration)
        self._modes = hist.L
        # the weights regrouped by vehicle: (vehicle, fill, 1, row, 2), one block each
        self._W = np.ascontiguousarray(hist.W[:, :n].transpose(1, 0, 2, 3))[:, :, None]
        self._fom = dict(X0=np.zeros((n, 4)), N=np.zeros(n, dtype=np.int64),
                         CV=np.array([coefficients(p).kernel for p in params], dtype=float),
                         smooth=params[0].planing_form == 'smooth', alphas=alphas[:n].copy(),
                         cp=cp[:n].copy(), cc=cc[:n].copy(),
                         fill=np.zeros(n, dtype=np.int64),      # each group's buffer fill
                         **{k: np.ascontiguousarray(getattr(hist, k)[:n]) for k in (
                             'H', 'eps_k', 'ET', 'a0_coef', 'a0_small')})

    def _new_order(self, i: int, params) -> None:
        """Vehicle ``i``'s history group for a newly drawn alpha: its one-group history's
        weights, padded to the layout's modes as the history pads every group (zero weights,
        the decay of its fastest mode)."""
        one, alphas, cp, cc = _soe_arrays([params], self.tasks[i].duration)
        f, m, L = self._fom, one.L, self._modes
        if m > L:
            raise RuntimeError(f'fractional_order={params.fractional_order:g} needs {m} SOE '
                               f'modes, more than the {L} its order_range was laid out for')
        W = self._W[i, :, 0]
        W[:] = 0.0
        W[:, 1:1 + m] = one.W[:, 0, 1:1 + m]
        W[:, 1 + L:] = one.W[:, 0, 1 + m:]
        f['eps_k'][i, 0, :m] = one.eps_k[0, 0]
        f['eps_k'][i, 0, m:] = one.eps_k[0, 0, m - 1]
        f['ET'][i, :, :m] = one.ET[0]
        f['ET'][i, :, m:] = one.ET[0, :, m - 1:m]
        f['a0_coef'][i] = one.a0_coef[0]
        f['a0_small'][i] = one.a0_small[0]
        f['alphas'][i], f['cp'][i], f['cc'][i] = alphas[0], cp[0], cc[0]

    def _build_int(self, params) -> None:
        n = self.num_envs
        taus = []
        for t in self.tasks:                # the longest delay a reset may draw sizes the rings
            p = t.params
            if t.speed_range is not None and p.advection_delay == 'consistent':
                p = p.replace(speed=t.speed_range[0])
            taus.append(p.delay if p.model == 'delayed' else 0.0)
        size = int(math.ceil(max(tau / p.step for tau, p in zip(taus, params)))) + 3
        self._int = dict(X0=np.zeros((n, 4)), N=np.zeros(n, dtype=np.int64),
                         H=np.array([p.step for p in params]),
                         CV=np.array([coefficients(p).kernel for p in params], dtype=float),
                         smooth=params[0].planing_form == 'smooth',
                         delayed=self._kind == 'delayed',
                         HX=np.zeros((n, size, 4)), HF=np.zeros((n, size, 4)),
                         LAG=np.zeros(n), TAU=np.zeros(n),
                         paper=params[0].immersion_form == 'paper')

    # -- reset ------------------------------------------------------------------------------
    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Reset every vehicle; ``seed`` an int (vehicle i gets ``seed + i``), a list of N
        seeds or None; ``options`` as ``HSSV-v0``'s (``initial_state`` for every vehicle)."""
        n = self.num_envs
        if seed is None:
            seeds = [None] * n
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f'seed has {len(seeds)} entries; allowed: an int, None or '
                                 f'{n} seeds')
        for i, s in enumerate(seeds):
            if s is not None or not self._started:
                self._rngs[i] = gym.utils.seeding.np_random(s)[0]
        x0 = (options or {}).get('initial_state')
        for i in range(n):
            self._reset_one(i, x0)
        self._started = True
        return self._observe(), self._infos()

    def _reset_one(self, i: int, initial_state: Any = None) -> None:
        task = self.tasks[i]
        params, x0 = task.draw(self._rngs[i], initial_state)
        self._params[i] = params
        self._speed[i] = params.speed
        self.X[i] = x0
        self.U[i] = 0.0
        self._steps[i] = 0
        self._ended[i] = False
        if self._kind == 'fom':
            f = self._fom
            f['X0'][i] = x0
            f['N'][i] = 0
            f['CV'][i] = coefficients(params).kernel
            if params.fractional_order != f['alphas'][i]:
                self._new_order(i, params)
            f['H'][i] = 0.0
            f['fill'][i] = 0
            c = kernels._coefficients(f['CV'][i])
            w = float(x0[1])
            self.FP[i] = physics.planing_smooth(w, c) if f['smooth'] else \
                physics.planing_exact(w, c)
        elif self._kind is not None:
            f = self._int
            f['X0'][i] = x0
            f['N'][i] = 0
            f['CV'][i] = coefficients(params).kernel
            f['HX'][i] = 0.0
            f['HF'][i] = 0.0
            tau = params.delay if f['delayed'] else 0.0
            f['TAU'][i] = tau
            f['LAG'][i] = tau / params.step
            c = kernels._coefficients(f['CV'][i])
            z, w, th, _ = (float(v) for v in x0)
            if f['delayed']:      # before t = 0 the history is x(0): the delayed state is x0
                form = 'paper' if f['paper'] else 'geometric'
                self.FP[i] = physics.planing_delayed(z, th, z, w, th, c, form)
            else:
                self.FP[i] = physics.planing_smooth(w, c) if f['smooth'] else \
                    physics.planing_exact(w, c)
        else:
            plant = self._plants[i]
            if plant is not None and plant.params == params:
                plant.reset(x0)
            else:
                plant = self._plants[i] = make_plant(params, x0, duration=task.duration)
            self.FP[i] = plant.planing_force

    # -- step -------------------------------------------------------------------------------
    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        """One control period of every vehicle (see the module docstring for autoreset).

        Raises:
            RuntimeError: before the first reset.
            ValueError: actions of the wrong shape, or an active vehicle's action non-finite
                or beyond its limit (as ``HSSV-v0`` words it); nothing is stepped then.
        """
        if not self._started:
            raise RuntimeError('call reset() before step()')
        active = ~self._ended
        self._take(actions, active)
        status = self._run(active)
        n = self.num_envs
        rewards, lost, truncated = np.empty(n), np.empty(n, bool), np.empty(n, bool)
        score_step(self.X, self.U, self._previous, self.FP, self._rw, active, status,
                   self._steps, self._episode_steps, rewards, lost, truncated, self._ended)
        if self._user_reward:
            for i in np.flatnonzero(active):
                rewards[i] = self.tasks[i].score(self.X[i].copy(), self.U[i].copy(),
                                                 self._previous[i].copy(), float(self.FP[i]),
                                                 bool(lost[i]))
        return self._observe(), rewards, lost, truncated, self._infos(status)

    def _take(self, actions: Any, active: np.ndarray) -> None:
        """Check the actions of the ``active`` vehicles (nothing changes when one is bad),
        reset the others, hold the actions in ``U``."""
        lim = self._act_limits
        a = np.asarray(actions, dtype=float)
        if a.shape != lim.shape:
            raise ValueError(f'actions of shape {a.shape} must have the shape {lim.shape} '
                             '(num_envs, action size)')
        bad = take_actions(a, lim, lim.shape[1] == 2, active, self.U, self._previous)
        if bad >= 0:
            self.tasks[bad].action(a[bad])               # raises, naming value and range
        if not active.all():
            for i in np.flatnonzero(~active):
                self._reset_one(int(i))

    def _run(self, active: np.ndarray) -> np.ndarray:
        """One control period of the ``active`` vehicles; each one's status (0 fine, 1 the
        state turned non-finite, 2 it left the plant's bounds)."""
        status = self._status
        if self._kind is not None:
            self._advance(active)
            return status
        self._why = {}
        status[:] = 0
        for i in np.flatnonzero(active):
            plant = self._plants[i]
            try:
                plant.advance((self.U[i, 0], self.U[i, 1]), self.tasks[i].hold)
            except FloatingPointError as exc:
                status[i] = 1
                self._why[i] = str(exc)
            self.X[i] = plant.x
            self.FP[i] = plant.planing_force
            if not (status[i] or self.tasks[i].in_bounds(self.X[i], self._speed[i])):
                status[i] = 2
        return status

    def _advance(self, active: np.ndarray) -> None:
        """The one compiled call: a control period of every ``active`` vehicle with its input
        ``U`` held (no rewards, no observations; the benchmark times it alone)."""
        hold = self.tasks[0].hold
        if self._kind != 'fom':
            f = self._int
            int_periods(self.X, f['N'], hold, f['H'], f['CV'], f['smooth'], f['delayed'],
                        f['HX'], f['HF'], f['LAG'], f['TAU'], f['X0'], f['paper'], self.U,
                        active, self._speed, self.FP, self._status)
            return
        f = self._fom
        fom_periods(self.X, f['X0'], f['N'], hold, f['CV'], f['smooth'], self.U, active,
                    f['H'], self._W, f['fill'], f['eps_k'], f['ET'], f['a0_coef'],
                    f['a0_small'], f['alphas'], f['cp'], f['cc'], self._speed, self.FP,
                    self._status)

    def _lost_text(self, i: int, status: int) -> str:
        """Why vehicle ``i`` was lost in the step just taken."""
        t = float(self._steps[i] * self._holds[i]) * self._h[i]
        if status == 1:
            return self._why.get(i) or f'state became non-finite at t={t:.9g} s'
        return (f'state beyond physical bounds at t={t:.9g} s: [z, w, theta, q] = '
                f'{self.X[i].tolist()} (|w| <= V = {self._speed[i]:g} m/s, |theta| <= pi/2 '
                'rad)')

    def _observe(self) -> np.ndarray:
        return self.tasks[0].observe(self.X, self.FP, self._rw[:, 0])

    def _infos(self, status: np.ndarray | None = None) -> dict[str, Any]:
        # t = n h with n the steps taken, as the plant counts it
        t = (self._steps * self._holds) * self._h
        infos = {'t': t, 'planing_force': self.FP.copy(), 'delta_f': self.U[:, 0].copy(),
                 'delta_c': self.U[:, 1].copy()}
        every = self._every
        for k in list(infos):
            infos['_' + k] = every
        if status is not None and status.any():
            lost = status > 0
            infos['lost'] = np.array([self._lost_text(i, s) if s else ''
                                      for i, s in enumerate(status.tolist())], dtype=object)
            infos['_lost'] = lost
        return infos
