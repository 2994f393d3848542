"""Issue 21: what a recorder announces is what it checked (real recorder process, sources in
the test process over DDS).

* Namespaced topics (``topics:=[/a/state,/b/state]``): each is written under its own name, and
  the recorder waits for the run_end of each namespace (one recorder, two vehicles).
* Two publishers of one topic: the first run_end does not close the bag; the sum of both
  run_ends is checked (exit 0). When the second never comes: exit 7, completeness unchecked.
* Publishers gone without any run_end (a plant that died): after end_timeout of silence the
  recorder says so and exits 7 with a readable bag.
"""

from __future__ import annotations

import contextlib
import signal

import pytest
import rclpy
import yaml
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, String
from test_graph_support import stop_all

from fohssv_sim import contract
from fohssv_sim.bag import load_run

import rosproc

pytestmark = pytest.mark.graph

_DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                   reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
_END = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                  durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Sources:
    """Nodes in the test process, each publishing ``state`` (and ``run_end``) in a namespace."""

    def __init__(self, domain: int) -> None:
        self.ctx = rosproc.init_context(domain)     # the nodes' discovery settings
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.nodes = []

    def add(self, name: str, namespace: str = ''):
        node = rclpy.create_node(name, namespace=namespace, context=self.ctx)
        self.ex.add_node(node)
        self.nodes.append(node)
        return (node, node.create_publisher(Float64MultiArray, 'state', _DEEP),
                node.create_publisher(String, 'run_end', _END))

    def wait(self, predicate, what: str) -> None:
        rosproc.wait_for(lambda: (self.ex.spin_once(timeout_sec=0.01), predicate())[1], 60,
                         what=what)

    def spin(self, seconds: float) -> None:
        import time
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.ex.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        for n in self.nodes:
            with contextlib.suppress(Exception):
                n.destroy_node()
        rclpy.shutdown(context=self.ctx)


def _publish(state, end, n: int, t0: float = 0.0, claim: int | None = None) -> None:
    for k in range(n):
        state.publish(Float64MultiArray(data=[t0 + k * 1e-4, 0.0, 0.0, 0.0, 0.0]))
    if end is not None:
        end.publish(String(data=contract.run_end_text(
            'plant', 'test', 0, t0 + n * 1e-4, {state.topic_name: n if claim is None
                                                else claim})))


def _recorder(tmp_path, env, topics: str, end_timeout: float = 2.0):
    bag, log = tmp_path / 'bag', tmp_path / 'recorder.log'
    rec = rosproc.start_recorder(env, log, f'bag_path:={bag}', 'plant_node:=none',
                                 f'end_timeout:={end_timeout}', f'topics:={topics}')
    return rec, bag, log


def test_one_recorder_records_two_namespaced_vehicles(tmp_path):
    domain = rosproc.unique_domain_id()
    rec, bag, log = _recorder(tmp_path, rosproc.ros_env(domain), '[/a/state,/b/state]')
    src = Sources(domain)
    try:
        _, sa, ea = src.add('plant', 'a')
        _, sb, eb = src.add('plant', 'b')
        src.wait(lambda: all(p.get_subscription_count() >= 1 for p in (sa, sb, ea, eb)),
                 'the recorder to match')
        # /b's samples first, acknowledged by the recorder's reader (so the recorder has
        # discovered /b's writer: a recorder that has not yet seen a vehicle cannot wait for
        # it, and under load its half of discovery came after /a's end), its run_end last
        _publish(sb, None, 20)
        assert sb.wait_for_all_acked(Duration(seconds=60)), 'the recorder took /b/state'
        src.spin(1.0)                                   # its graph looks every 0.1 s
        _publish(sa, ea, 30)
        src.spin(1.0)
        assert rec.poll() is None, log.read_text()      # /b has not ended yet
        _publish(sb, eb, 0, t0=20e-4, claim=20)
        code = rosproc.wait_exit(rec, 60)
    finally:
        src.close()
        stop_all(rec)
    text = log.read_text()
    assert code == 0, text
    assert 'KeyError' not in text and 'every message of the run is in the bag' in text
    assert load_run(bag, namespace='/a').topics['/a/state'] == 30
    assert load_run(bag, namespace='/b').topics['/b/state'] == 20


