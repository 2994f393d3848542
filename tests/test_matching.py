"""SubscriptionGate with a real rclpy node in this process: it pauses while the graph lists a
subscription its publisher has not matched, and during its grace period it reads the graph at
most every GRAPH_RECHECK s while reading the matched count at every call."""

from __future__ import annotations

import time

import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray

from fohssv_sim.ros.matching import GRAPH_RECHECK, SubscriptionGate

import rosproc


def _until(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


def test_gate_pauses_for_a_listed_unmatched_subscription_and_reads_the_graph_sparingly():
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=rosproc.unique_domain_id())
    node = rclpy.create_node('gate_test', context=context)
    try:
        best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        pub = node.create_publisher(Float64MultiArray, 'gated', best_effort)
        node.create_subscription(Float64MultiArray, 'gated', lambda m: None, best_effort)
        assert _until(lambda: pub.get_subscription_count() == 1, 10)
        gate = SubscriptionGate(node, pub, grace=60.0)
        queries = []
        count_subscribers = node.count_subscribers

        def counted(topic: str) -> int:
            queries.append(time.monotonic())
            return count_subscribers(topic)

        node.count_subscribers = counted        # the real query, its calls counted
        begin = time.monotonic()
        calls = 0
        while time.monotonic() - begin < 0.05:
            assert gate()                       # one subscription, matched
            calls += 1
        elapsed = time.monotonic() - begin
        assert calls > 200, calls               # (else the test says nothing)
        assert len(queries) <= elapsed / GRAPH_RECHECK + 2, (len(queries), elapsed)
        # a reliable reader cannot match a best-effort writer: listed by the graph, never
        # matched, it pauses the gate (within GRAPH_RECHECK of being listed) for the grace
        node.create_subscription(Float64MultiArray, 'gated', lambda m: None, reliable)
        assert _until(lambda: count_subscribers('/gated') == 2, 10)
        time.sleep(2 * GRAPH_RECHECK)
        assert not gate() and pub.get_subscription_count() == 1
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)
