"""``HSSV-v0``: one vehicle in-process, one control period per step.

Each :meth:`HSSVEnv.step` holds the action's deflections over one ``control_period`` and
advances the plant the parameters name (:func:`fohssv_sim.models.make_plant`) by its
``control_period / step`` integration steps in one compiled call (``Plant.advance``), exactly
as the lockstep plant node and ``simulate(..., control_period=...)`` do.

Pure: numpy, Gymnasium and the core; no rclpy.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from ..models import Plant, make_plant
from .task import Task, make_task

__all__ = ['HSSVEnv', 'EpisodeEnv', 'spaces_of']


def spaces_of(task: Task) -> tuple[gym.spaces.Box, gym.spaces.Box]:
    """(observation space, action space): the observation unbounded (float64), the action
    the deflections within their limits [delta_c] or [delta_f, delta_c] (rad, float64)."""
    n = task.observation_size
    obs = gym.spaces.Box(-np.inf, np.inf, (n,), dtype=np.float64)
    lim = task.limits if task.fin else task.limits[1:]
    act = gym.spaces.Box(-lim, lim, dtype=np.float64)
    return obs, act


class EpisodeEnv(gym.Env):
    """What ``HSSV-v0`` and ``HSSVRos-v0`` share: an episode's bookkeeping (its step count,
    the action before, the end flags), the reward and ``info`` by the ``task``'s rules. A
    subclass sets ``task`` and runs each control period between :meth:`_begin_step` and
    :meth:`_end_step`."""

    metadata = {'render_modes': []}
    task: Task
    _done = True

    def _begin_episode(self, x: Any, fp: float, t: float) -> tuple[np.ndarray, dict]:
        self._done = False
        self._steps = 0
        self._u = np.zeros(2)
        return self.task.observe(x, fp), self._info(t, fp, '')

    def _begin_step(self, action: Any) -> tuple[float, float]:
        """The action's (delta_f, delta_c), checked, in an episode that has not ended."""
        if self._done:
            raise RuntimeError('the episode has ended (or never started): call reset() before '
                               'step()')
        return self.task.action(action)

    def _end_step(self, u: tuple[float, float], x: Any, fp: float, t: float, why: str
                  ) -> tuple[np.ndarray, float, bool, bool, dict]:
        """The step's result after input ``u`` led to state ``x`` and Fp ``fp`` at time
        ``t``; ``why`` the vehicle was lost ('' when it was not)."""
        task = self.task
        ua = np.array(u)
        reward = task.score(np.array(x), ua, self._u, fp, bool(why))
        self._u = ua
        self._steps += 1
        truncated = self._steps >= task.episode_steps and not why
        self._done = bool(why) or truncated
        return task.observe(x, fp), reward, bool(why), truncated, self._info(t, fp, why)

    def _info(self, t: float, fp: float, why: str) -> dict[str, Any]:
        info = {'t': t, 'planing_force': fp, 'delta_f': float(self._u[0]),
                'delta_c': float(self._u[1])}
        if why:
            info['lost'] = why
        return info


class HSSVEnv(EpisodeEnv):
    """The supercavitating vehicle's dive plane as a Gymnasium environment.

    Keyword arguments: see :mod:`fohssv_sim.envs.task` (model parameters, ``control_period``,
    ``initial_state``, deflection limits, episode and reward options). ``info`` holds ``t``
    (s), ``planing_force`` (m^2/s^2), the applied ``delta_f`` and ``delta_c`` (rad) and, when
    the vehicle was lost, ``lost`` (why).

    ``reset(seed=..., options={'initial_state': [...]})``: options may fix the start state
    (no draw); see :meth:`fohssv_sim.envs.task.Task.draw` for the randomisation.

    Raises (from ``step``): ValueError for a bad action, RuntimeError for a step before
    ``reset`` or after the episode ended.
    """

    def __init__(self, **kwargs: Any) -> None:
        self.task = make_task(kwargs)
        self.observation_space, self.action_space = spaces_of(self.task)
        self.plant: Plant | None = None
        #: The model parameters of the current episode (after the draw), as a dict.
        self.episode_parameters: dict[str, Any] = {}

    def reset(self, *, seed: int | None = None, options: dict | None = None
              ) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        params, x0 = self.task.draw(self.np_random, (options or {}).get('initial_state'))
        plant = self.plant
        if plant is not None and plant.params == params:
            plant.reset(x0)
        else:
            plant = self.plant = make_plant(params, x0, duration=self.task.duration)
        self.episode_parameters = params.to_dict()
        return self._begin_episode(plant.x, plant.planing_force, plant.t)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        u = self._begin_step(action)
        plant = self.plant
        why = ''
        try:
            plant.advance(u, self.task.hold)
        except FloatingPointError as exc:
            why = str(exc)
        x = plant.x
        if not why and not self.task.in_bounds(x, plant.params.speed):
            why = (f'state beyond physical bounds at t={plant.t:.9g} s: [z, w, theta, q] = '
                   f'{list(x)} (|w| <= V = {plant.params.speed:g} m/s, |theta| <= pi/2 rad)')
        return self._end_step(u, x, plant.planing_force, plant.t, why)
