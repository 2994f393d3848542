"""When a publisher may send its first message without losing it to a known subscriber; and a
warning when a topic that should have one publisher (``state``: one plant) has more."""

from __future__ import annotations

import time

from rclpy.node import Node
from rclpy.publisher import Publisher

__all__ = ['HoldReporter', 'SubscriptionGate', 'SecondPublisherWarning', 'UNKNOWN_NODE',
           'node_path', 'GRAPH_RECHECK']

#: During a :class:`SubscriptionGate`'s grace period, the graph's subscriptions of its topic
#: are read again at most this often (s); the matched count at every call.
GRAPH_RECHECK = 1e-3

#: The name DDS gives an endpoint's node until the node itself is discovered (an endpoint is
#: found before its node's name: seen under load).
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'


def node_path(info) -> str:
    """``/namespace/name`` of the node of an endpoint (a ``TopicEndpointInfo``)."""
    return f"{info.node_namespace.rstrip('/')}/{info.node_name}"


class SecondPublisherWarning:
    """Checks every ``period`` s (a steady-clock timer of ``node``) whether ``topic`` has more
    than one publisher, and warns once, naming their nodes: two plants on one ROS_DOMAIN_ID and
    namespace (each plant refuses to run beside another; a controller or recorder started
    with them says what it saw). Graph queries only, never on the per-sample path."""

    def __init__(self, node: Node, topic: str, period: float = 0.5) -> None:
        from rclpy.clock import Clock, ClockType

        self.node = node
        self.topic = topic
        self.warned = False
        self._unnamed = 0
        self.timer = node.create_timer(period, self._check,
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _check(self) -> None:
        if self.warned or self.node.count_publishers(self.topic) <= 1:
            return
        infos = self.node.get_publishers_info_by_topic(self.topic)
        if any(i.node_name == UNKNOWN_NODE for i in infos) and self._unnamed < 10:
            self._unnamed += 1          # the endpoints are discovered before their nodes' names
            return
        self.warned = True
        self.timer.cancel()
        nodes = sorted(node_path(i) for i in infos)
        self.node.get_logger().warning(
            f"{len(infos)} publishers of {self.topic} (nodes: {', '.join(nodes)}): two plants "
            '(or a plant and a republishing player) on one ROS_DOMAIN_ID and namespace; their '
            'samples interleave. Give each its own ROS_DOMAIN_ID or namespace.')


class SubscriptionGate:
    """Callable that turns True once ``publisher`` has matched at least ``minimum``
    subscriptions and every subscription the graph lists on its topic (the plant, a recorder);
    or at least ``minimum`` and ``grace`` s have passed since it first matched that many (a
    listed subscription may never match, e.g. with incompatible QoS). It is re-checked at every
    message during the grace period (a subscription the graph lists but the writer has not
    matched yet pauses sending: latching at the first success let a recorder miss commands),
    and stays open after it, so a subscriber joining a running loop later does not hold it.
    ``minimum`` is a start condition: once it was met, a subscriber that leaves (a recorder
    stopped during the grace period) does not shut the gate again (it stalled a lockstep run).

    The graph lists a remote subscription only once discovery has reached this process, which
    can be after the plant's first sample: ``minimum`` is the guarantee (``minimum=2`` for a
    plant and a recorder), the graph check a best effort on top of it. The matched count is
    read at every message; the graph's count of subscriptions at most every
    :data:`GRAPH_RECHECK` s (a graph query costs about 4 us, most of a lockstep controller's
    own time per sample during the grace period), so a subscription the graph lists pauses
    sending at most that long after it is listed.

    ``follow`` (a topic name: the controller node's ``state``): the gate also waits, at the
    first message it passes and for at most ``follow_grace`` s from then, until the graph lists a
    subscription of this topic in the process of every publisher of ``follow`` and the
    publisher has matched every listed subscription. A controller answers the plant's state;
    the plant's ``command`` subscription can reach this process after its state did, while
    another subscriber of ``command`` (a recorder, a viewer) already meets ``minimum``: the
    first answer then went to that subscriber only and the lockstep plant waited for it
    until its ``command_timeout`` (a graph test failed so under load).
    """

    def __init__(self, node: Node, publisher: Publisher, grace: float = 2.0,
                 minimum: int = 1, follow: str | None = None,
                 follow_grace: float = 5.0) -> None:
        if minimum < 1:
            raise ValueError(f'minimum={minimum!r} must be >= 1')
        self._node, self._pub, self._grace = node, publisher, grace
        self._minimum = minimum
        self._deadline: float | None = None
        self._follow = follow
        self._follow_grace = follow_grace
        self._follow_deadline: float | None = None
        self._listed = 0              # the graph's subscriptions of the topic, read ...
        self._listed_until = 0.0      # ... again from this time (monotonic s) on

    def __call__(self) -> bool:
        matched = self._pub.get_subscription_count()
        now = time.monotonic()
        if self._deadline is None:
            if matched < self._minimum:
                return False
            self._deadline = now + self._grace
        if self._follow is not None:
            if self._follow_deadline is None:
                self._follow_deadline = now + self._follow_grace
            if now < self._follow_deadline and not self._follow_met(matched):
                return False
            self._follow = None       # met (or waited long enough): not asked again
        if now >= self._deadline:
            return True
        if now >= self._listed_until:
            self._listed = self._node.count_subscribers(self._pub.topic_name)
            self._listed_until = now + GRAPH_RECHECK
        return matched >= self._listed

    def _follow_met(self, matched: int) -> bool:
        """Whether the graph lists a publisher of ``follow`` (the state just answered came
        from one), every such process has a subscription of this topic in the graph, and the
        publisher has matched every listed subscription. Processes are told apart by their
        endpoints' GUID prefix, the first 12 bytes of the endpoint GID: a node's name can be
        discovered after its endpoints."""
        node = self._node
        topic = self._pub.topic_name
        if matched < node.count_subscribers(topic):
            return False
        sources = {bytes(i.endpoint_gid[:12])
                   for i in node.get_publishers_info_by_topic(self._follow)}
        listed = {bytes(i.endpoint_gid[:12])
                  for i in node.get_subscriptions_info_by_topic(topic)}
        return bool(sources) and sources <= listed

    @property
    def settled(self) -> bool:
        """True once the grace period has passed (and a ``follow`` check with it): from then
        on the gate is open, and a caller that found it open may stop asking
        (the controller node does, so that it makes no graph query per sample)."""
        return (self._deadline is not None and self._follow is None
                and time.monotonic() >= self._deadline)

    def describe(self) -> str:
        """Why the gate is shut, for a log line."""
        return (f'{self._pub.topic_name} has matched {self._pub.get_subscription_count()} of '
                f'{self._minimum} required subscription(s) (the graph lists '
                f'{self._node.count_subscribers(self._pub.topic_name)})')


class HoldReporter:
    """Logs, every ``every`` s after the first ``after`` s, that messages are held behind a
    shut :class:`SubscriptionGate` (a ``min_command_subscribers`` nobody meets would
    otherwise look like a hang)."""

    def __init__(self, node: Node, gate: SubscriptionGate, after: float = 2.0,
                 every: float = 5.0) -> None:
        self._node, self._gate, self._after, self._every = node, gate, after, every
        self._first: float | None = None
        self._next = 0.0

    def report(self, held: int) -> None:
        now = time.monotonic()
        if self._first is None:
            self._first, self._next = now, now + self._after
        if now >= self._next:
            self._next = now + self._every
            self._node.get_logger().warning(
                f'holding {held} message(s) for {now - self._first:.1f} s: '
                f'{self._gate.describe()}')
