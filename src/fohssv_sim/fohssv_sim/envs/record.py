"""Record an environment's episodes to bags in the project's format.

:class:`RecordEpisodes` wraps any single fohssv environment (in-process or ROS-backed) and
writes each episode to ``directory/episode_<k>`` (k = 0, 1, ...); :class:`RecordVectorEpisodes`
wraps the vectorised one and writes vehicle i's episodes to
``directory/vehicle_<i>/episode_<k>``, following Gymnasium's next-step autoreset. Each bag
holds what the recorder records of the lockstep plant: ``state`` ``[t, z, w, theta, q]``,
``planing_force`` ``[t, Fp]`` and ``/clock`` at every sample (the reset's and each step's),
the ``command`` ``[t, delta_f, delta_c]`` applied from each sample but the last, log time =
round(t * 1e9) ns, and the episode's model parameters as ``fohssv.plant_parameters``.
``load_run`` and ``fohssv plot`` read them; the states are the observations' first four
columns, bit for bit.

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

__all__ = ['RecordEpisodes', 'RecordVectorEpisodes']


class _EpisodeBag:
    """One episode's bag: its samples and the commands between them."""

    def __init__(self, path: Path, metadata: dict[str, Any]) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.writer = w = RunWriter(path).open()
        for topic in contract.TOPICS:
            w.add_topic(topic.name if topic.name.startswith('/') else '/' + topic.name,
                        topic.type)
        w.add_metadata(metadata)
        self.t = 0.0

    def sample(self, obs: np.ndarray, t: float, planing_force: float) -> None:
        self.t = t = float(t)
        ns = round(t * 1e9)
        w = self.writer
        w.write('/clock', ns, clock(ns))
        w.write('/state', ns, float64_array(contract.STATE, [t, *np.asarray(obs)[:4]]))
        w.write('/planing_force', ns, float64_array(contract.PLANING_FORCE,
                                                    [t, planing_force]))

    def command(self, delta_f: float, delta_c: float) -> None:
        """The command applied from the last sample."""
        self.writer.write('/command', round(self.t * 1e9),
                          float64_array(contract.COMMAND, [self.t, delta_f, delta_c]))

    def close(self) -> None:
        self.writer.close()


def _metadata(env: Any, parameters: dict[str, Any], controller: str) -> dict[str, Any]:
    spec = getattr(env, 'spec', None)
    return {'fohssv.plant_parameters': parameters, 'fohssv.controller': controller,
            'fohssv.environment': spec.id if spec else type(env.unwrapped).__name__}


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
        self._bag: _EpisodeBag | None = None

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        self._finish()
        obs, info = self.env.reset(**kwargs)
        path = self.directory / f'episode_{len(self.paths):06d}'
        params = getattr(self.env.unwrapped, 'episode_parameters', {})
        self._bag = _EpisodeBag(path, _metadata(self.env, params, self.controller))
        self.paths.append(path)
        self._bag.sample(obs, info['t'], info['planing_force'])
        return obs, info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        bag = self._bag
        if bag is not None:
            bag.command(info['delta_f'], info['delta_c'])
            bag.sample(obs, info['t'], info['planing_force'])
            if terminated or truncated:
                self._finish()
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        self._finish()
        super().close()

    def _finish(self) -> None:
        if self._bag is not None:
            self._bag.close()
            self._bag = None


class RecordVectorEpisodes(gym.vector.VectorWrapper):
    """Writes every episode of each vehicle of the vectorised ``env``
    (:class:`~fohssv_sim.envs.HSSVVectorEnv`) to a bag under ``directory/vehicle_<i>`` (see
    the module docstring); ``paths`` lists the bags written so far, in the order opened. A
    vehicle's bag is closed when its episode ends, at the next reset, or at :meth:`close`;
    the step that autoresets it opens the next one with its first observation.

    Raises:
        FileExistsError: an episode's bag directory exists already.
    """

    def __init__(self, env: gym.vector.VectorEnv, directory: str | Path,
                 controller: str = 'agent') -> None:
        super().__init__(env)
        self.directory = Path(directory)
        self.controller = controller
        self.paths: list[Path] = []
        self._bags: list[_EpisodeBag | None] = [None] * self.num_envs
        self._episodes = [0] * self.num_envs
        self._ended = np.zeros(self.num_envs, dtype=bool)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, infos = self.env.reset(**kwargs)
        for i in range(self.num_envs):
            self._open(i, obs, infos)
        self._ended[:] = False
        return obs, infos

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                          dict]:
        obs, rewards, terminated, truncated, infos = self.env.step(actions)
        for i in range(self.num_envs):
            bag = self._bags[i]
            if self._ended[i]:               # autoreset: the first sample of its next episode
                self._open(i, obs, infos)
            elif bag is not None:
                bag.command(infos['delta_f'][i], infos['delta_c'][i])
                bag.sample(obs[i], infos['t'][i], infos['planing_force'][i])
                if terminated[i] or truncated[i]:
                    self._finish(i)
        self._ended = np.logical_or(terminated, truncated)
        return obs, rewards, terminated, truncated, infos

    def close(self, **kwargs: Any) -> None:
        for i in range(self.num_envs):
            self._finish(i)
        super().close(**kwargs)

    def _open(self, i: int, obs: np.ndarray, infos: dict) -> None:
        self._finish(i)
        path = self.directory / f'vehicle_{i:03d}' / f'episode_{self._episodes[i]:06d}'
        params = self.env.unwrapped.vehicle_parameters(i)
        bag = self._bags[i] = _EpisodeBag(path, _metadata(self.env, params, self.controller))
        self._episodes[i] += 1
        self.paths.append(path)
        bag.sample(obs[i], infos['t'][i], infos['planing_force'][i])

    def _finish(self, i: int) -> None:
        if self._bags[i] is not None:
            self._bags[i].close()
            self._bags[i] = None
