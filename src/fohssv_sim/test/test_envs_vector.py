"""The vectorised HSSV-v0 against N single envs; Gymnasium's autoreset; recording to bags."""

import gymnasium as gym
import numpy as np
import pytest

from fohssv_sim.bag import load_run
from fohssv_sim.envs import ENV_ID, HSSVEnv, HSSVVectorEnv, RecordEpisodes, RecordVectorEpisodes
from fohssv_sim.params import ParameterError

VEHICLES = [{'speed': 70.0}, {'speed': 75.0, 'fractional_order': 0.9}, {'speed': 82.0}]


def _singles_with_autoreset(kwargs, vehicles, seed, actions):
    """What the vectorised env must give: each single env i seeded seed + i, reset by hand
    the step after its episode ended (Gymnasium's next-step rule, the action ignored)."""
    n = len(vehicles)
    envs = [HSSVEnv(**kwargs, **v) for v in vehicles]
    obs = np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(envs)])
    rows, rewards, ended = [obs], [], np.zeros(n, bool)
    flags = []
    for a in actions:
        o, r, te, tr = np.empty_like(obs), np.zeros(n), np.zeros(n, bool), np.zeros(n, bool)
        for i, e in enumerate(envs):
            if ended[i]:
                o[i] = e.reset()[0]
            else:
                o[i], r[i], te[i], tr[i], _ = e.step(a[i])
        ended = te | tr
        rows.append(o)
        rewards.append(r)
        flags.append((te.copy(), tr.copy()))
    return np.array(rows), np.array(rewards), flags


@pytest.mark.parametrize('model, extra', [
    ('fractional', {}), ('delay-free', {}), ('delayed', {}),
    ('delay-free', {'speed_range': (65.0, 85.0)}),     # V drawn at each reset
    ('delayed', {'speed_range': (65.0, 85.0)}),        # and with it the delay L/V
    ('fractional', {'speed_range': (65.0, 85.0), 'order_range': (0.7, 0.95)}),
    ('fractional', {'solver': 'abm'}),                 # each vehicle's plant in turn
])
def test_vector_env_equals_single_envs_through_autoresets(model, extra):
    kwargs = {'model': model, 'episode_steps': 7, 'observe_planing_force': True, **extra}
    vehicles = [dict(v) for v in VEHICLES]
    for v in vehicles:
        if model != 'fractional':
            v.pop('fractional_order', None)
        if 'speed_range' in extra:
            v.pop('speed')
        if 'order_range' in extra:
            v.pop('fractional_order', None)
    actions = np.random.default_rng(3).uniform(-0.1, 0.1, (20, 3, 1))
    ref, ref_r, ref_flags = _singles_with_autoreset(kwargs, vehicles, 11, actions)
    venv = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode='vector_entry_point',
                        vehicles=vehicles, **kwargs)
    assert isinstance(venv.unwrapped, HSSVVectorEnv)
    obs, _ = venv.reset(seed=11)
    rows, rewards = [obs], []
    for k, a in enumerate(actions):
        obs, r, te, tr, info = venv.step(a)
        rows.append(obs)
        rewards.append(r)
        assert np.array_equal(te, ref_flags[k][0]) and np.array_equal(tr, ref_flags[k][1])
    rows = np.array(rows)
    assert np.abs(rows - ref).max() <= 1e-12
    assert np.abs(np.array(rewards) - ref_r).max() <= 1e-9
    assert np.abs(rows[:, :, 0]).max() > 1e-3        # a trajectory, not a rest state
    assert sum(tr.sum() for _, tr in ref_flags) == 6     # two truncations per vehicle


def test_vector_env_loses_one_vehicle_and_keeps_the_others():
    venv = HSSVVectorEnv(2, vehicles=[{'initial_state': [0, 80.0, 0, 0]}, {}],
                         initial_spread=(0, 0, 0, 0))
    venv.reset(seed=0)
    obs, r, te, tr, info = venv.step(np.zeros((2, 1)))
    assert te.tolist() == [True, False] and 'physical bounds' in info['lost'][0]
    assert r[0] < -100.0 and info['_lost'].tolist() == [True, False]
    x1 = venv.X[1].copy()
    with pytest.raises(ValueError, match='delta_c=0.7 rad is outside the actuator range'):
        venv.step(np.array([[0.0], [0.7]]))              # refused: nothing changes
    assert np.array_equal(venv.X[1], x1) and venv._ended.tolist() == [True, False]
    obs, r, te, tr, info = venv.step(np.zeros((2, 1)))     # vehicle 0 autoresets
    assert obs[0].tolist() == [0.0, 80.0, 0.0, 0.0] and r[0] == 0.0 and not te.any()
    assert info['t'].tolist() == [0.0, 2e-4]


