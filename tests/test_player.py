"""The player as a real process over DDS (no mocks): commands replay, republish, bad bags.

* Open loop: a lockstep run (plant + state_feedback controller + recorder, all real
  processes) is recorded to bag A; a fresh lockstep plant fed by the player in ``commands``
  mode, recorded by a second recorder to bag B, reproduces A's state series exactly (checked
  to 1e-12 and bit for bit). A plant whose states the bag does not answer fails the player
  with the time named.
* Republish: at rate 0 every state reaches a keep-all subscriber in the test process, in
  order, byte-identical to the bag, with /clock at every log time; at rate 1 the states
  arrive spread over about the recorded simulated time (loose bound). A cut bag plays what is
  recoverable, with a warning.
* Missing, empty, truncated and non-bag paths: the player's reader names each; the player
  process says it in one ``player: error:`` line, exit 1, no traceback.
"""

from __future__ import annotations

import signal
import threading

import numpy as np
import pytest
import rclpy
from ament_index_python.packages import get_package_share_directory
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray
from test_graph_support import plant_args

from fohssv_sim.bag import BagError, load_run, scan
from fohssv_sim.bag.synthetic import write_bag

import rosproc

pytestmark = pytest.mark.graph

TOL = 1e-12
DURATION = 0.05            # simulated s per lockstep run (501 samples at 1e-4 s)
N = round(DURATION / 1e-4) + 1

def _player(env, *params: str, log=None):
    return rosproc.start('fohssv_sim', 'player', rosproc.param_args(*params), env=env, log=log)


def _plant(env, log, **params):
    yaml_file = f"{get_package_share_directory('fohssv_sim')}/config/plant.yaml"
    return rosproc.start('fohssv_sim', 'plant', ['--ros-args', '--params-file', yaml_file]
                         + plant_args(**params)[1:], env=env, log=log)


def _recorder(env, bag, log):
    # command_publishers:=1: the recorder subscribes to state (which the plant waits for) only
    # once its command subscription matched the command publisher; the feeder's
    # min_command_subscribers:=2 holds commands until its side of that match exists too
    return rosproc.start_recorder(env, log, f'bag_path:={bag}', 'plant_timeout:=20.0',
                                  'command_publishers:=1', ready=False)


def _recorded(bag) -> tuple[int, int]:
    try:
        run = load_run(bag)
    except BagError:
        return 0, 0
    return len(run.t), len(run.command_t)


def _close_recorder(proc, bag, n: int, log) -> None:
    # the commands too: under load the recorder takes them later than the states
    def complete() -> bool:
        states, commands = _recorded(bag)
        return states >= n and commands >= n - 1

    rosproc.wait_for(complete, 30, interval=0.1, what=f'{n} states and {n - 1} commands in {bag}')
    assert rosproc.stop(proc, signal.SIGINT) == 0, log.read_text()


def _lockstep_run(tmp_path, name: str, feeder) -> tuple[object, str]:
    """One lockstep run of the delay-free plant recorded to ``tmp_path/name``; ``feeder(env)``
    starts whatever answers the states. Returns the loaded run and the logs."""
    env = rosproc.ros_env()
    bag = tmp_path / name
    logs = {k: tmp_path / f'{name}-{k}.log' for k in ('plant', 'feeder', 'recorder')}
    rec = _recorder(env, bag, logs['recorder'])
    feed = feeder(env, logs['feeder'])
    plant = _plant(env, logs['plant'], model='delay-free', duration=DURATION,
                   min_state_subscribers=2, start_timeout=60.0, pace_to_subscribers=512)
    code = rosproc.wait_exit(plant, 90)
    assert code == 0, logs['plant'].read_text()
    # the bag first, then the feeder: a reader loses the samples it has not taken yet when
    # their writer goes away, so stopping the controller early cut the recorded commands
    _close_recorder(rec, bag, N, logs['recorder'])
    feed_code = rosproc.wait_exit(feed, 30) if name == 'B' else rosproc.stop(feed)
    text = '\n'.join(f'--- {k}\n{v.read_text()}' for k, v in logs.items())
    assert feed_code == 0, text
    return load_run(bag), text


