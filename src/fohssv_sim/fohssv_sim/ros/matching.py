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
    with incompatible QoS). It latches: later joiners do not hold a running loop."""

    def __init__(self, node: Node, publisher: Publisher, grace: float = 2.0) -> None:
        self._node, self._pub, self._grace = node, publisher, grace
        self._deadline: float | None = None
        self._open = False

    def __call__(self) -> bool:
        if self._open:
            return True
        matched = self._pub.get_subscription_count()
        if matched == 0:
            return False
        now = time.monotonic()
        if self._deadline is None:
            self._deadline = now + self._grace
        known = self._node.count_subscribers(self._pub.topic_name)
        self._open = matched >= known or now >= self._deadline
        return self._open
