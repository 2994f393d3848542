"""``HSSV-v0`` vectorised: N vehicles, one compiled call per control period.

:class:`HSSVVectorEnv` is a :class:`gymnasium.vector.VectorEnv` whose sub-environment ``i``
is the ``HSSV-v0`` built from the shared keyword arguments updated with ``vehicles[i]`` (each
vehicle its own model parameters, e.g. ``vehicles=[{'speed': 70}, {'speed': 80}]``) and
seeded with ``seed + i``, as :class:`gymnasium.vector.SyncVectorEnv` seeds its copies: its
observations equal those of that single environment (tested to 1e-12).

One compiled call per control period is the whole step of every vehicle (:mod:`.stepping`:
the action check, the integration steps, the bounds, the default reward, the observations
and the arrays of ``infos``); the Python around it draws the autoresets, calls a user's
reward function and builds the ``infos`` dict. It runs, for the fractional model with its
compiled 'soe' solver (the default), the plant's own kernel on each vehicle's slice of one
SOE history with a group per vehicle, the layout of :mod:`fohssv_sim.analysis.population`
(the vehicles then share the step, the planing form and the 'soe' settings; an alpha drawn
from ``order_range`` gets its group's weights anew, padded to the modes the range's ends
need); for the delay-free and delayed models their RK4 kernels, each vehicle with its own
history rings (the vehicles share the model and its planing and immersion forms). The
vehicles share ``control_period / step``. Anything else (an interpreted solver, mixed
models) steps each vehicle's plant in turn.

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

from ..analysis.population import _soe_arrays, check_population
from ..coefficients import coefficients
from ..models import make_plant
from ..params import ParameterError
from . import stepping
from .single import spaces_of
from .task import make_task

__all__ = ['HSSVVectorEnv', 'warm_up']

#: The vehicles step each its own plant in turn (an interpreted solver, or mixed models).
_PLANTS = -1
_INFO_KEYS = ('t', 'planing_force', 'delta_f', 'delta_c')


def _kind(params) -> int:
    """How the vehicles step together: ``stepping.FOM`` (the compiled 'soe' FOM),
    ``DELAY_FREE`` or ``DELAYED`` (all of that model and planing or immersion form), else
    :data:`_PLANTS` (each vehicle's plant in turn: an interpreted solver, or mixed models)."""
    models = {p.model for p in params}
    if models == {'fractional'}:
        return stepping.FOM if all(p.solver == 'soe' for p in params) else _PLANTS
    forms = {(p.planing_form, p.immersion_form) for p in params}
    if len(models) > 1 or len(forms) > 1:
        return _PLANTS
    return stepping.DELAY_FREE if models.pop() == 'delay-free' else stepping.DELAYED


def _no_fom() -> tuple:
    """The ``fom`` tuple of vehicles that are not FOM: empty arrays of its types."""
    f, i = np.float64, np.int64
    return tuple(np.zeros((0,) * d, dtype=t) for d, t in
                 ((3, f), (5, f), (1, i), (3, f), (3, f), (2, f), (2, f), (1, f), (1, f), (1, f)))


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
        self.tasks = ts = [make_task({**kwargs, **(vehicles[i] if vehicles else {})})
                           for i in range(n)]
        t0 = ts[0]
        self.single_observation_space, self.single_action_space = spaces_of(t0)
        for t in ts[1:]:
            if (t.observation_size, t.action_size) != (t0.observation_size, t0.action_size):
                raise ParameterError('vehicles must share fin, observe_planing_force and '
                                     'observe_depth_error (one observation and action space)')
        if len({t.hold for t in ts}) > 1:
            raise ParameterError('vehicles must share control_period / step (the integration '
                                 'steps of one env step)')
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self._user_reward = any(t.reward is not None for t in ts)
        self._action_shape = (n, t0.action_size)
        self._obs_shape = (n, t0.observation_size)
        self._params = params = [t.params for t in ts]
        # the arrays of the compiled step (see stepping's docstring), changed in place
        rw = np.array([[t.target_depth, t.depth_scale, t.planing_weight, t.rate_weight,
                        *t.limits.tolist(), t.lost_penalty] for t in ts])
        self._task = (rw, np.array([t.episode_steps for t in ts], dtype=np.int64), t0.fin,
                      t0.observe_planing_force, t0.observe_depth_error)
        self.X, self.FP, self.U = np.zeros((n, 4)), np.zeros(n), np.zeros((n, 2))
        self._ended = np.ones(n, dtype=bool)
        self._all = np.ones(n, dtype=bool)     # every vehicle active (read-only)
        self._n_ended = n               # vehicles whose episode ended at the last step
        self._state = (self.X, self.FP, self.U, np.zeros((n, 2)), np.zeros(n, dtype=np.int64),
                       np.zeros(n, dtype=np.int64), self._ended)
        self._plants = [None] * n
        self._build_model(_kind(params))
        self._rngs = [np.random.default_rng() for _ in range(n)]
        self._masks = {f'_{k}': np.ones(n, dtype=bool) for k in _INFO_KEYS}
        self._why: dict[int, str] = {}
        self._started = False

    def _build_model(self, kind: int) -> None:
        """The ``model`` tuple of the compiled step for vehicles of ``kind``."""
        n, params = self.num_envs, self._params
        self._speed = np.array([p.speed for p in params])
        fom = _no_fom()
        rk = (np.zeros((0, 0, 0)), np.zeros((0, 0, 0)), np.zeros(0), np.zeros(0))
        if kind == stepping.FOM:
            try:
                check_population(params)
            except ValueError as exc:
                raise ParameterError(f'vehicles of one vectorised FOM env: {exc}') from None
            fom = self._fom_arrays(params)
        elif kind in (stepping.DELAY_FREE, stepping.DELAYED):
            size = 3
            for t in self.tasks:        # the longest delay a reset may draw sizes the rings
                p = t.params
                if t.speed_range is not None and p.advection_delay == 'consistent':
                    p = p.replace(speed=t.speed_range[0])
                if kind == stepping.DELAYED:
                    size = max(size, int(math.ceil(p.delay / p.step)) + 3)
            rk = (np.zeros((n, size, 4)), np.zeros((n, size, 4)), np.zeros(n), np.zeros(n))
        p0 = params[0]
        self._model = (kind, self.tasks[0].hold, p0.planing_form == 'smooth',
                       p0.immersion_form == 'paper', self._speed,
                       np.array([p.step for p in params]), np.zeros((n, 4)),
                       np.zeros(n, dtype=np.int64),
                       np.array([coefficients(p).kernel for p in params], dtype=float), fom, rk)

    def _fom_arrays(self, params) -> tuple:
        """The ``fom`` tuple: one SOE history with a group per vehicle."""
        n = self.num_envs
        # the ends of each order_range join the layout as groups of their own (dropped below),
        # so that the history holds as many modes as any alpha a reset may draw needs: the
        # count falls as alpha rises (checked at each draw)
        ends = [p.replace(fractional_order=a) for t, p in zip(self.tasks, params)
                if t.order_range is not None for a in t.order_range]
        hist, alphas, cp, cc = _soe_arrays([*params, *ends], self.tasks[0].duration)
        self._modes = hist.L
        # the weights regrouped by vehicle: (vehicle, fill, 1, row, 2), one block each, so
        # that each vehicle's period reads one contiguous block
        W = np.ascontiguousarray(hist.W[:, :n].transpose(1, 0, 2, 3))[:, :, None]
        H, eps_k, ET, a0_coef, a0_small = (np.ascontiguousarray(getattr(hist, k)[:n]) for k in
                                           ('H', 'eps_k', 'ET', 'a0_coef', 'a0_small'))
        return (H, W, np.zeros(n, dtype=np.int64), eps_k, ET, a0_coef, a0_small,
                alphas[:n].copy(), cp[:n].copy(), cc[:n].copy())

    def _new_order(self, i: int, params) -> None:
        """Vehicle ``i``'s history group for a newly drawn alpha: its one-group history's
        weights, padded to the layout's modes as the history pads every group (zero weights,
        the decay of its fastest mode)."""
        one, alphas, cp, cc = _soe_arrays([params], self.tasks[i].duration)
        _, W, _, eps_k, ET, a0_coef, a0_small, f_alphas, f_cp, f_cc = self._model[9]
        m, L = one.L, self._modes
        if m > L:
            raise RuntimeError(f'fractional_order={params.fractional_order:g} needs {m} SOE '
                               f'modes, more than the {L} its order_range was laid out for')
        W = W[i, :, 0]
        W[:] = 0.0
        W[:, 1:1 + m] = one.W[:, 0, 1:1 + m]
        W[:, 1 + L:] = one.W[:, 0, 1 + m:]
        eps_k[i, 0, :m] = one.eps_k[0, 0]
        eps_k[i, 0, m:] = one.eps_k[0, 0, m - 1]
        ET[i, :, :m] = one.ET[0]
        ET[i, :, m:] = one.ET[0, :, m - 1:m]
        a0_coef[i] = one.a0_coef[0]
        a0_small[i] = one.a0_small[0]
        f_alphas[i], f_cp[i], f_cc[i] = alphas[0], cp[0], cc[0]

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
        self._n_ended = 0
        self._started = True
        infos = {'t': np.zeros(n), 'planing_force': self.FP.copy(),
                 'delta_f': self.U[:, 0].copy(), 'delta_c': self.U[:, 1].copy(),
                 **self._masks}
        return self.tasks[0].observe(self.X, self.FP, self._task[0][:, 0]), infos

    def _reset_one(self, i: int, initial_state: Any = None) -> None:
        task = self.tasks[i]
        params, x0 = task.draw(self._rngs[i], initial_state)
        self._params[i] = params
        self._speed[i] = params.speed
        self.X[i] = x0
        self.U[i] = 0.0
        self._state[4][i] = 0               # steps
        self._ended[i] = False
        kind, *_, X0, N, CV, fom, rk = self._model
        if kind == _PLANTS:
            plant = self._plants[i]
            if plant is not None and plant.params == params:
                plant.reset(x0)
            else:
                plant = self._plants[i] = make_plant(params, x0, duration=task.duration)
            self.FP[i] = plant.planing_force
            return
        X0[i] = x0
        N[i] = 0
        CV[i] = coefficients(params).kernel
        if kind == stepping.FOM:
            if params.fractional_order != fom[7][i]:
                self._new_order(i, params)
            fom[0][i] = 0.0                 # the history H and its fill
            fom[2][i] = 0
        else:
            HX, HF, LAG, TAU = rk
            HX[i] = 0.0
            HF[i] = 0.0
            TAU[i] = params.delay if kind == stepping.DELAYED else 0.0
            LAG[i] = TAU[i] / params.step
        self.FP[i] = stepping.planing(i, self.X[i], self._model)

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
        a = np.asarray(actions, dtype=float)
        if a.shape != self._action_shape:
            raise ValueError(f'actions of shape {a.shape} must have the shape '
                             f'{self._action_shape} (num_envs, action size)')
        n = self.num_envs
        if self._n_ended:                   # Gymnasium's next-step autoreset
            active = ~self._ended
            self._autoreset(a, active)
        else:
            active = self._all
        obs, F, B = out = (np.empty(self._obs_shape), np.empty((5, n)),
                           np.empty((2, n), dtype=bool))
        if self._model[0] != _PLANTS:
            bad, n_lost, self._n_ended = stepping.step(a, active, self._task, self._state,
                                                       self._model, out)
        else:
            bad = stepping.take_actions(a, active, self._task, self._state)
            if bad < 0:
                self._plant_periods(active)
                n_lost, self._n_ended = stepping.score_step(active, self._task, self._state,
                                                            self._model, out)
        if bad >= 0:
            self.tasks[bad].action(a[bad])               # raises, naming value and range
        rewards, lost = F[0], B[0]
        if self._user_reward:
            previous = self._state[3]
            for i in np.flatnonzero(active).tolist():
                rewards[i] = self.tasks[i].score(self.X[i].copy(), self.U[i].copy(),
                                                 previous[i].copy(), float(self.FP[i]),
                                                 bool(lost[i]))
        infos = {'t': F[1], 'planing_force': F[2], 'delta_f': F[3], 'delta_c': F[4],
                 **self._masks}
        if n_lost:
            infos['lost'] = np.array([self._lost_text(i) if lost[i] else ''
                                      for i in range(n)], dtype=object)
            infos['_lost'] = lost
        return obs, rewards, lost, B[1], infos

    def _autoreset(self, actions: np.ndarray, active: np.ndarray) -> None:
        """Reset the vehicles not ``active`` (their episode ended at the step before), once
        the others' actions are known good (a bad one changes nothing)."""
        bad = stepping.first_bad(actions, active, self._task)
        if bad >= 0:
            self.tasks[bad].action(actions[bad])         # raises, naming value and range
        for i in np.flatnonzero(~active).tolist():
            self._reset_one(i)
        self._n_ended = 0

    def _plant_periods(self, active: np.ndarray) -> None:
        """One control period of each ``active`` vehicle's own plant, in turn (the models
        the compiled step does not run); their status as :func:`.stepping.periods` leaves it."""
        status = self._state[5]
        self._why = {}
        status[:] = 0
        for i in np.flatnonzero(active).tolist():
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

    def _advance(self, active: np.ndarray) -> None:
        """The compiled advance alone: a control period of every ``active`` vehicle with its
        input ``U`` held (no checks, rewards or observations; the benchmark times it)."""
        stepping.periods(active, self._state, self._model)

    def _lost_text(self, i: int) -> str:
        """Why vehicle ``i`` was lost in the step just taken."""
        t = float(self._state[4][i] * self._model[1]) * self._model[5][i]
        if self._state[5][i] == 1:
            return self._why.get(i) or f'state became non-finite at t={t:.9g} s'
        return (f'state beyond physical bounds at t={t:.9g} s: [z, w, theta, q] = '
                f'{self.X[i].tolist()} (|w| <= V = {self._speed[i]:g} m/s, |theta| <= pi/2 '
                'rad)')

    def vehicle_parameters(self, i: int) -> dict[str, Any]:
        """Vehicle ``i``'s model parameters in its current episode (after the draw)."""
        return self._params[i].to_dict()


def warm_up() -> None:
    """Compile (or load from numba's cache) the compiled step (:mod:`.stepping`, and the
    plant kernels it calls from compiled code): one vehicle reset and stepped once; the
    arrays have the same types for every model, so one step compiles every kind's path
    (``make test`` calls it once, before the test workers start)."""
    env = HSSVVectorEnv(1)
    env.reset(seed=0)
    env.step(np.zeros((1, *env.single_action_space.shape), dtype=np.float32))
    env.close()