def test_commands_replay_reproduces_the_lockstep_run(tmp_path):
    def controller(env, log):
        return rosproc.start('fohssv_controller', 'state_feedback',
                             rosproc.param_args('min_command_subscribers:=2'), env=env, log=log)

    # Bag A holds every answer: the controller sent none before the recorder matched it.
    a, text_a = _lockstep_run(tmp_path, 'A', controller)
    assert len(a.t) == N and not a.truncated, text_a
    assert np.array_equal(a.command_t[:N - 1], a.t[:N - 1]), text_a
    bag_a = a.path

    def player(env, log):
        return _player(env, f'bag_path:={bag_a}', 'mode:=commands',
                       'min_command_subscribers:=2', log=log)

    b, text_b = _lockstep_run(tmp_path, 'B', player)
    assert 'every recorded command was replayed' in text_b or 'commands end' in text_b, text_b
    assert 'the plant /plant matches the recording' in text_b, text_b
    assert b.state.shape == a.state.shape, text_b
    assert np.array_equal(b.t, a.t)
    assert np.max(np.abs(b.state - a.state)) <= TOL
    assert np.array_equal(b.state, a.state)           # in fact bit for bit
    assert np.array_equal(b.planing_force, a.planing_force)
    # B's recorder matched the player before its first command: every command, equal to A's.
    # The answer to the last state comes after the plant's run ended (and its run_end, at
    # which a recorder closes the bag): a bag may or may not hold it.
    k = min(len(a.command_t), len(b.command_t))
    assert k >= N - 1, (len(a.command_t), len(b.command_t))
    assert np.array_equal(b.command_t[:k], a.command_t[:k])
    assert np.array_equal(b.delta_f[:k], a.delta_f[:k])
    assert np.array_equal(b.delta_c[:k], a.delta_c[:k])
    # not a trivial run: eq. 31 moves the cavitator (its fins stay at 0) and the state moves
    assert np.ptp(a.delta_c) > 1e-3 and np.all(np.ptp(a.state, axis=0) > 0)


def test_commands_mode_names_a_state_the_bag_does_not_answer(tmp_path):
    bag = tmp_path / 'synthetic'
    write_bag(bag, 50)                # states every 1e-3 s; the plant publishes every 1e-4 s
    env = rosproc.ros_env()
    player = _player(env, f'bag_path:={bag}', 'mode:=commands')
    plant = _plant(env, tmp_path / 'plant.log', model='delay-free', duration=0.01,
                   command_timeout=30.0, start_timeout=60.0)
    code = rosproc.wait_exit(player, 60)
    out = rosproc.output(player)
    rosproc.stop(plant)
    assert code == 1, out
    assert 'no recorded command for the state at t=0.0001 s' in out and 'Traceback' not in out


class Listener:
    """A keep-all, transient-local subscriber (a late match loses nothing) in the test, with the
    nodes' discovery settings (:func:`rosproc.init_context`): /state (raw bytes, with the DDS
    source timestamp: when the player handed each one to DDS, which the test process's own
    scheduling under load does not shift), /command (counted) and /clock."""

    def __init__(self, domain: int) -> None:
        self.ctx = rosproc.init_context(domain)
        self.node = rclpy.create_node('listener', context=self.ctx)
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.states: list[tuple[float, bytes]] = []
        self.commands = 0
        self.clock: list[int] = []
        self.node.create_subscription(
            Float64MultiArray, '/state',
            lambda raw, info: self.states.append((info['source_timestamp'] * 1e-9, raw)),
            qos, raw=True)
        self.node.create_subscription(Float64MultiArray, '/command', self._on_command, qos,
                                      raw=True)
        self.node.create_subscription(
            Clock, '/clock', lambda m: self.clock.append(m.clock.sec * 10**9
                                                         + m.clock.nanosec), qos)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self._stop = False
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _on_command(self, raw: bytes) -> None:
        self.commands += 1

    def _spin(self) -> None:
        while not self._stop and self.ctx.ok():
            self.executor.spin_once(timeout_sec=0.02)

    def close(self) -> None:
        self._stop = True
        self.thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def listener():
    domain = rosproc.unique_domain_id()
    lis = Listener(domain)
    yield domain, lis
    lis.close()


def _recorded_states(bag) -> tuple[list[bytes], list[int]]:
    sc = scan(bag)
    ids = {c.id for c in sc.channels.values() if c.topic == '/state'}
    msgs = [(log, raw) for cid, log, raw in sc.messages if cid in ids]
    return [raw for _, raw in msgs], [log for log, _ in msgs]


def _play(domain, lis, bag, rate: float, n: int, tmp_path) -> str:
    log = tmp_path / f'player-{rate:g}.log'
    proc = _player(rosproc.ros_env(domain), f'bag_path:={bag}', f'rate:={rate!r}',
                   'topics:=[state]', log=log)
    assert rosproc.wait_exit(proc, 60) == 0, log.read_text()
    rosproc.wait_for(lambda: len(lis.states) >= n, 10, what=f'{n} states at the listener')
    return log.read_text()


