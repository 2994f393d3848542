"""Viewer: watch a run live in Foxglove, with no foxglove_bridge (which the PyPI wheels lack).

``ros2 run fohssv_sim viewer`` serves the Foxglove WebSocket protocol on ws://127.0.0.1:8765
(parameters ``host``, ``port``); in Foxglove, *Open connection -> Foxglove WebSocket ->
ws://localhost:8765* and import the layout ``docs/foxglove/fohssv_layout.json``: the vehicle
and its cavity move in the 3D panel, the plots draw the state and the planing force.

* It subscribes to the plant's typed views (``pose``, ``twist``, ``planing_wrench``,
  ``vehicle_marker``, published every ``view_period`` of simulated time, see :mod:`.views`),
  reliable, keep-last 100, volatile. The plant's view writers are keep-last, so a slow viewer
  never holds the plant back (its oldest views are dropped instead). Reliable, not best
  effort: the plant starts once its writers have matched the viewer's readers
  (``min_view_subscribers``), and discovery is not symmetric in time: the viewer's side of
  the match can complete later, and a best-effort reader drops what a writer it does not
  know yet sends (a short run was over before that: the viewer received no view, under
  load). A reliable reader asks for those views once it has matched. It does not subscribe
  to ``state``: a subscriber there counts in the plant's ``min_state_subscribers``, so a
  viewer could stand in for a controller or the recorder and let the plant start before
  they listen. The state and the planing force it serves are the
  views' numbers (exact, theta to rounding; see :mod:`.foxglove_live`).
* Decimation: at most ``rate`` views per wall-clock second reach Foxglove (a timer at ``rate``
  Hz sends the newest complete view, if it is new); the plant's own decimation
  (``view_period``, 0.01 s of simulated time by default) comes first.
* What it serves (topics, schemas): :mod:`.foxglove_live`; the conversion lives there, without
  rclpy. The channels are advertised at start, so a client can subscribe before the run.
* ``host`` is the loopback address by default: only this machine can connect. Another
  address serves the run to the network without authentication (a warning says so).
* Clients (:mod:`.foxglove_gate`): both names of the protocol (``foxglove.websocket.v1``,
  ``foxglove.sdk.v1``); browser origins of the Foxglove and Lichtblick apps and of this
  machine's pages, plus ``allowed_origins``; at most ``max_clients`` at once. A refused
  handshake is logged (a warning naming the peer and the reason, once per reason and peer).

Exit codes: 0 stopped by SIGINT/SIGTERM (the server is closed); 1 the server cannot bind (port
in use, unknown host: one ``viewer: error: ...`` line); 2 invalid arguments or parameters
(one line naming the parameter, the value, the allowed range and the unit).
"""

from __future__ import annotations

import sys
import time
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import Marker as MarkerMsg

from .. import contract
from .foxglove_live import LiveServer, Marker, ViewAssembler
from .nodekit import (
    NODE_OPTIONS,
    declare,
    destroy_on_error,
    error_line,
    final_log,
    refuse_unknown,
    run_node,
)
from .viewer_options import VIEWER_PARAMETERS, ViewerOptions

__all__ = ['Viewer', 'main']

#: Messages kept per topic (two markers per view): keep-last, so a viewer slower than that
#: drops the oldest. 100: as deep as the plant's view writers (a second of views at the default
#: view_period); with 10 a viewer starved for a tenth of a second under load lost 8 of a
#: 0.3 s run's 31 views (a make test run).
_DEPTH = 100


def _stamp(header: Any) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def _xyz(v: Any) -> tuple[float, float, float]:
    return v.x, v.y, v.z


def _xyzw(q: Any) -> tuple[float, float, float, float]:
    return q.x, q.y, q.z, q.w


