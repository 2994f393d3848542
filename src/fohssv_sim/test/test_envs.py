"""HSSV-v0: Gymnasium's checker, determinism, the second method (simulate), reward, errors."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from fohssv_sim import control
from fohssv_sim.envs import ENV_ID, HSSVEnv
from fohssv_sim.params import ModelParameters, ParameterError
from fohssv_sim.simulate import simulate

SHORT = {'episode_steps': 20}


@pytest.mark.parametrize('model', ['fractional', 'delay-free', 'delayed'])
@pytest.mark.parametrize('options', [{}, {'fin': True, 'observe_planing_force': True,
                                          'observe_depth_error': True}])
def test_check_env_passes(model, options):
    env = gym.make(ENV_ID, model=model, **SHORT, **options).unwrapped
    check_env(env, skip_render_check=True)
    n = 4 + options.get('observe_planing_force', 0) + options.get('observe_depth_error', 0)
    assert env.observation_space.shape == (n,)
    assert env.action_space.shape == ((2,) if options else (1,))
    assert np.all(env.action_space.high == 0.5)     # the controllers' deflection limit


def _rollout(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, *_ = env.step(a)
        out.append(obs)
    return np.array(out)


def test_same_seed_and_actions_give_identical_observations():
    actions = np.random.default_rng(1).uniform(-0.05, 0.05, (30, 1))
    a = _rollout(HSSVEnv(), 7, actions)
    b = _rollout(HSSVEnv(), 7, actions)
    c = _rollout(HSSVEnv(), 8, actions)
    assert np.array_equal(a, b)
    assert not np.array_equal(a[0], c[0])       # another seed draws another start


def test_reset_draws_start_within_spread_and_ranges():
    env = HSSVEnv(speed_range=(60.0, 90.0), order_range=(0.8, 0.9),
                  initial_spread=(0.1, 0.0, 0.0, 0.0))
    for seed in range(5):
        obs, _ = env.reset(seed=seed)
        p = env.plant.params
        assert 60.0 <= p.speed <= 90.0 and 0.8 <= p.fractional_order <= 0.9
        assert abs(obs[0]) <= 0.1 and obs[1:].tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize('model', ['fractional', 'delay-free'])
def test_eq31_through_the_env_equals_simulate(model):
    """The second method: the batch runner with the same law, period and start."""
    x0 = [0.01, 0.2, -0.002, 0.05]
    period = 2e-4
    env = HSSVEnv(model=model, fin=True, control_period=period, initial_state=x0,
                  initial_spread=(0, 0, 0, 0), episode_steps=500)
    law = control.make('state_feedback')
    obs, info = env.reset(seed=0)
    states = [obs]
    for _ in range(500):
        obs, _, term, trunc, info = env.step(law.command(info['t'], obs))
        states.append(obs)
    assert trunc and not term
    params = ModelParameters(model=model)
    ref = simulate(params, control.make('state_feedback'), 500 * period, control_period=period,
                   initial_state=x0, sample_every=round(period / params.step))
    assert np.abs(np.array(states) - ref.state).max() <= 1e-12
    assert abs(np.array(states)[:, 0]).max() > 1e-3         # a trajectory, not a rest state


def test_default_reward_equals_hand_computation():
    env = HSSVEnv(fin=True, observe_planing_force=True, target_depth=0.002, depth_scale=0.02,
                  planing_weight=3e-3, rate_weight=0.5, max_fin_deflection=0.4,
                  initial_spread=(0, 0, 0, 0))
    env.reset(seed=0)
    prev = (0.0, 0.0)
    for a in [(0.1, -0.2), (0.3, 0.1), (-0.4, 0.05)]:
        obs, r, *_ = env.step(np.array(a))
        z, fp = obs[0], obs[4]
        hand = -(((z - 0.002) / 0.02) ** 2) - 3e-3 * fp ** 2 \
            - 0.5 * (((a[0] - prev[0]) / 0.4) ** 2 + ((a[1] - prev[1]) / 0.5) ** 2)
        assert r == pytest.approx(hand, rel=1e-14, abs=1e-300)
        prev = a


def test_user_reward_function_is_called_with_the_step():
    seen = []

    def reward(state, action, previous, fp, target):
        seen.append((state.copy(), action.copy(), previous.copy(), fp, target))
        return 1.5

    env = HSSVEnv(reward=reward, target_depth=0.3)
    obs0, _ = env.reset(seed=1)
    obs, r, *_ = env.step([0.1])
    assert r == 1.5
    state, action, previous, fp, target = seen[0]
    assert np.array_equal(state, obs) and action.tolist() == [0.0, 0.1]
    assert previous.tolist() == [0.0, 0.0] and target == 0.3


def test_truncation_at_episode_length_and_termination_when_lost():
    env = HSSVEnv(episode_steps=3)
    env.reset(seed=0)
    flags = [env.step([0.0])[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]
    # w beyond V: the plant's bounds lose the vehicle at the first step, with the penalty
    env = HSSVEnv(initial_state=[0, 80.0, 0, 0], initial_spread=(0, 0, 0, 0), speed=75.0)
    env.reset(seed=0)
    obs, r, term, trunc, info = env.step([0.0])
    assert term and not trunc and 'physical bounds' in info['lost'] and r < -100.0
    with pytest.raises(RuntimeError, match='call reset'):
        env.step([0.0])


@pytest.mark.parametrize('action, words', [
    ([math.nan], 'delta_c=nan rad is not finite; allowed: [-0.5, 0.5] rad'),
    ([0.6], 'delta_c=0.6 rad is outside the actuator range; allowed: [-0.5, 0.5] rad'),
    ([0.1, 0.2], 'must hold 1 number'),
])
def test_bad_actions_are_refused_naming_value_and_range(action, words):
    env = HSSVEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError) as err:
        env.step(action)
    assert words in str(err.value)
    env.step([0.0])               # the env is still usable


@pytest.mark.parametrize('kwargs, words', [
    ({'speed': -3}, 'speed=-3 is outside the allowed range (0, inf) m/s'),
    ({'sped': 70}, 'unknown keyword argument(s) sped; valid names: model'),
    ({'control_period': 3e-5}, 'whole multiple of the integration step'),
    ({'episode_steps': 0}, 'episode_steps=0 is outside the allowed range [1, 1e+09] periods'),
    ({'max_cavitator_deflection': 2.0}, 'max_cavitator_deflection=2.0 is outside'),
    ({'speed_range': (90, 60)}, 'speed_range=(90, 60) is not an increasing pair of numbers; '
     'allowed: none or (low, high), low <= high, each in (0, inf) m/s'),
    ({'order_range': (0.5, 1.2)}, 'fractional_order=1.2 is outside the allowed range (0, 1]'),
    ({'model': 'delay-free', 'order_range': (0.5, 0.6)}, "needs model='fractional'"),
    ({'initial_spread': (1, 1, -1, 1)}, 'has a negative half-width'),
    ({'fin': 'yes'}, 'is not true or false'),
    ({'reward': 3}, 'reward=3 is not callable'),
])
def test_bad_keyword_arguments_are_refused(kwargs, words):
    with pytest.raises(ParameterError) as err:
        gym.make(ENV_ID, **kwargs)
    assert words in str(err.value)


def test_step_before_reset_is_refused():
    with pytest.raises(RuntimeError, match='call reset'):
        HSSVEnv().step([0.0])


def test_environments_doc_holds_the_keyword_table():
    from pathlib import Path

    from fohssv_sim.envs.baselines import keyword_table

    doc = Path(__file__).resolve().parents[3] / 'docs' / 'environments.md'
    assert keyword_table() in doc.read_text()


def test_baseline_evaluation_scores_eq31_against_doing_nothing():
    from fohssv_sim.envs.baselines import evaluate

    law = evaluate('state_feedback', episodes=2, episode_steps=300)
    zero = evaluate('zero', episodes=2, episode_steps=300)
    assert law.episodes == 2 and law.lost == 0
    # eq. 31 holds the depth; with no deflection the vehicle drifts off it
    assert law.mean_return > zero.mean_return and law.mean_depth_error < zero.mean_depth_error
