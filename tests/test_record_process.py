"""The recorder as a real process over DDS, fed by a real rclpy node in the test that plays
the plant: it steps the real delay-free model and publishes the contract messages.

Asserts: the recorded state series equals the model's trajectory sample for sample with
exact times and log times round(t * 1e9); the bag carries the plant's parameters and the
source revision; SIGINT and SIGTERM give complete bags that pass the structural check,
``pymcap-cli doctor`` without error or warning, and open with rosbags and mcap_ros2; every
topic's ``offered_qos_profiles`` (metadata.yaml and MCAP channel) deserializes to what the
plant's publisher offers, as the ROS graph reports it; SIGKILL leaves a bag that loads with
every flushed message and that repair makes complete and doctor-clean.
"""

from __future__ import annotations

import signal
import threading
import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from mcap.reader import make_reader
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, ReliabilityPolicy
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.metadata import parse_qos
from rosgraph_msgs.msg import Clock
from ruamel.yaml import YAML
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from visualization_msgs.msg import Marker

from fohssv_sim import contract
from fohssv_sim.bag import BagError, load_run
from fohssv_sim.bag.check import check
from fohssv_sim.bag.repair import repair
from fohssv_sim.models import make_plant
from fohssv_sim.params import ModelParameters
from fohssv_sim.ros.qos import profile

from mcap_doctor import assert_doctor_clean
from rosproc import (
    init_context,
    output,
    ros_env,
    start,
    start_recorder,
    stop,
    unique_domain_id,
    wait_exit,
    wait_for,
)

pytestmark = pytest.mark.graph

_CLASSES = {contract.FLOAT64_ARRAY: Float64MultiArray, contract.CLOCK.type: Clock,
            contract.POSE.type: PoseStamped, contract.TWIST.type: TwistStamped,
            contract.WRENCH.type: WrenchStamped, contract.MARKER.type: Marker}
VIEWS = {'/' + t.name for t in contract.VIEW_TOPICS}


class FakePlant:
    """A node named 'plant' with parameters, publishing a real model's steps."""

    def __init__(self, domain: int) -> None:
        self.ctx = init_context(domain)     # the nodes' discovery settings
        self.node = Node('plant', context=self.ctx)
        self.node.declare_parameter('model', 'delay-free')
        self.node.declare_parameter('V', 75.0)
        self.node.declare_parameter('control_period', 1e-4)
        # the typed views too (the recorder records them by default); none is published here
        self.pubs = {t.name: self.node.create_publisher(_CLASSES[t.type], t.name, profile(t))
                     for t in contract.TOPICS + contract.VIEW_TOPICS}
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()
        self.model = make_plant(ModelParameters(model='delay-free'))
        self.t: list[float] = []
        self.x: list[tuple] = []

    def wait_matched(self) -> None:
        wait_for(lambda: all(p.get_subscription_count() > 0 for p in self.pubs.values()), 20,
                 what='the recorder subscribing to every topic')

    def publish(self, steps: int, period: float = 1e-3) -> None:
        """``steps`` steps, one every ``period`` s of wall time (as a real-time plant paces
        them: command's keep-last queue is only COMMAND_DEPTH deep); asleep in between (a
        busy wait took a core for the whole run)."""
        start = time.perf_counter()
        for k in range(steps):
            ahead = start + k * period - time.perf_counter()
            if ahead > 0:
                time.sleep(ahead)
            t, x = self.model.t, self.model.state
            u = (0.01 * np.sin(50 * t), -0.005)
            self.t.append(t)
            self.x.append(tuple(x))
            for topic, data in ((contract.STATE, [t, *x]),
                                (contract.PLANING_FORCE, [t, self.model.planing_force]),
                                (contract.COMMAND, [t, *u])):
                msg = Float64MultiArray(data=[float(v) for v in data])
                msg.layout.dim = [MultiArrayDimension(label=topic.label, size=len(data),
                                                      stride=len(data))]
                self.pubs[topic.name].publish(msg)
            clock = Clock()
            ns = round(t * 1e9)
            clock.clock.sec, clock.clock.nanosec = ns // 10**9, ns % 10**9
            self.pubs['/clock'].publish(clock)
            self.model.step(u)

    def close(self) -> None:
        # the spin thread ends before the node and context it waits on are destroyed (the
        # other order crashed a test worker with a segfault inside the executor's wait)
        self.executor.shutdown()
        self.thread.join(timeout=5)
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def domain():
    return unique_domain_id()


