"""Train a PPO agent on HSSV-v0 (Stable-Baselines3) and score it as the baselines are scored.

Not a dependency of fohssv: run it where stable-baselines3 is installed (docs/environments.md).
"""

import gymnasium as gym
from stable_baselines3 import PPO

import fohssv_sim.envs  # noqa: F401 - registers fohssv/HSSV-v0
from fohssv_sim.envs.baselines import baseline_table, evaluate

env = gym.make('fohssv/HSSV-v0', fin=True)          # the baselines' task
model = PPO('MlpPolicy', env, seed=0, verbose=0)
model.learn(total_timesteps=20_480)                  # ten rollouts of 2048 steps: a short run


def agent(obs):
    return model.predict(obs, deterministic=True)[0]


# the baselines' episodes (seeds 0-4); no deflection at all for scale
print(baseline_table([evaluate(agent, episodes=5, name='ppo (20,480 steps)'),
                      evaluate('zero', episodes=5)]))