def test_republish_every_state_in_order_with_clock_and_rate(tmp_path, listener):
    domain, lis = listener
    bag = tmp_path / 'run'
    write_bag(bag, 500)                  # 0.499 s simulated
    raws, logs = _recorded_states(bag)

    out = _play(domain, lis, bag, 0.0, 500, tmp_path)
    assert 'Traceback' not in out
    assert [raw for _, raw in lis.states] == raws        # every one, in order, same bytes
    rosproc.wait_for(lambda: len(lis.clock) >= 500, 10, what='/clock at every step')
    assert lis.clock == logs

    lis.states.clear()
    out = _play(domain, lis, bag, 1.0, 500, tmp_path)
    assert [raw for _, raw in lis.states] == raws
    # sent over about the recorded 0.499 s (DDS source timestamps: the arrival times in this
    # process spread over 2.5-6.4 s while two busy loops shared the cores with it)
    spread = lis.states[-1][0] - lis.states[0][0]
    assert 0.8 * 0.499 <= spread <= 3 * 0.499, (spread, out)


def test_republish_a_cut_bag_plays_what_is_recoverable(tmp_path, listener):
    domain, lis = listener
    bag = tmp_path / 'killed'
    write_bag(bag, 400, flush_every=100, close=False)
    mcap = next(bag.glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) * 6 // 10])      # cut in the middle of a chunk
    run = load_run(bag)
    assert run.truncated and 0 < len(run.t) < 400
    out = _play(domain, lis, bag, 0.0, len(run.t), tmp_path)
    assert 'bag is truncated' in out and 'Traceback' not in out, out
    raws, _ = _recorded_states(bag)
    assert [raw for _, raw in lis.states] == raws


def test_bad_paths_give_one_line_and_exit_1(tmp_path):
    """Each bad path is named by the player's reader (``scan``) with its cause; a player
    process turns that into one ``player: error:`` line and exit 1 (shown on one of them: the
    line is the same code for every BagError), and refuses an unknown mode with exit 2."""
    good = tmp_path / 'good'
    write_bag(good, 20)
    mcap = next(good.glob('*.mcap'))
    (tmp_path / 'empty').mkdir()
    text = tmp_path / 'notes.txt'
    text.write_text('not a bag\n')
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(mcap.read_bytes()[:5])
    headless = tmp_path / 'headless.mcap'
    headless.write_bytes(mcap.read_bytes()[:30])
    cases = {tmp_path / 'missing': 'no such file or directory',
             tmp_path / 'empty': 'empty directory',
             text: 'not an MCAP file',
             cut: 'truncated MCAP file',
             headless: 'nothing to recover'}
    for path, words in cases.items():
        with pytest.raises(BagError) as info:
            scan(path)
        assert str(path) in str(info.value) and words in str(info.value), info.value
    env = rosproc.ros_env()
    procs = {cut: _player(env, f'bag_path:={cut}'),
             'mode': _player(env, f'bag_path:={good}', 'mode:=loop')}
    for path, proc in procs.items():
        code = rosproc.wait_exit(proc, 60)
        out = rosproc.output(proc)
        assert 'Traceback' not in out, out
        lines = [ln for ln in out.splitlines() if ln.strip()]
        if path == 'mode':
            assert code == 2 and "mode='loop'" in out, out
            continue
        assert code == 1, (path, out)
        assert len(lines) == 1 and lines[0].startswith('player: error: '), out
        assert str(path) in lines[0] and cases[path] in lines[0], out


def _commands_bag(path, control_period: float, n: int) -> None:
    """A bag as a lockstep delay-free run at ``control_period`` records it: zero commands at
    every sample time t = k h (h = 1e-5 s, the times the plant computes), and the plant's
    parameters in the run metadata."""
    from fohssv_sim import contract
    from fohssv_sim.bag.synthetic import float64_array
    from fohssv_sim.bag.writer import RunWriter
    from fohssv_sim.params import ModelParameters

    w = RunWriter(path).open()
    w.add_topic('/command', contract.COMMAND.type)
    w.add_metadata({'fohssv.plant_parameters': {
        **ModelParameters(model='delay-free').to_dict(), 'step': 'auto',
        'control_period': control_period, 'initial_state': [0.0, 0.0, 0.0, 0.0],
        'mode': 'lockstep'}})
    hold = round(control_period / 1e-5)
    for k in range(n):
        t = k * hold * 1e-5
        w.write('/command', round(t * 1e9), float64_array(contract.COMMAND, [t, 0.0, 0.0]))
    w.close()