@pytest.mark.parametrize('kwargs, words', [
    ({'num_envs': 0}, 'num_envs=0 is not valid'),
    ({'num_envs': 2, 'vehicles': [{}]}, 'vehicles has 1 entries'),
    ({'num_envs': 2, 'vehicles': [{'step': 2e-5}, {'step': 1e-5}]},
     'must share control_period / step'),
    ({'num_envs': 2, 'vehicles': [{'step': 2e-5}, {'step': 1e-5, 'control_period': 5e-5}]},
     'must share step'),
    ({'num_envs': 2, 'vehicles': [{'fin': True}, {}]}, 'vehicles must share fin'),
])
def test_vector_env_bad_arguments(kwargs, words):
    with pytest.raises(ParameterError, match=words):
        HSSVVectorEnv(**kwargs)


def test_recorded_episode_loads_with_load_run_and_equals_the_observations(tmp_path):
    env = RecordEpisodes(HSSVEnv(episode_steps=40, fin=True), tmp_path / 'runs', 'random')
    rng = np.random.default_rng(0)
    episodes = []
    for seed in (1, 2):
        obs, info = env.reset(seed=seed)
        seen, fps, acts = [obs], [info['planing_force']], []
        done = False
        while not done:
            a = rng.uniform(-0.05, 0.05, 2)
            obs, _, te, tr, info = env.step(a)
            seen.append(obs)
            fps.append(info['planing_force'])
            acts.append(a)
            done = te or tr
        episodes.append((np.array(seen), np.array(fps), np.array(acts)))
    env.close()
    assert [p.name for p in env.paths] == ['episode_000000', 'episode_000001']
    for path, (seen, fps, acts) in zip(env.paths, episodes):
        run = load_run(path)
        assert not run.truncated
        assert np.array_equal(run.state, seen[:, :4])
        assert np.array_equal(run.t, (np.arange(41) * 5) * 2e-5)     # t = n h, 5 steps a period
        assert np.array_equal(run.planing_force, fps)
        assert np.array_equal(np.column_stack([run.delta_f, run.delta_c]), acts)
        assert run.parameters['model'] == 'fractional' and run.parameters['speed'] == 75.0
        assert run.metadata['fohssv.controller'] == 'random'


def test_vector_recording_writes_each_vehicles_episodes_through_autoresets(tmp_path):
    """Vehicle 0 is lost at each episode's first step, vehicle 1 truncated at 6: each episode
    of each vehicle is its own bag, its states the observations of that episode bit for bit
    (autoreset steps start a new bag with their first observation)."""
    venv = RecordVectorEpisodes(
        HSSVVectorEnv(2, vehicles=[{'initial_state': [0, 80.0, 0, 0], 'initial_spread':
                                    (0, 0, 0, 0)}, {'speed': 70.0}], episode_steps=6, fin=True),
        tmp_path / 'runs', 'random')
    rng = np.random.default_rng(4)
    obs, info = venv.reset(seed=3)
    episodes = [[[(obs[i], info['planing_force'][i], None)]] for i in range(2)]
    ended = np.zeros(2, bool)
    for _ in range(14):
        a = rng.uniform(-0.05, 0.05, (2, 2))
        obs, _, te, tr, info = venv.step(a)
        for i in range(2):
            if ended[i]:
                episodes[i].append([(obs[i], info['planing_force'][i], None)])
            else:
                episodes[i][-1].append((obs[i], info['planing_force'][i], a[i]))
        ended = te | tr
    venv.close()
    names = sorted(p.relative_to(tmp_path / 'runs').as_posix() for p in venv.paths)
    assert names == [f'vehicle_000/episode_{k:06d}' for k in range(8)] + \
        [f'vehicle_001/episode_{k:06d}' for k in range(3)]
    for i in range(2):
        paths = sorted(p for p in venv.paths if p.parent.name == f'vehicle_{i:03d}')
        for path, ep in zip(paths, episodes[i], strict=True):
            run = load_run(path)
            assert np.array_equal(run.state, np.array([o[:4] for o, _, _ in ep]))
            assert np.array_equal(run.planing_force, np.array([f for _, f, _ in ep]))
            acts = np.array([a for _, _, a in ep[1:]]).reshape(-1, 2)
            assert np.array_equal(np.column_stack([run.delta_f, run.delta_c]), acts)
            assert np.array_equal(run.t, np.arange(len(ep)) * 5 * 2e-5)
            assert run.parameters['speed'] == (75.0, 70.0)[i]
            assert run.metadata['fohssv.controller'] == 'random'
    # vehicle 1: two full episodes of 7 samples, and the first sample of the third
    assert [len(load_run(p).t) for p in paths] == [7, 7, 1]
