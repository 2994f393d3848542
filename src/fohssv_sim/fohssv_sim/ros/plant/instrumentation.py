"""Measurement hooks of the plant node: :class:`Profile` (``profile:=1``) times named parts of
the per-sample path by wrapping the node's own calls, so the product path has no timing code
and no twin methods. Pure module: no rclpy.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from time import perf_counter_ns
from typing import Any

__all__ = ['PROFILE_PARTS', 'Profile']


#: The per-sample costs :class:`Profile` measures, in the order of its ``ns`` accumulators.
PROFILE_PARTS = ('advance', 'write_sample', 'publish_state', 'publish_planing_force',
                 'publish_clock', 'command_callback', 'publish_views', 'hosted_law')


@dataclass
class Profile:
    """Accumulated wall time (``time.perf_counter_ns``) of each part of the per-sample path.

    Installed on a node (:meth:`install`) only when the ``profile`` option is on: then each
    part costs two ``perf_counter_ns`` calls (about 0.1 us) on top of itself; off, the node
    runs its own calls, untouched. ``ns[i]`` and ``calls[i]`` belong to ``PROFILE_PARTS[i]``.
    """

    ns: list[int] = field(default_factory=lambda: [0] * len(PROFILE_PARTS))
    calls: list[int] = field(default_factory=lambda: [0] * len(PROFILE_PARTS))
    worst: list[int] = field(default_factory=lambda: [0] * len(PROFILE_PARTS))

    last: list[int] = field(default_factory=lambda: [0] * len(PROFILE_PARTS))

    def add(self, part: int, ns: int) -> None:
        self.ns[part] += ns
        self.calls[part] += 1
        self.last[part] = ns
        if ns > self.worst[part]:
            self.worst[part] = ns

    def add_more(self, part: int, ns: int) -> None:
        """More cost of the last call of ``part``, paid at a later sample (a view's messages
        go out one per sample): mean and worst are per call, all its pieces together."""
        self.ns[part] += ns
        self.last[part] += ns
        if self.last[part] > self.worst[part]:
            self.worst[part] = self.last[part]

    def summary(self) -> dict[str, dict[str, float]]:
        """Per part that ran (``command_callback`` with an external controller,
        ``hosted_law``, the law and the publishing of its command, with a hosted one): mean
        and worst cost in microseconds and the number of calls."""
        return {name: {'mean_us': self.ns[i] / self.calls[i] / 1e3,
                       'worst_us': self.worst[i] / 1e3, 'calls': self.calls[i]}
                for i, name in enumerate(PROFILE_PARTS) if self.calls[i]}

    def timed(self, part: str, call: Callable[..., Any], more: bool = False
              ) -> Callable[..., Any]:
        """``call`` with its wall time added to ``part`` (``more``: as :meth:`add_more`)."""
        i = PROFILE_PARTS.index(part)
        add = self.add_more if more else self.add

        def timed_call(*args: Any) -> Any:
            t0 = perf_counter_ns()
            result = call(*args)
            add(i, perf_counter_ns() - t0)
            return result

        return timed_call

    def install(self, node: Any) -> None:
        """Time the plant node's named parts from now on: the model's period (``_step``),
        the sample's writing (``sim.write_sample``), the publishes (``_send_state``,
        ``_send_force``, ``_send_clock``, the views'), the command callback
        (``_command_callback``) and a hosted law with its command's publish (``_control``).
        Each is the node's own call wrapped, so the profiled run takes the node's path and
        rules (its publish retries too)."""
        node._step = self.timed('advance', node._step)
        node.sim.write_sample = self.timed('write_sample', node.sim.write_sample)
        node._send_state = self.timed('publish_state', node._send_state)
        node._send_force = self.timed('publish_planing_force', node._send_force)
        node._send_clock = self.timed('publish_clock', node._send_clock)
        if node._command_callback is not None:     # an external controller's commands
            node._command_callback = self.timed('command_callback', node._command_callback)
        node._control = self.timed('hosted_law', node._control)
        if node.views is not None:
            node.views.publish = self.timed('publish_views', node.views.publish)
            node.views.publish_next = self.timed('publish_views', node.views.publish_next,
                                                 more=True)
