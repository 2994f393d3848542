"""When a publisher may send its first message without losing it to a known subscriber."""

from __future__ import annotations

import time

from rclpy.node import Node
from rclpy.publisher import Publisher

__all__ = ['SubscriptionGate']


class SubscriptionGate:
    """Callable that turns True once ``publisher`` has matched every subscription the graph
    lists on its topic (the plant, a recorder), and at least one; or at least one and
    ``grace`` s have passed since the first match (a listed subscription may never match, e.g.
    with incompatible QoS). It is re-checked at every message during the grace period (a
    subscription the graph lists but the writer has not matched yet pauses sending: latching
    at the first success let a recorder miss commands), and stays open after it, so a
    subscriber joining a running loop later does not hold it."""

    def __init__(self, node: Node, publisher: Publisher, grace: float = 2.0) -> None:
        self._node, self._pub, self._grace = node, publisher, grace
        self._deadline: float | None = None

    def __call__(self) -> bool:
        matched = self._pub.get_subscription_count()
        if matched == 0:
            return False
        now = time.monotonic()
        if self._deadline is None:
            self._deadline = now + self._grace
        if now >= self._deadline:
            return True
        return matched >= self._node.count_subscribers(self._pub.topic_name)
