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

__all__ = ['HSSVEnv', 'spaces_of']


def spaces_of(task: Task) -> tuple[gym.spaces.Box, gym.spaces.Box]:
    """(observation space, action space): the observation unbounded (float64), the action
    the deflections within their limits [delta_c] or [delta_f, delta_c] (rad, float64)."""
    n = task.observation_size
    obs = gym.spaces.Box(-np.inf, np.inf, (n,), dtype=np.float64)
    lim = task.limits if task.fin else task.limits[1:]
    act = gym.spaces.Box(-lim, lim, dtype=np.float64)
    return obs, act


class HSSVEnv(gym.Env):
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

    metadata = {'render_modes': []}

    def __init__(self, **kwargs: Any) -> None:
        self.task = make_task(kwargs)
        self.observation_space, self.action_space = spaces_of(self.task)
        self.plant: Plant | None = None
        #: The model parameters of the current episode (after the draw), as a dict.
        self.episode_parameters: dict[str, Any] = {}
        self._done = True
        self._u = np.zeros(2)

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
        self._done = False
        self._steps = 0
        self._u = np.zeros(2)
        fp = plant.planing_force
        return self.task.observe(plant.x, fp), self._info(fp, '')

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._done:
            raise RuntimeError('the episode has ended (or never started): call reset() before '
                               'step()')
        task = self.task
        u = task.action(action)
        plant = self.plant
        why = ''
        try:
            plant.advance(u, task.hold)
        except FloatingPointError as exc:
            why = str(exc)
        x = plant.x
        if not why and not task.in_bounds(x, plant.params.speed):
            why = (f'state beyond physical bounds at t={plant.t:.9g} s: [z, w, theta, q] = '
                   f'{list(x)} (|w| <= V = {plant.params.speed:g} m/s, |theta| <= pi/2 rad)')
        fp = plant.planing_force
        ua = np.array(u)
        reward = task.score(np.array(x), ua, self._u, fp, bool(why))
        self._u = ua
        self._steps += 1
        truncated = self._steps >= task.episode_steps
        self._done = bool(why) or truncated
        return task.observe(x, fp), reward, bool(why), truncated and not why, self._info(fp, why)

    def _info(self, fp: float, why: str) -> dict[str, Any]:
        info = {'t': self.plant.t, 'planing_force': fp, 'delta_f': float(self._u[0]),
                'delta_c': float(self._u[1])}
        if why:
            info['lost'] = why
        return info