class Viewer(Node):
    """Subscribes to the plant's views and serves them to Foxglove; see the module
    docstring. Raises ValueError (bad parameters) or OSError (cannot bind) from the
    constructor."""

    @destroy_on_error
    def __init__(self, **kwargs: Any) -> None:
        super().__init__('viewer', **NODE_OPTIONS, **kwargs)
        self.options = ViewerOptions(**declare(self, VIEWER_PARAMETERS))
        refuse_unknown(self)
        o = self.options
        # as many incomplete views as the readers hold: a viewer behind the run takes a topic's
        # queued messages together (all the poses, then all the twists, ...), so every view of
        # that backlog is incomplete until its last topic's turn (with 8 kept, a viewer that
        # lagged under load assembled 4 of a 0.3 s run's 31 views: a make test run)
        self.assembler = ViewAssembler(keep=_DEPTH)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=_DEPTH,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
        subs = [self.create_subscription(cls, topic.name, callback, qos) for cls, topic, callback
                in ((PoseStamped, contract.POSE, self._on_pose),
                    (TwistStamped, contract.TWIST, self._on_twist),
                    (WrenchStamped, contract.WRENCH, self._on_wrench),
                    (MarkerMsg, contract.MARKER, self._on_marker))]
        self.subscriptions_ = subs
        names = {'pose': subs[0].topic_name, 'twist': subs[1].topic_name,
                 'wrench': subs[2].topic_name, 'scene': subs[3].topic_name,
                 'state': self.resolve_topic_name(contract.STATE.name),
                 'force': self.resolve_topic_name(contract.PLANING_FORCE.name)}
        self.server = LiveServer(o.host, o.port, names, max_clients=int(o.max_clients),
                                 allowed_origins=o.allowed_origins,
                                 on_refused=self.get_logger().warning)
        url_host = 'localhost' if o.loopback else o.host
        self.get_logger().info(
            f'serving Foxglove on ws://{o.host}:{self.server.port} (in Foxglove: Open '
            f'connection -> ws://{url_host}:{self.server.port}; layout '
            f'docs/foxglove/fohssv_layout.json); at most {o.rate:g} views/s of '
            f"{', '.join(s.topic_name for s in subs)}")
        if not o.loopback:
            self.get_logger().warning(
                f'host={o.host!r} is not a loopback address: anyone who can reach this '
                'machine can connect and watch the run (no authentication)')
        self._reported = 0
        self._next_send = 0.0      # monotonic s: no view before (see _forward)
        self.timer = self.create_timer(1.0 / o.rate, self._forward)

    def _on_pose(self, msg: PoseStamped) -> None:
        self.assembler.add_pose(_stamp(msg.header), msg.header.frame_id,
                                _xyz(msg.pose.position), _xyzw(msg.pose.orientation))

    def _on_twist(self, msg: TwistStamped) -> None:
        self.assembler.add_twist(_stamp(msg.header), msg.header.frame_id,
                                 _xyz(msg.twist.linear), _xyz(msg.twist.angular))

    def _on_wrench(self, msg: WrenchStamped) -> None:
        self.assembler.add_wrench(_stamp(msg.header), msg.header.frame_id,
                                  _xyz(msg.wrench.force), _xyz(msg.wrench.torque))

    def _on_marker(self, msg: MarkerMsg) -> None:
        c = msg.color
        self.assembler.add_marker(_stamp(msg.header), Marker(
            msg.id, msg.header.frame_id, _xyz(msg.pose.position), _xyzw(msg.pose.orientation),
            _xyz(msg.scale), (c.r, c.g, c.b, c.a)))

    def _forward(self) -> None:
        subscriptions = self.server.subscriptions
        if subscriptions != self._reported:
            self._reported = subscriptions
            self.get_logger().info(f'Foxglove clients: {subscriptions} subscription(s) of '
                                   f'{len(self.server.topics)} channels')
        # at most `rate` views a second: after a stall the executor may fire the timer's missed
        # ticks back to back (seen under load: 5 views sent in 0.29 s at rate 10); such a tick
        # sends nothing, and the newest view waits for the next one
        now = time.monotonic()
        if now < self._next_send:
            return
        view = self.assembler.take()
        if view is not None:
            self.server.send(view)
            self._next_send = now + 0.9 / self.options.rate   # a tick's jitter still passes

    def summary(self) -> str:
        a = self.assembler
        return (f'{a.complete} views received, {self.server.sent} sent to Foxglove '
                f'({self.server.sessions} session(s))')


def _close(node: Viewer) -> None:
    server = getattr(node, 'server', None)
    if server is not None:
        final_log('viewer', f'stopping: {node.summary()}')
        server.stop()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run fohssv_sim viewer``; returns the exit code. SIGINT and
    SIGTERM only set STOP (spin.StopSignal): the spin ends, the server is closed."""
    return run_node('viewer', args, Viewer, specs=VIEWER_PARAMETERS,
                    on_error=error_line('viewer'), on_exit=_close)


if __name__ == '__main__':
    sys.exit(main())