@pytest.fixture
def plant(domain):
    p = FakePlant(domain)
    yield p
    p.close()


def _recorder(tmp_path, domain, *params: str):
    log = tmp_path / 'recorder.log'
    return start_recorder(ros_env(domain), log, 'plant_timeout:=20.0', *params,
                          ready=False), log


def _assert_matches(run, plant, n=None):
    n = len(plant.t) if n is None else n
    t = np.array(plant.t[:n])
    assert np.array_equal(run.t, t)                       # exact doubles
    assert np.array_equal(run.state, np.array(plant.x[:n]))
    assert np.array_equal(run.log_time['state'], np.array([round(v * 1e9) for v in t]))
    assert np.array_equal(run.command_t, t) and np.array_equal(run.planing_force_t, t)


def _assert_qos_is_what_the_plant_offers(bag, plant) -> None:
    """Deserialize each topic's offered_qos_profiles from metadata.yaml and from the MCAP
    channel; compare with the plant publisher's profile as the graph reports it (history and
    depth, which the graph does not report, with the profile the publisher was created with)."""
    info = YAML(typ='safe').load((bag / 'metadata.yaml').read_text())
    from_yaml = {t['topic_metadata']['name']: parse_qos(t['topic_metadata']['offered_qos_profiles'])
                 for t in info['rosbag2_bagfile_information']['topics_with_message_count']}
    with open(bag / 'run.mcap', 'rb') as f:
        summary = make_reader(f).get_summary()
    from_mcap = {c.topic: parse_qos(c.metadata['offered_qos_profiles'])
                 for c in summary.channels.values()}
    assert set(from_yaml) == set(from_mcap) == {'/state', '/planing_force', '/command',
                                                '/clock'} | VIEWS
    for topic in contract.TOPICS + contract.VIEW_TOPICS:
        name = topic.name if topic.name.startswith('/') else '/' + topic.name
        offered = [i.qos_profile for i in plant.node.get_publishers_info_by_topic(name)]
        assert len(offered) == 1, (name, offered)
        graph, made = offered[0], profile(topic)
        for qos_list in (from_yaml[name], from_mcap[name]):
            assert len(qos_list) == 1, (name, qos_list)
            q = qos_list[0]
            assert HistoryPolicy[q.history.name] == made.history and q.depth == made.depth
            assert ReliabilityPolicy[q.reliability.name] == graph.reliability, name
            assert DurabilityPolicy[q.durability.name] == graph.durability, name
            assert LivelinessPolicy[q.liveliness.name] == graph.liveliness, name
            for field in ('deadline', 'lifespan', 'liveliness_lease_duration'):
                t = getattr(q, field)
                assert Duration(seconds=t.sec, nanoseconds=t.nsec) == getattr(graph, field)
    assert from_yaml['/state'][0].durability.name == 'TRANSIENT_LOCAL'   # not all defaults


def _recorded(bag) -> int:
    try:
        run = load_run(bag)
    except BagError:          # nothing flushed yet
        return 0
    return min(len(run.t), len(run.command_t), len(run.planing_force_t))


def _wait_recorded(bag, n: int) -> None:
    """Poll the bag while the recorder writes it (the loader reads unfinished bags)."""
    wait_for(lambda: _recorded(bag) >= n, 90, interval=0.1, what=f'{n} steps in {bag}')


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_signal_closes_a_complete_bag_equal_to_the_trajectory(tmp_path, domain, plant, sig):
    bag = tmp_path / 'run'
    proc, log = _recorder(tmp_path, domain, f'bag_path:={bag}')
    plant.wait_matched()
    wait_for(lambda: 'parameters of /plant' in log.read_text(), 30,
             what='the recorder reading the plant parameters')
    plant.publish(1500)
    _wait_recorded(bag, 1500)
    assert stop(proc, sig) == 0, log.read_text()
    out = log.read_text()
    assert f'recording to {bag}' in out and 'closed' in out and '/state: 1500' in out
    run = load_run(bag)
    assert not run.truncated
    _assert_matches(run, plant)
    clock = run.topics.pop('/clock')
    assert {v: run.topics.pop(v) for v in VIEWS} == dict.fromkeys(VIEWS, 0)
    assert run.topics == {'/state': 1500, '/planing_force': 1500, '/command': 1500}
    # /clock is keep-last 1 at the publisher (qos.py): the newest may replace an unsent one
    assert 0 < clock <= 1500 and set(run.clock_t) <= {round(t * 1e9) * 1e-9 for t in plant.t}
    assert run.parameters['model'] == 'delay-free' and run.parameters['V'] == 75.0
    assert run.metadata['fohssv.git_revision']
    assert run.metadata['fohssv.version'] == '0.1.0'
    report = check(bag)
    assert report.ok, report.problems
    with Reader(bag) as reader:
        assert reader.message_count == 3 * 1500 + clock
    assert_doctor_clean(bag / 'run.mcap')
    _assert_qos_is_what_the_plant_offers(bag, plant)


