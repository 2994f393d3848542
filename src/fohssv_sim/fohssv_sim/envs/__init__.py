"""Gymnasium environments of the FO-HSSV (docs/environments.md).

Importing this package registers:

* ``fohssv/HSSV-v0``: one vehicle in-process (:class:`HSSVEnv`), with the vectorised
  :class:`HSSVVectorEnv` as its ``vector_entry_point``:
  ``gymnasium.make_vec('fohssv/HSSV-v0', num_envs=N, vectorization_mode='vector_entry_point')``;
* ``fohssv/HSSVRos-v0``: the agent as the controller of a real plant node over DDS
  (:class:`fohssv_sim.ros.env.HSSVRosEnv`; needs rclpy, imported only when made).

:class:`RecordEpisodes` (a single env) and :class:`RecordVectorEpisodes` (the vectorised one)
write their episodes to bags that ``load_run`` and ``fohssv plot`` read.

Pure: importing it imports no rclpy.
"""

from __future__ import annotations

import gymnasium as gym

from .record import RecordEpisodes, RecordVectorEpisodes
from .single import HSSVEnv
from .task import ENV_PARAMETERS, Task, default_reward, make_task
from .vector import HSSVVectorEnv

__all__ = ['HSSVEnv', 'HSSVVectorEnv', 'RecordEpisodes', 'RecordVectorEpisodes',
           'ENV_PARAMETERS', 'Task',
           'default_reward', 'make_task', 'ENV_ID', 'ROS_ENV_ID']

ENV_ID = 'fohssv/HSSV-v0'
ROS_ENV_ID = 'fohssv/HSSVRos-v0'

if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point='fohssv_sim.envs.single:HSSVEnv',
                 vector_entry_point='fohssv_sim.envs.vector:HSSVVectorEnv')
if ROS_ENV_ID not in gym.registry:
    gym.register(ROS_ENV_ID, entry_point='fohssv_sim.ros.env:HSSVRosEnv')