def test_commands_mode_refuses_a_plant_that_does_not_match_the_recording(tmp_path):
    """Issue 12, defect 8: a plant at control period 2e-4 s used to replay a 1e-4 s
    recording silently (both exit 0). The player compares and refuses, naming the
    difference; with force:=true it replays with a warning."""
    bag = tmp_path / 'rec'
    _commands_bag(bag, 1e-4, 201)
    env = rosproc.ros_env()
    player = _player(env, f'bag_path:={bag}', 'mode:=commands')
    plant = _plant(env, tmp_path / 'plant.log', model='delay-free', control_period=2e-4,
                   duration=0.01, command_timeout=30.0, start_timeout=60.0)
    code = rosproc.wait_exit(player, 60)
    out = rosproc.output(player)
    rosproc.stop(plant)
    assert code == 1, out
    assert ('the plant /plant does not match the recording: control_period: recorded '
            '0.0001, plant 0.0002') in out and 'force:=true' in out, out

    env = rosproc.ros_env()
    player = _player(env, f'bag_path:={bag}', 'mode:=commands', 'force:=true')
    plant = _plant(env, tmp_path / 'plant2.log', model='delay-free', control_period=2e-4,
                   duration=0.01, command_timeout=30.0, start_timeout=60.0)
    assert rosproc.wait_exit(plant, 60) == 0, (tmp_path / 'plant2.log').read_text()
    code = rosproc.wait_exit(player, 60)
    out = rosproc.output(player)
    assert code == 0, out
    assert 'does not match the recording: control_period' in out and 'replaying anyway' in out



def _interleaved_bag(path, n: int) -> None:
    """A bag as a recorder writes a loop in arrival order: the command answering t_k after
    the state t_(k+1) (the log times of the file step back at every other message)."""
    from fohssv_sim import contract
    from fohssv_sim.bag.synthetic import float64_array
    from fohssv_sim.bag.writer import RunWriter

    w = RunWriter(path).open()
    w.add_topic('/state', contract.STATE.type)
    w.add_topic('/command', contract.COMMAND.type)
    ts = [k * 1e-4 for k in range(n)]
    for k, t in enumerate(ts):
        w.write('/state', round(t * 1e9), float64_array(contract.STATE, [t, 0.0, 0.0, 0.0, 0.0]))
        if k:
            p = ts[k - 1]
            w.write('/command', round(p * 1e9), float64_array(contract.COMMAND, [p, 0.0, 0.0]))
    w.close()


def test_replayed_clock_never_steps_back_on_an_interleaved_bag(tmp_path, listener):
    """Issue 21.2: /clock stepped back about 2000 times per simulated second (it followed the
    log time of each message in file order). Every recorded time once, in order."""
    domain, lis = listener
    bag = tmp_path / 'interleaved'
    _interleaved_bag(bag, 300)
    log = tmp_path / 'player.log'
    # the player waits for the listener on each topic it plays (state, command, /clock);
    # with min_subscribers:=0 it played before the listener was matched, to nobody
    proc = _player(rosproc.ros_env(domain), f'bag_path:={bag}', 'rate:=0.0', log=log)
    assert rosproc.wait_exit(proc, 60) == 0, log.read_text()
    expected = [round(k * 1e-4 * 1e9) for k in range(300)]
    # at rate 0 /clock is reliable keep-all (the player's run_end lists it): every recorded
    # time once, in increasing order
    rosproc.wait_for(lambda: len(lis.clock) >= len(expected), 10, what='/clock')
    assert lis.clock == expected, lis.clock


def test_a_recorder_started_together_with_the_player_gets_its_run_end(tmp_path):
    """Issue 22.6: started at the same moment, the recorder could miss the player's run_end
    and never stop. Three pairs started at once: every recorder stops by itself with exit 0
    and the whole bag."""
    bag = tmp_path / 'source'
    _interleaved_bag(bag, 200)
    pairs = []
    for i in range(3):
        env = rosproc.ros_env()
        out, log = tmp_path / f'copy{i}', tmp_path / f'rec{i}.log'
        rec = rosproc.start_recorder(env, log, f'bag_path:={out}', 'plant_node:=none',
                                     ready=False)
        ply = _player(env, f'bag_path:={bag}', 'rate:=0.0', log=tmp_path / f'ply{i}.log')
        pairs.append((rec, ply, out, log))
    try:
        for rec, ply, out, log in pairs:
            assert rosproc.wait_exit(rec, 120) == 0, log.read_text()
            assert rosproc.wait_exit(ply, 60) == 0
            run = scan(out)
            counts = {}
            for cid, _, _ in run.messages:
                counts[run.channels[cid].topic] = counts.get(run.channels[cid].topic, 0) + 1
            assert counts.get('/state') == 200 and counts.get('/command') == 199, counts
    finally:
        for rec, ply, _, _ in pairs:
            for p in (rec, ply):
                if p.poll() is None:
                    rosproc.stop(p)