@pytest.mark.parametrize('second_ends', [True, False])
def test_two_publishers_of_a_topic_need_two_run_ends(tmp_path, second_ends):
    domain = rosproc.unique_domain_id()
    rec, bag, log = _recorder(tmp_path, rosproc.ros_env(domain), '[state]')
    src = Sources(domain)
    try:
        _, s1, e1 = src.add('player')
        _, s2, e2 = src.add('player2')
        src.wait(lambda: all(p.get_subscription_count() >= 1 for p in (s1, s2, e1, e2)),
                 'the recorder to match')
        src.spin(0.5)                                    # the recorder counts 2 publishers
        _publish(s1, e1, 25)
        src.spin(1.0)
        assert rec.poll() is None, log.read_text()       # not complete at the first run_end
        _publish(s2, e2 if second_ends else None, 15, t0=1.0)
        code = rosproc.wait_exit(rec, 60)
    finally:
        src.close()
        stop_all(rec)
    text = log.read_text()
    assert load_run(bag).topics['/state'] == 40
    if second_ends:
        assert code == 0, text
        assert 'every message of the run is in the bag' in text
    else:
        assert code == 7, text
        assert 'every message of the run is in the bag' not in text
        assert 'completeness cannot be checked' in text


def test_publishers_gone_without_run_end_end_the_recording_with_exit_7(tmp_path):
    domain = rosproc.unique_domain_id()
    rec, bag, log = _recorder(tmp_path, rosproc.ros_env(domain), '[state]', end_timeout=1.0)
    src = Sources(domain)
    try:
        node, s, e = src.add('plant')
        src.wait(lambda: s.get_subscription_count() >= 1 and e.get_subscription_count() >= 1,
                 'the recorder to match')
        _publish(s, None, 12)
        src.spin(1.0)
        node.destroy_node()                              # the plant died: no run_end
        src.nodes.remove(node)
        code = rosproc.wait_exit(rec, 60)
    finally:
        src.close()
        stop_all(rec)
    text = log.read_text()
    assert code == 7, text
    assert 'gone without a run_end' in text and 'Traceback' not in text
    assert load_run(bag).topics['/state'] == 12



def test_a_signal_after_the_publishers_left_without_run_end_exits_7(tmp_path):
    """A recorder far behind a fast run misses its run_end (the plant left first: a reader
    drops what it has not taken from a writer that goes away) and gets its signal before
    end_timeout of silence (``make demo`` stops it 30 s after the plant's end): the drain
    must not end in exit 0, a completeness never checked (seen: 11865 of 20001 states, exit
    0, the demo's summary printed)."""
    domain = rosproc.unique_domain_id()
    rec, bag, log = _recorder(tmp_path, rosproc.ros_env(domain), '[state]', end_timeout=60.0)
    src = Sources(domain)
    watcher = rclpy.create_node('watcher', context=src.ctx)
    src.ex.add_node(watcher)
    try:
        node, s, e = src.add('plant')
        src.wait(lambda: s.get_subscription_count() >= 1 and e.get_subscription_count() >= 1,
                 'the recorder to match')
        _publish(s, None, 12)
        src.spin(1.0)
        node.destroy_node()                              # gone without its run_end
        src.nodes.remove(node)
        src.wait(lambda: watcher.count_publishers('/state') == 0, 'the plant to be gone')
        src.spin(1.0)                                    # the recorder looks every 0.1 s
        assert rec.poll() is None, log.read_text()       # end_timeout (60 s) not reached
        rec.send_signal(signal.SIGINT)
        code = rosproc.wait_exit(rec, 60)
    finally:
        watcher.destroy_node()
        src.close()
        stop_all(rec)
    text = log.read_text()
    assert code == 7, text
    assert 'gone without a run_end' in text and 'Traceback' not in text
    assert load_run(bag).topics['/state'] == 12


def test_a_recorder_stopped_before_any_message_marks_its_bag_empty(tmp_path):
    """What the launch file leaves when another node fails at start (``controller:=nope``):
    the recorder, stopped by the launch before any message, closes a bag marked
    ``fohssv.empty`` in its metadata and says so (the demo removes such a bag)."""
    rec, bag, log = _recorder(tmp_path, rosproc.ros_env(), '[state]')
    rec.send_signal(signal.SIGINT)
    code = rosproc.wait_exit(rec, 60)
    text = log.read_text()
    assert code == 0, text
    assert 'the bag is empty (marked fohssv.empty in its metadata)' in text
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
    custom = meta['rosbag2_bagfile_information']['custom_data']
    assert custom['fohssv.empty'] == 'no message arrived before the recorder stopped'
