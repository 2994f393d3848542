"""HSSVRos-v0 against HSSV-v0: a real plant process over real DDS, in lockstep."""

import gymnasium as gym
import numpy as np
import pytest

from fohssv_sim import control
from fohssv_sim.envs import ROS_ENV_ID, HSSVEnv
from fohssv_sim.params import ParameterError

import rosproc

pytestmark = pytest.mark.graph


@pytest.fixture
def ros_env():
    from fohssv_sim.ros.env import HSSVRosEnv

    made = []

    def make(**kwargs):
        env = HSSVRosEnv(domain_id=rosproc.unique_domain_id(), **kwargs)
        made.append(env)
        return env

    yield make
    for env in made:
        env.close()


def _episode(env, ref, seed, law, steps):
    """Step both envs with the law's actions on the ROS env's observations; the largest
    difference of observations and rewards, and the flags of the last step."""
    obs, info = env.reset(seed=seed)
    want, _ = ref.reset(seed=seed)
    worst = np.abs(obs - want).max()
    for _ in range(steps):
        a = law.command(info['t'], obs)
        obs, r, term, trunc, info = env.step(a)
        want, r_want, *_ = ref.step(a)
        worst = max(worst, np.abs(obs - want).max(), abs(r - r_want))
    return worst, term, trunc


def test_ros_env_equals_in_process_env_for_10000_steps(ros_env):
    kwargs = {'fin': True, 'episode_steps': 10_000, 'observe_planing_force': True}
    env = ros_env(namespace='vehicle', **kwargs)
    ref = HSSVEnv(**kwargs)
    law = control.make('state_feedback')
    worst, term, trunc = _episode(env, ref, 5, law, 10_000)
    assert worst == 0.0 and trunc and not term
    # the next episode starts through the plant's reset service, from another draw
    worst, term, trunc = _episode(env, ref, 6, law, 50)
    assert worst == 0.0 and not (term or trunc)
    assert env.process.poll() is None           # the same plant process


def test_ros_env_drives_a_plant_already_running(ros_env):
    kwargs = {'speed': 80.0, 'episode_steps': 200, 'control_period': 2e-4}
    env = ros_env(namespace='sub', start_plant=False, timeout=120.0, **kwargs)
    plant = rosproc.start('fohssv_sim', 'plant', env.plant_args(),
                          env=rosproc.ros_env(env.domain_id))
    try:
        ref = HSSVEnv(**kwargs)
        law = control.make('state_feedback')
        for seed in (3, 4):                 # each reset through the plant's service
            rng = np.random.default_rng(seed)
            obs, info = env.reset(seed=seed)
            want, _ = ref.reset(seed=seed)
            worst = np.abs(obs - want).max()
            for _ in range(200):
                a = [law.command(info['t'], obs)[1] + rng.uniform(-0.01, 0.01)]
                obs, r, term, trunc, info = env.step(a)
                want, r_want, *_ = ref.step(a)
                worst = max(worst, np.abs(obs - want).max(), abs(r - r_want))
            assert worst == 0.0 and trunc and not term
    finally:
        rosproc.stop(plant)


def test_ros_env_loses_the_vehicle_at_the_step_and_with_the_observation_of_the_in_process_env(
        ros_env):
    """A pitch beyond pi/2 at the 50th step: the plant ends there without publishing it; the
    ROS env's steps up to it and that step itself are HSSV-v0's, then a reset restarts it."""
    kwargs = {'initial_state': [0.0, 0.0, 1.5, 5.0], 'initial_spread': (0, 0, 0, 0),
              'observe_planing_force': True}
    env, ref = ros_env(**kwargs), HSSVEnv(**kwargs)
    for seed in (0, 1):                       # the second through a plant started anew
        obs, _ = env.reset(seed=seed)
        want, _ = ref.reset(seed=seed)
        assert np.array_equal(obs, want)
        steps, term = 0, False
        while not term and steps < 100:
            obs, r, term, trunc, info = env.step([0.3])
            want, r_want, term_want, trunc_want, info_want = ref.step([0.3])
            assert np.array_equal(obs, want) and r == r_want and info['t'] == info_want['t']
            assert (term, trunc) == (term_want, trunc_want)
            steps += 1
        assert term and steps == 50 and abs(obs[2]) > np.pi / 2 and r < -100.0
        assert info['lost'].startswith(info_want['lost'])
        assert 'the plant exited with code 1' in info['lost']
        with pytest.raises(RuntimeError, match='call reset'):
            env.step([0.0])


def test_ros_env_refuses_domain_randomisation():
    with pytest.raises(ParameterError, match='speed_range=.* is not supported by HSSVRos-v0'):
        gym.make(ROS_ENV_ID, speed_range=(70.0, 80.0))     # registered, made through Gymnasium


def test_an_env_never_closed_still_stops_its_plant():
    """A notebook or a failing script may never call close(): the plant the env started (its
    own session, so a terminal's Ctrl-C does not reach it) ends when the env is collected."""
    import gc

    from fohssv_sim.ros.env import HSSVRosEnv

    env = HSSVRosEnv(domain_id=rosproc.unique_domain_id(), episode_steps=10)
    env.reset(seed=1)
    proc = env.process
    assert proc.poll() is None
    del env
    gc.collect()
    assert proc.wait(timeout=20) is not None