def test_sigkill_keeps_every_flushed_message_and_repair_completes_it(tmp_path, domain, plant):
    bag = tmp_path / 'killed'
    proc, log = _recorder(tmp_path, domain, f'bag_path:={bag}', 'flush_period:=0.05',
                          'plant_node:=none')
    plant.wait_matched()
    plant.publish(1000)
    # they reach the file within a flush period, readable while the recorder runs
    _wait_recorded(bag, 1000)
    plant.publish(300)    # and 300 more, killed straight after: some may be lost
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    assert not (bag / 'metadata.yaml').exists()
    run = load_run(bag)
    assert run.truncated and 'recovered' in run.recovery
    assert 1000 <= len(run.t) <= 1300
    # a kill can land between a step's messages: each topic is an exact prefix of its own
    t_all = np.array(plant.t)
    for times in (run.t, run.command_t, run.planing_force_t):
        assert 1000 <= len(times) and np.array_equal(times, t_all[:len(times)])
    assert np.array_equal(run.state, np.array(plant.x[:len(run.t)]))
    assert run.metadata['fohssv.plant_node'] == 'none'
    assert repair(bag).repaired
    assert check(bag).ok
    assert_doctor_clean(bag / 'killed.mcap')
    again = load_run(bag)
    assert not again.truncated and np.array_equal(again.state, run.state)


def test_default_path_and_bad_parameters(tmp_path, domain):
    env = ros_env(domain, FOHSSV_ROOT=str(tmp_path))
    proc = start('fohssv_sim', 'recorder', ['--ros-args', '-p', 'plant_node:=none'], env=env)
    wait_for(lambda: any((tmp_path / 'runs').glob('*/*.mcap')), 20, what='a bag under runs/')
    assert stop(proc, signal.SIGINT) == 0
    out = proc.stdout.read()
    bags = list((tmp_path / 'runs').iterdir())
    assert len(bags) == 1 and f'recording to {bags[0]}' in out
    assert check(bags[0]).ok     # an empty run is still a sound bag
    assert_doctor_clean(next(bags[0].glob('*.mcap')))
    for bad, words in ((['topics:=[speed]'], "'speed' is not a contract topic"),
                       ([f'bag_path:={bags[0]}'], 'exists already'),
                       (['flush_period:=0.0'], 'flush_period')):
        proc = start('fohssv_sim', 'recorder', ['--ros-args', '-p', *bad], env=env)
        assert wait_exit(proc, 30) == 2     # invalid parameters, as in every node
        out = proc.stdout.read()
        assert words in out and 'Traceback' not in out, out


def test_signals_while_the_recorder_exits_keep_exit_0(tmp_path):
    """A recorder that is closing (here after a first SIGINT) keeps getting SIGINTs until it
    is gone, as a test harness or an impatient terminal does: it still exits 0 with a
    complete bag. (Python's finalization restored the default action, so a signal in the
    last moments killed it with -SIGINT.)"""
    env = ros_env()
    bag = tmp_path / 'bag'
    rec = start('fohssv_sim', 'recorder', ['--ros-args', '-p', f'bag_path:={bag}',
                                           '-p', 'plant_node:=none'], env=env)
    wait_for(lambda: any(bag.glob('*.mcap')), 30, what='the bag')
    deadline = time.monotonic() + 30
    while rec.poll() is None and time.monotonic() < deadline:
        try:
            rec.send_signal(signal.SIGINT)
        except ProcessLookupError:
            break
        time.sleep(0.002)
    assert wait_exit(rec, 10) == 0, output(rec)
    assert check(bag).ok
