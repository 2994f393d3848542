"""The project's controllers as policies of ``HSSV-v0``, and the generated parts of
docs/environments.md.

:func:`evaluate` runs a controller plugin (:func:`fohssv_sim.control.make`; a law with memory
is reset at each episode, a scheduled law follows the episode's V) on the default reward and
task: its clamped ``command(t, state)`` as the action ``[delta_f, delta_c]`` of an env with
``fin=True``. ``python -m fohssv_sim.envs.baselines`` prints the baselines table and the
keyword table of docs/environments.md (a test checks the page holds the keyword table).

Pure: no rclpy.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import control
from ..docs import markdown_table
from .single import HSSVEnv
from .task import ENV_PARAMETERS

__all__ = ['Score', 'evaluate', 'baseline_table', 'keyword_table', 'POLICIES']

#: The built-in laws evaluated in the docs, and 'zero' (no deflection) for scale.
POLICIES = ('state_feedback', 'lqr', 'fractional_pid', 'scheduled', 'zero')


@dataclass(frozen=True)
class Score:
    """Mean and spread of the episode returns, lost episodes, mean |z - z_ref| (m)."""

    policy: str
    episodes: int
    mean_return: float
    std_return: float
    lost: int
    mean_depth_error: float


def evaluate(policy: str | Callable[[np.ndarray], Any], episodes: int = 5, seed: int = 0,
             name: str | None = None, **kwargs: Any) -> Score:
    """Run ``policy`` (a controller plugin name, 'zero', or a function of the observation
    returning the action, e.g. a trained agent's, scored as ``name``) for ``episodes``
    episodes of ``HSSV-v0(fin=True, **kwargs)`` seeded ``seed, seed + 1, ...``.

    Raises:
        fohssv_sim.control.UnknownController: no such plugin.
        ParameterError: a bad keyword argument.
    """
    env = HSSVEnv(fin=True, **kwargs)
    returns, errors, lost = [], [], 0
    for k in range(episodes):
        obs, info = env.reset(seed=seed + k)
        law = None
        if isinstance(policy, str) and policy != 'zero':
            cls = control.load(policy)
            law = cls(**{k: env.plant.params.to_dict()[model_name]
                         for k, model_name in cls.scheduling.items()})
        total, err, done = 0.0, [], False
        while not done:
            if callable(policy):
                a = policy(obs)
            else:
                a = (0.0, 0.0) if law is None else law.command(info['t'], obs[:4])
            obs, r, term, trunc, info = env.step(a)
            total += r
            err.append(abs(obs[0] - env.task.target_depth))
            done = term or trunc
        lost += bool(term)
        returns.append(total)
        errors.append(float(np.mean(err)))
    return Score(name or str(policy), episodes, float(np.mean(returns)),
                 float(np.std(returns)), lost, float(np.mean(errors)))


def baseline_table(scores: list[Score]) -> str:
    """The baselines as Markdown."""
    return markdown_table(
        ('policy', 'episodes', 'mean return', 'std', 'lost', 'mean abs(z - z_ref) (m)'),
        ((f'`{s.policy}`', str(s.episodes), f'{s.mean_return:.4g}', f'{s.std_return:.3g}',
          str(s.lost), f'{s.mean_depth_error:.3g}') for s in scores))


def keyword_table() -> str:
    """The environments' own keyword arguments (:data:`ENV_PARAMETERS`) as Markdown."""
    def default(v: Any) -> str:
        return f'{v:g}' if isinstance(v, float) else str(v)

    return markdown_table(
        ('keyword', 'default', 'unit', 'allowed', 'meaning'),
        ((f'`{s.name}`', f'`{default(s.default)}`', s.unit, s.range_text().replace('|', '/'),
          s.description) for s in ENV_PARAMETERS))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description='Print the baselines table and the keyword '
                                 'table of docs/environments.md.')
    ap.add_argument('--episodes', type=int, default=5)
    args = ap.parse_args(argv)
    scores = []
    for name in POLICIES:
        print(f'evaluating {name} ...', file=sys.stderr, flush=True)
        scores.append(evaluate(name, args.episodes))
    print(baseline_table(scores))
    print()
    print(keyword_table())
    return 0


if __name__ == '__main__':
    sys.exit(main())
