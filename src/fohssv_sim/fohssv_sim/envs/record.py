"""Record an environment's episodes to bags in the project's format.

:class:`RecordEpisodes` wraps any fohssv environment (in-process or ROS-backed) and writes
each episode to ``directory/episode_<k>`` (k = 0, 1, ...) as the recorder records the
lockstep plant: ``state`` ``[t, z, w, theta, q]``, ``planing_force`` ``[t, Fp]`` and
``/clock`` at every sample (the reset's and each step's), the ``command`` ``[t, delta_f,
delta_c]`` applied from each sample but the last, log time = round(t * 1e9) ns, and the
episode's model parameters as ``fohssv.plant_parameters``. ``load_run`` and ``fohssv plot``
read them; the states are the observations' first four columns, bit for bit.

Pure: numpy, Gymnasium and the bag writer; no rclpy.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from .. import contract
from ..bag.synthetic import clock, float64_array
from ..bag.writer import RunWriter

__all__ = ['RecordEpisodes']


class RecordEpisodes(gym.Wrapper):
    """Writes every episode of ``env`` to a bag under ``directory`` (see the module
    docstring), naming the policy ``controller`` in the run metadata (``fohssv plot`` shows
    it); ``paths`` lists the bags written so far. An episode's bag is closed when it
    ends (terminated or truncated), at the next reset, or at :meth:`close`.

    Raises:
        FileExistsError: an episode's bag directory exists already.
    """

    def __init__(self, env: gym.Env, directory: str | Path, controller: str = 'agent') -> None:
        super().__init__(env)
        self.directory = Path(directory)
        self.controller = controller
        self.paths: list[Path] = []
        self._writer: RunWriter | None = None

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        self._finish()
        obs, info = self.env.reset(**kwargs)
        path = self.directory / f'episode_{len(self.paths):06d}'
        self.directory.mkdir(parents=True, exist_ok=True)
        w = self._writer = RunWriter(path).open()
        self.paths.append(path)
        for topic in contract.TOPICS:
            w.add_topic(topic.name if topic.name.startswith('/') else '/' + topic.name,
                        topic.type)
        params = getattr(self.env.unwrapped, 'episode_parameters', {})
        w.add_metadata({'fohssv.plant_parameters': params, 'fohssv.controller': self.controller,
                        'fohssv.environment': self.env.spec.id if self.env.spec else
                        type(self.env.unwrapped).__name__})
        self._sample(obs, info)
        return obs, info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        t0 = self._t
        obs, reward, terminated, truncated, info = self.env.step(action)
        w = self._writer
        if w is not None:
            ns = round(t0 * 1e9)
            w.write('/command', ns, float64_array(contract.COMMAND,
                                                  [t0, info['delta_f'], info['delta_c']]))
            self._sample(obs, info)
            if terminated or truncated:
                self._finish()
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        self._finish()
        super().close()

    def _sample(self, obs: np.ndarray, info: dict) -> None:
        t = self._t = float(info['t'])
        ns = round(t * 1e9)
        w = self._writer
        w.write('/clock', ns, clock(ns))
        w.write('/state', ns, float64_array(contract.STATE, [t, *np.asarray(obs)[:4]]))
        w.write('/planing_force', ns, float64_array(contract.PLANING_FORCE,
                                                    [t, info['planing_force']]))

    def _finish(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None
