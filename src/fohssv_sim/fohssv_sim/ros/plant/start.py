"""The start gate and the restart: peers, listed readers, a second plant or controller, the
start, and the ``reset`` service.

Two rooms of :class:`fohssv_sim.ros.plant_node.PlantNode`:

* :class:`PeerGate`, an object that owns its state (how long it has waited, what it last
  logged, its two timers): given the node's graph queries and publishers, it calls the node
  back once to start the run, or to fail it (no peers, a second plant or controller);
* :class:`RunStart`, the start and the reset of a run, a mixin over the node's attributes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from time import monotonic
from typing import Any

from rclpy.node import Node
from rclpy.task import Future
from std_srvs.srv import Trigger

from ..matching import UNKNOWN_NODE, node_path
from ..nodekit import reset_plugin
from ..pacing import BurstWait, Pacer, cpu_seconds
from .codes import (
    EXIT_NO_PEERS,
    EXIT_PUBLISH_FAILED,
    EXIT_SECOND_CONTROLLER,
    EXIT_SECOND_PLANT,
    PublishFailed,
)
from .realtime import WATCHDOG_CHECK

#: How long a plant whose minimum peers are there waits for the other listed subscribers of
#: its sample topics to match before it starts anyway (PeerGate._listed_matched).
_LISTED_WAIT = 10.0

#: Wall seconds between two looks at the graph for a second plant (a graph query, off the
#: per-sample path).
RIVAL_CHECK_PERIOD = 0.5

#: Rival checks (of RIVAL_CHECK_PERIOD) a rival publisher's node name is waited for before
#: the plant stops without it.
_NAME_WAIT = 10

#: While waiting for its peers, the plant says what it waits for this often (s) and whenever
#: the matched counts change.
_WAIT_LOG_PERIOD = 5.0


class PeerGate:
    """The start gate (the module docstring): the plant publishes nothing until its peers
    matched; every :data:`RIVAL_CHECK_PERIOD` s, for the whole run, it looks for a second
    plant (and, hosted, a second controller).

    Given: ``node`` (its graph queries, timers and logger), ``options`` (the plant's options
    now: they may change at run time), ``hosted`` (the hosted law's name, None with an
    external controller), the node's publishers (``state_pub``, ``clock_pub``, the
    ``sample_pubs`` whose listed readers the start waits for, ``views``), its ``command_sub``
    (None when hosted) and ``command_topic``, ``finished`` (the run's end) and two calls back:
    ``start()`` once the peers matched, ``fail(code, message)``. Offers :meth:`peers`.
    """

    def __init__(self, node: Node, options: Callable[[], Any], hosted: str | None,
                 state_pub: Any, clock_pub: Any, sample_pubs: tuple[Any, ...], views: Any,
                 command_sub: Any, command_topic: str, finished: Future,
                 start: Callable[[], None], fail: Callable[[int, str], None]) -> None:
        self._node, self._options, self._hosted = node, options, hosted
        self._state_pub, self._clock_pub, self._sample_pubs = state_pub, clock_pub, sample_pubs
        self._views, self._command_sub, self._command_topic = views, command_sub, command_topic
        self._finished, self._start, self._fail = finished, start, fail
        self._log = node.get_logger()
        self._started = False
        self._wall_start = time.monotonic()
        self._minimums_since: float | None = None   # when the minimums were last met
        self._peers_logged: tuple[int, int] | None = None   # the counts last said
        self._next_wait_log = 0.0
        self._unnamed_checks = 0    # rival checks that waited for a publisher's node name
        self._peer_timer = node.create_timer(0.01, self._wait_for_peers)
        self._rival_timer = node.create_timer(RIVAL_CHECK_PERIOD, self._check_rivals)

    def peers(self) -> tuple[int, int]:
        """Matched (state subscribers, command publishers); a hosted law counts as one of
        each (it reads every sample and commands), so the same minimums start a hosted plant
        alone and a hosted plant with a recorder."""
        subs = self._state_pub.get_subscription_count()
        if self._hosted is not None:
            return subs + 1, 1
        return subs, self._command_sub.get_publisher_count()

    def _views_matched(self) -> int:
        """The fewest matched subscribers of any typed view (a large number with views off:
        nothing to wait for)."""
        if self._views is None:
            return 1 << 30
        return min(p.get_subscription_count() for p in self._views.publishers)

    def _listed_matched(self) -> bool:
        """Every subscription the graph lists on the sample topics and ``/clock`` has matched
        the plant's writer (a recorder or probe whose planing_force reader matches after its
        state reader would otherwise miss the start of a short, fast run; a volatile
        ``command`` reader of a hosted plant would miss its first commands, and a ``/clock``
        reader the first ``/clock`` messages, published only while someone subscribes).
        Best effort: after :data:`_LISTED_WAIT` s with the minimums met the plant starts
        anyway, saying which readers had not matched (one may never match, e.g. with
        incompatible QoS)."""
        if self._minimums_since is None:
            self._minimums_since = time.monotonic()
        unmatched = [f'{pub.topic_name} ({pub.get_subscription_count()} of {listed} '
                     'matched)' for pub in self._sample_pubs + (self._clock_pub,)
                     if pub.get_subscription_count() < (listed := self._node.count_subscribers(
                         pub.topic_name))]
        if not unmatched:
            return True
        if time.monotonic() - self._minimums_since > _LISTED_WAIT:
            self._log.warning(
                f'starting although not every listed subscriber matched after '
                f'{_LISTED_WAIT:g} s: {", ".join(unmatched)}; those readers may miss the '
                'first samples (incompatible QoS?)')
            return True
        return False

    def _waiting_for(self, subs: int, pubs: int) -> str:
        """What the plant waits for, in words (logged at start, on a change, every 5 s)."""
        o = self._options()
        missing = []
        if pubs < o.min_command_publishers:
            missing.append('a controller' if o.min_command_publishers - pubs == 1 else
                           f'{o.min_command_publishers - pubs} command publishers')
        if subs < o.min_state_subscribers:
            missing.append(f'{o.min_state_subscribers - subs} more state subscriber(s) '
                           '(controllers, recorders)')
        views = self._views_matched()
        if views < o.min_view_subscribers:
            missing.append(f'{o.min_view_subscribers - views} more subscriber(s) of each view '
                           '(a viewer)')
        what = ' and '.join(missing) or 'the listed subscribers to match'
        return (f'waiting for {what}: command has {pubs}/{o.min_command_publishers} '
                f'publisher(s), {self._state_pub.topic_name} has {subs}/'
                f'{o.min_state_subscribers} subscriber(s)')

    def _check_rivals(self) -> None:
        """Refuse to run beside another publisher of ``state`` (a second plant, a republishing
        player): the two would take each other's commands and publish interleaved samples.
        With a hosted controller, also beside another publisher of ``command``."""
        if self._hosted is not None:
            self._check_second_controller()
        if self._finished.done() or self._node.count_publishers(self._state_pub.topic_name) <= 1:
            return                                # only this plant's own publisher
        nodes = self._publisher_nodes(self._state_pub.topic_name)
        if nodes is None:
            return
        self._fail(EXIT_SECOND_PLANT,
                   f'{len(nodes)} publishers of {self._state_pub.topic_name} (nodes: '
                   f"{', '.join(nodes)}): another plant (or a republishing player) runs on this "
                   'ROS_DOMAIN_ID and namespace, and the two would take each other\'s commands; '
                   'stopping. Give each its own ROS_DOMAIN_ID or namespace.')

    def _check_second_controller(self) -> None:
        """A hosted plant and an external publisher of ``command`` (a controller node, a
        player replaying commands): two controllers must never mix, so the plant stops."""
        topic = self._command_topic
        if self._finished.done() or self._node.count_publishers(topic) <= 1:
            return                                # only the plant's own command publisher
        nodes = self._publisher_nodes(topic)
        if nodes is None:
            return
        self._fail(EXIT_SECOND_CONTROLLER,
                   f'{len(nodes)} publishers of {topic} (nodes: {", ".join(nodes)}): this '
                   f'plant hosts the controller {self._hosted!r} (controller:='
                   f'{self._options().controller}) and another node publishes commands too; two '
                   'controllers must not mix, stopping. Stop the external controller, or start '
                   "the plant with controller:='' to use it.")

    def _publisher_nodes(self, topic: str) -> list[str] | None:
        """The nodes publishing ``topic``, sorted, for the one line that stops the plant; None
        while a publisher's node is not named yet (DDS discovers an endpoint before its
        node's name: the line said ``_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_``) and the
        name has been waited for less than :data:`_NAME_WAIT` rival checks; after that the
        stop goes ahead, naming the node as not yet known."""
        infos = self._node.get_publishers_info_by_topic(topic)
        unnamed = sum(i.node_name == UNKNOWN_NODE for i in infos)
        if unnamed and self._unnamed_checks < _NAME_WAIT:
            self._unnamed_checks += 1
            return None
        return sorted('(a node whose name is not discovered yet)' if i.node_name == UNKNOWN_NODE
                      else node_path(i) for i in infos)

    def _wait_for_peers(self) -> None:
        if self._started or self._finished.done():
            return    # a timer event queued before the start destroyed the timer: start once
        subs, pubs = self.peers()
        o = self._options()
        if (subs >= o.min_state_subscribers and pubs >= o.min_command_publishers
                and self._views_matched() >= o.min_view_subscribers):
            if self._listed_matched():
                self._node.destroy_timer(self._peer_timer)
                self._started = True
                self._start()
                return
        else:
            self._minimums_since = None    # a peer left again (a controller swapped)
        now = time.monotonic()
        waited = now - self._wall_start
        if o.start_timeout == 0.0 or waited < o.start_timeout:
            # no clock, no sample: say what is missing when it changes and every 5 s
            if (subs, pubs) != self._peers_logged or now >= self._next_wait_log:
                self._peers_logged = (subs, pubs)
                self._next_wait_log = now + _WAIT_LOG_PERIOD
                limit = ('no start timeout' if o.start_timeout == 0.0 else
                         f'start_timeout {o.start_timeout:g} s')
                hint = ('; start one in the same ROS_DOMAIN_ID and namespace, e.g. '
                        '`ros2 run fohssv_controller state_feedback`'
                        if pubs < o.min_command_publishers else '')
                self._log.info(f'{self._waiting_for(subs, pubs)} (waited {waited:.0f} '
                               f's, {limit}){hint}')
            return
        self._fail(EXIT_NO_PEERS, f'start timeout: state has {subs}/{o.min_state_subscribers} '
                   f'subscriber(s), command has {pubs}/{o.min_command_publishers} '
                   f'publisher(s) after {waited:.1f} s (start_timeout={o.start_timeout:g} s); '
                   'is the controller running in the same ROS_DOMAIN_ID and namespace?')


class RunStart:
    """The start and the reset of a run (the module docstring): a mixin, as both drive every
    other room (publishing, lockstep, real time, the hosted law) over the node's attributes."""

    running = False             # started and not ended (nor interrupted)
    pacer: Pacer | None = None  # realtime: the wall-clock schedule, from the start
    bursts: BurstWait | None = None   # hosted realtime: the wake-up per burst of samples
    _timer: Any = None          # the run's check: lockstep timeout, or real time's watchdog
    _run_wall_start = 0.0       # monotonic s at the start
    _cpu_start = 0.0            # process CPU s at the start
    resets = 0
    _samples_before = 0         # samples and steps before the last reset
    _steps_before = 0

    def _start(self) -> None:
        self.running = True
        self._run_wall_start = time.monotonic()
        self._cpu_start = cpu_seconds()
        self.watchdog.last = self._run_wall_start
        try:
            self._start_run()
        except PublishFailed as exc:
            self._fail(EXIT_PUBLISH_FAILED, str(exc))

    def _start_run(self) -> None:
        subs, pubs = self.gate.peers()
        self.get_logger().info(f'peers matched (command: {pubs} publisher(s), state: {subs} '
                               'subscriber(s)); starting at t = 0')
        if self.record is not None:   # the law's name in the bag (plot titles)
            self.record.name_controller(None if self.hosted is None
                                        else self.get_parameter('controller').value)
        # who subscribes to /clock (and a hosted plant's command): looked at again between
        # chunks of samples (hosted) or in the timer's checks (external controller)
        self._refresh_matched()
        if self._free_run:           # lockstep, hosted: the spin loop runs chunks of samples
            self._publish()
            self._control()
        elif self.options.mode == 'lockstep':
            self._publish()
            self._await_command()
            period = min(0.05, max(self.options.command_timeout / 4.0, 0.001))
            self.command_wait.checked = monotonic()
            self._timer = self.create_timer(period, self._check_lockstep_timeout)
        else:
            o = self.options
            wall_period = o.control_period / o.real_time_factor
            tick = max(o.pacing_period, wall_period)
            batch = max(1, round(tick / wall_period))
            pacer = Pacer(period=wall_period, tolerance=tick, max_batch=2 * batch,
                          max_backlog=10 * batch)
            # hosted: one wake-up per burst of samples (5 at the defaults, fewer while the
            # machine is slow to wake the plant: BurstWait)
            if self.hosted is not None:
                self.bursts = BurstWait(period=wall_period, tolerance=tick)
            pacer.begin(time.monotonic())
            self._publish()
            pacer.published(time.monotonic())
            self.pacer = pacer   # from now on the spin loop publishes the samples when due
            if self.hosted is None:
                self._timer = self.create_timer(WATCHDOG_CHECK, self._check_watchdog)
            else:
                self._control()

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        if self.finished.done() or self._announced:
            response.success = False
            response.message = 'the run has ended'
            return response
        if self.hosted is not None:   # first: a law that cannot reset refuses the reset
            failed = reset_plugin(self.hosted.name, self.hosted.reset)
            if failed is not None:
                response.success = False
                response.message = f'{failed}; the plant was not reset'
                self.get_logger().error(f'reset refused: {response.message}')
                return response
        self.resets += 1
        self._samples_before += self.sim.samples
        self._steps_before += self.sim.plant.n
        self.sim.reset(self.options.initial_state)
        self.lag_stop.rearm()
        self.watchdog.rearm()
        self.get_logger().info(f'reset to t = 0 at {list(self.options.initial_state)}')
        if self.running:
            if self.pacer is not None:     # due from now on; its counts stay the run's
                self.pacer.restart(time.monotonic())
            try:
                self._publish()
            except PublishFailed as exc:
                self._fail(EXIT_PUBLISH_FAILED, str(exc))
                response.success = False
                response.message = str(exc)
                return response
            if self.pacer is not None:
                self.pacer.published(time.monotonic())
            if self.hosted is not None:
                self._control()
            elif self.options.mode == 'lockstep':
                self._await_command()
        response.success = True
        response.message = f't = {self.sim.t!r} s, state = {list(self.options.initial_state)}'
        return response
