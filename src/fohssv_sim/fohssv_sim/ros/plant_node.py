"""The plant node: ``ros2 run fohssv_sim plant [--ros-args --params-file config/plant.yaml]``.

A thin wrapper around :class:`fohssv_sim.ros.loop.SampledPlant` (the model the parameters name,
sampled every ``control_period`` with the command held). Topics (relative names, see
:mod:`fohssv_sim.contract` and ``docs/ros.md``): publishes ``state``, ``planing_force`` and
``/clock`` at every sample, the typed views (:mod:`.views`) every ``view_period``, and once,
when the run ends (also after a signal), ``run_end``: the messages it published on each topic,
which a recorder checks its bag against; subscribes ``command``; service ``reset``
(std_srvs/Trigger).

Modes:

* ``lockstep``: publish the sample at t_n, wait for the ``command`` whose t is exactly t_n,
  advance one control period with it, publish the next. Deterministic whatever the load;
  ``command_timeout`` ends the run (exit 3) naming the side that stalled.
* ``realtime``: a wall-clock pacer publishes every sample when due (``real_time_factor``),
  holding the newest good command; deadline misses are counted and reported; the watchdog
  warns once per outage when no command came for ``watchdog_timeout``.

Start: the plant publishes nothing (no sample, no ``/clock``) until ``min_command_publishers``
controllers and ``min_state_subscribers`` readers have matched; it logs what it still waits
for whenever that changes and every 5 s. ``start_timeout`` 0 (default) waits indefinitely, so
``ros2 run fohssv_sim plant`` and a controller started later in another terminal just work; a
positive ``start_timeout`` is for scripts: exit 4 when it expires, in both modes.

Exit codes: 0 clean stop (signal or ``duration`` reached), 1 state turned non-finite,
2 invalid parameters at start, 3 lockstep timeout or plant overrun, 4 peers missing when a
positive ``start_timeout`` expired, 5 another publisher of ``state`` (a second plant) on the
same ROS_DOMAIN_ID and namespace, 6 a sample could not be published (DDS refused it for
``publish_timeout`` s, e.g. a machine so loaded that the readers never acknowledge): the run
ends there with its summary and a ``run_end`` listing what was published.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Mapping
from time import monotonic, perf_counter_ns
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from ..contract import CLOCK, COMMAND, PLANING_FORCE, RUN_END, STATE, run_end_text
from ..params import PARAMETERS, ModelParameters
from .loop import (
    CommandRejected,
    Pacer,
    Profile,
    SampledPlant,
    answered_time,
    check_command,
    cpu_seconds,
)
from .nodekit import (
    STOP,
    ArrayReader,
    ArrayWriter,
    ClockWriter,
    LogLimiter,
    PausedCollector,
    declare,
    destroy_on_error,
    final_log,
    install_validation,
    make_executor,
    profile,
    refuse_unknown,
    run_node,
    set_realtime_priority,
    spin_until,
    tighten_timer_slack,
)
from .options import NODE_PARAMETERS, PlantOptions, check_options, clock_samples, view_samples
from .views import ViewPublisher

__all__ = ['PlantNode', 'main', 'EXIT_OK', 'EXIT_DIVERGED', 'EXIT_BAD_PARAMETERS',
           'EXIT_TIMEOUT', 'EXIT_NO_PEERS', 'EXIT_SECOND_PLANT', 'EXIT_PUBLISH_FAILED']

EXIT_OK, EXIT_DIVERGED, EXIT_BAD_PARAMETERS, EXIT_TIMEOUT, EXIT_NO_PEERS = 0, 1, 2, 3, 4
#: Another publisher of ``state`` on the plant's domain and namespace (a second plant).
EXIT_SECOND_PLANT = 5
#: A sample DDS refused to take for :data:`_PUBLISH_RETRY` s (retried every millisecond).
EXIT_PUBLISH_FAILED = 6
_PUBLISH_RETRY = 1.0


class PublishFailed(Exception):
    """A sample that could not be published (after retries); ends the run with exit 6."""
#: Wall seconds between two looks at the graph for a second plant (a graph query, off the
#: per-sample path).
_RIVAL_CHECK_PERIOD = 0.5

_MODEL_NAMES = tuple(p.name for p in PARAMETERS)
_NODE_NAMES = tuple(p.name for p in NODE_PARAMETERS)
#: Lockstep with pace_to_subscribers: the longest wait for the acknowledgements (s).
_ACK_TIMEOUT = 1.0
#: Rejected commands logged one by one; later ones are throttled to one line per second.
_LOG_EACH = 20
#: Realtime mode: wall-clock period of the watchdog check (s).
_WATCHDOG_CHECK = 0.01
#: While waiting for its peers, the plant says what it waits for this often (s) and whenever
#: the matched counts change.
_WAIT_LOG_PERIOD = 5.0


def build_config(values: Mapping[str, Any]) -> tuple[ModelParameters, PlantOptions, int]:
    """The pure configuration from parameter values: model, options, steps per sample.

    Raises:
        ParameterError: an invalid value or combination.
    """
    model = ModelParameters.from_dict({n: values[n] for n in _MODEL_NAMES})
    options = PlantOptions(**{n: values[n] for n in _NODE_NAMES})
    hold = check_options(model, options)
    return model, options, hold


class PlantNode(Node):
    """See the module docstring. Raises ParameterError from the constructor on bad values."""

    @destroy_on_error
    def __init__(self, **kwargs: Any) -> None:
        super().__init__('plant', **kwargs)
        values = declare(self, PARAMETERS + NODE_PARAMETERS)
        refuse_unknown(self)
        self.model, self.options, hold = build_config(values)
        self.sim = SampledPlant(self.model, self.options.control_period,
                                self.options.initial_state, self.options.duration)
        install_validation(self, _MODEL_NAMES + _NODE_NAMES, build_config, self._apply)

        self.finished = Future()
        self.exit_code = EXIT_OK
        # the messages of every sample, serialized once and written in place (wire.py)
        self._state_out = ArrayWriter(STATE)
        self._force_out = ArrayWriter(PLANING_FORCE)
        self._state_data = self._state_out.values   # [t, z, w, theta, q] inside the CDR
        self._force_data = self._force_out.values
        self._clock_out = ClockWriter()
        self._command_in = ArrayReader(COMMAND)
        self._clock_every = clock_samples(self.options)
        self._lockstep = self.options.mode == 'lockstep'
        self.profile: Profile | None = Profile() if self.options.profile else None
        self._cpu_start = 0.0
        self.state_pub = self.create_publisher(Float64MultiArray, STATE.name, profile(STATE))
        self.force_pub = self.create_publisher(Float64MultiArray, PLANING_FORCE.name,
                                               profile(PLANING_FORCE))
        self.clock_pub = self.create_publisher(Clock, CLOCK.name, profile(CLOCK))
        # typed views for viewers, every view_period (views.py); None when off
        self._view_every = view_samples(self.options)
        self.views = ViewPublisher(self, self.model) if self._view_every else None
        # the writers whose readers (recorders, viewers) the start, flush and linger wait for
        self._sample_pubs = (self.state_pub, self.force_pub) + (
            self.views.publishers if self.views is not None else ())
        on_command = self._on_command if self.profile is None else self._on_command_profiled
        self.command_sub = self.create_subscription(Float64MultiArray, COMMAND.name,
                                                    on_command, profile(COMMAND), raw=True)
        if self.profile is not None:
            self._publish = self._publish_profiled   # type: ignore[method-assign]
            self._step = self._step_profiled         # type: ignore[method-assign]
        self.reset_srv = self.create_service(Trigger, 'reset', self._on_reset)
        # once, when the run ends: what was published, for recorders to check (contract.py)
        self.end_pub = self.create_publisher(String, RUN_END.name, profile(RUN_END))
        self.sent = 0                             # samples published (state, planing_force)
        self.received = 0                         # commands received while running
        self._announced = False                   # run_end published
        self.forces_lost = 0                      # planing_force samples not published
        self.publish_retries = 0                  # publishes DDS refused at first
        self.resets = 0
        self._samples_before = 0                  # samples and steps before the last reset
        self._steps_before = 0
        self._log_rejected = LogLimiter(self.get_logger(), _LOG_EACH)
        self._log_retry = LogLimiter(self.get_logger(), 5, level='warning')

        self.running = False
        self.rejected = 0
        self.stale = 0                            # realtime: of those, stale or future
        self.ignored = 0
        self._awaiting: float | None = None       # lockstep: t of the state awaiting a command
        self._published_wall = 0.0                # lockstep: when that state went out
        self._last_command_t: float | None = None  # t of the last command received
        self._last_command_wall: float | None = None
        self._watchdog_warned = False
        self._max_lag = 0.0                       # realtime: sim time between state and command
        self._wall_start = time.monotonic()
        self._run_wall_start = 0.0
        self._timer = None
        self.pacer: Pacer | None = None
        self._minimums_since: float | None = None
        self._peers_logged: tuple[int, int] | None = None
        self._next_wait_log = 0.0
        self._peer_timer = self.create_timer(0.01, self._wait_for_peers)
        self._rival_timer = self.create_timer(_RIVAL_CHECK_PERIOD, self._check_rivals)
        self.get_logger().info(
            f'{self.sim.plant.describe()} (ready in {self.sim.compile_seconds:.2f} s); mode '
            f'{self.options.mode}, control period '
            f'{self.options.control_period:g} s = {hold} steps (zero-order hold), duration '
            f'{self.options.duration:g} s')

    # -- parameters ------------------------------------------------------------------------
    def _apply(self, config: tuple[ModelParameters, PlantOptions, int]) -> None:
        _, options, _ = config
        self.options = options
        # a lowered deflection limit applies to the command held now, not only to the next
        # ones: a held command beyond it is replaced by the command clamped to the limit
        df, dc = self.sim.command
        lf, lc = options.max_fin_deflection, options.max_cavitator_deflection
        if abs(df) > lf or abs(dc) > lc:
            held = (max(-lf, min(lf, df)), max(-lc, min(lc, dc)))
            self.sim.command = held
            self.get_logger().warning(
                f'deflection limits now max_fin_deflection={lf:g} rad, '
                f'max_cavitator_deflection={lc:g} rad at t={self.sim.t!r} s: the held command '
                f'delta_f={df!r}, delta_c={dc!r} rad is beyond them; holding the clamped '
                f'command delta_f={held[0]!r}, delta_c={held[1]!r} rad')

    # -- start -------------------------------------------------------------------------------
    def _peers(self) -> tuple[int, int]:
        return self.state_pub.get_subscription_count(), self.command_sub.get_publisher_count()

    def _listed_matched(self) -> bool:
        """Every subscription the graph lists on the sample topics has matched the plant's
        writer (a recorder or probe whose planing_force reader matches after its state reader
        would otherwise miss the start of a short, fast run). Best effort: after 2 s with the
        minimums met the plant starts anyway (a listed reader may never match, e.g. with
        incompatible QoS)."""
        if self._minimums_since is None:
            self._minimums_since = time.monotonic()
        if time.monotonic() - self._minimums_since > 2.0:
            return True
        return all(pub.get_subscription_count() >= self.count_subscribers(pub.topic_name)
                   for pub in self._sample_pubs)

    def _waiting_for(self, subs: int, pubs: int) -> str:
        """What the plant waits for, in words (logged at start, on a change, every 5 s)."""
        o = self.options
        missing = []
        if pubs < o.min_command_publishers:
            missing.append('a controller' if o.min_command_publishers - pubs == 1 else
                           f'{o.min_command_publishers - pubs} command publishers')
        if subs < o.min_state_subscribers:
            missing.append(f'{o.min_state_subscribers - subs} more state subscriber(s) '
                           '(controllers, recorders)')
        what = ' and '.join(missing) or 'the listed subscribers to match'
        return (f'waiting for {what}: command has {pubs}/{o.min_command_publishers} '
                f'publisher(s), {self.state_pub.topic_name} has {subs}/'
                f'{o.min_state_subscribers} subscriber(s)')

    def _check_rivals(self) -> None:
        """Refuse to run beside another publisher of ``state`` (a second plant, a republishing
        player): the two would take each other's commands and publish interleaved samples."""
        if self.finished.done() or self.count_publishers(self.state_pub.topic_name) <= 1:
            return                                # only this plant's own publisher
        infos = self.get_publishers_info_by_topic(self.state_pub.topic_name)
        nodes = sorted(f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos)
        self._fail(EXIT_SECOND_PLANT,
                   f'{len(infos)} publishers of {self.state_pub.topic_name} (nodes: '
                   f"{', '.join(nodes)}): another plant (or a republishing player) runs on this "
                   'ROS_DOMAIN_ID and namespace, and the two would take each other\'s commands; '
                   'stopping. Give each its own ROS_DOMAIN_ID or namespace.')

    def _wait_for_peers(self) -> None:
        if self.running or self.finished.done():
            return    # a timer event queued before _start destroyed the timer: start once
        subs, pubs = self._peers()
        o = self.options
        if subs >= o.min_state_subscribers and pubs >= o.min_command_publishers:
            if self._listed_matched():
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
                self.get_logger().info(f'{self._waiting_for(subs, pubs)} (waited {waited:.0f} '
                                       f's, {limit}){hint}')
            return
        self._fail(EXIT_NO_PEERS, f'start timeout: state has {subs}/{o.min_state_subscribers} '
                   f'subscriber(s), command has {pubs}/{o.min_command_publishers} '
                   f'publisher(s) after {waited:.1f} s (start_timeout={o.start_timeout:g} s); '
                   'is the controller running in the same ROS_DOMAIN_ID and namespace?')

    def _start(self) -> None:
        self.destroy_timer(self._peer_timer)
        self.running = True
        self._run_wall_start = time.monotonic()
        self._cpu_start = cpu_seconds()
        self._last_command_wall = self._run_wall_start
        subs, pubs = self._peers()
        try:
            self._start_run()
        except PublishFailed as exc:
            self._fail(EXIT_PUBLISH_FAILED, str(exc))

    def _start_run(self) -> None:
        subs, pubs = self._peers()
        self.get_logger().info(f'peers matched (command: {pubs} publisher(s), state: {subs} '
                               'subscriber(s)); starting at t = 0')
        if self.options.mode == 'lockstep':
            self._publish()
            self._await_command()
            period = min(0.05, max(self.options.command_timeout / 4.0, 0.001))
            self._timer = self.create_timer(period, self._check_lockstep_timeout)
        else:
            o = self.options
            wall_period = o.control_period / o.real_time_factor
            tick = max(o.pacing_period, wall_period)
            batch = max(1, round(tick / wall_period))
            pacer = Pacer(period=wall_period, tolerance=tick, max_batch=2 * batch,
                          max_backlog=10 * batch)
            pacer.begin(time.monotonic())
            self._publish()
            pacer.published(time.monotonic())
            self.pacer = pacer   # from now on the spin loop publishes the samples when due
            self._timer = self.create_timer(_WATCHDOG_CHECK, self._check_watchdog)

    # -- publishing (every sample: preallocated messages written in place) --------------------
    def _publish(self) -> None:
        self.sent += 1
        self.sim.write_sample(self._state_data, self._force_data)
        # a failed publish (rclpy's RCLError 'Failed to publish' under load) is retried,
        # and ends the run with exit 6 (summary, run_end) if DDS keeps refusing it
        try:
            self.state_pub.publish(self._state_out.payload())
        except Exception as exc:  # noqa: BLE001 - RCLError is not exported by rclpy
            self._retry_publish(self.state_pub, self._state_out.payload(), exc, state=True)
        try:
            self.force_pub.publish(self._force_out.payload())
        except Exception as exc:  # noqa: BLE001
            self._retry_publish(self.force_pub, self._force_out.payload(), exc)
        if self.sim.samples % self._clock_every == 0:
            try:
                self.clock_pub.publish(self._clock_out.payload(round(self._state_data[0] * 1e9)))
            except Exception as exc:  # noqa: BLE001 - keep-last 1: the next one replaces it
                self._log_retry(f'/clock at t={self._state_data[0]!r} s not published: {exc}')
        if self._view_every and self.sim.samples % self._view_every == 0:
            try:
                self.views.publish(self._state_data, self._force_data[1])
            except Exception as exc:  # noqa: BLE001 - views are for people: never fatal
                self._log_retry(f'views at t={self._state_data[0]!r} s not published: {exc}')

    def _retry_publish(self, pub: Any, payload: Any, exc: Exception, state: bool = False
                       ) -> None:
        """Publish again every millisecond for up to :data:`_PUBLISH_RETRY` s (counted, the
        first lines logged); raise :class:`PublishFailed` if DDS still refuses."""
        self.publish_retries += 1
        self._log_retry(f'{pub.topic_name}: publishing the sample at t={self._state_data[0]!r} '
                        f'failed ({exc}); retrying ({self.publish_retries} retried)')
        deadline = monotonic() + _PUBLISH_RETRY
        while monotonic() < deadline and rclpy.ok():
            time.sleep(0.001)
            try:
                pub.publish(payload)
                return
            except Exception as again:  # noqa: BLE001
                exc = again
        if state:
            self.sent -= 1                     # the state of this sample never went out
        self.forces_lost += 1                  # nor its planing_force (not published after)
        raise PublishFailed(f'{pub.topic_name}: the sample at t={self._state_data[0]!r} s '
                            f'could not be published for {_PUBLISH_RETRY:g} s ({exc}); '
                            'stopping the run')

    def _publish_profiled(self) -> None:
        add = self.profile.add
        self.sent += 1
        t0 = perf_counter_ns()
        self.sim.write_sample(self._state_data, self._force_data)
        t1 = perf_counter_ns()
        self.state_pub.publish(self._state_out.payload())
        t2 = perf_counter_ns()
        self.force_pub.publish(self._force_out.payload())
        t3 = perf_counter_ns()
        add(1, t1 - t0)
        add(2, t2 - t1)
        add(3, t3 - t2)
        if self.sim.samples % self._clock_every == 0:
            t3 = perf_counter_ns()
            self.clock_pub.publish(self._clock_out.payload(round(self._state_data[0] * 1e9)))
            add(4, perf_counter_ns() - t3)
        if self._view_every and self.sim.samples % self._view_every == 0:
            t3 = perf_counter_ns()
            self.views.publish(self._state_data, self._force_data[1])
            add(6, perf_counter_ns() - t3)

    def _step(self) -> None:
        self.sim.advance()

    def _step_profiled(self) -> None:
        t0 = perf_counter_ns()
        self.sim.advance()
        self.profile.add(0, perf_counter_ns() - t0)

    def _advance(self) -> bool:
        """One control period and its sample; False when the run ended."""
        try:
            self._step()
        except FloatingPointError as exc:
            self._fail(EXIT_DIVERGED, f'simulation failed: {exc}')
            return False
        try:
            self._publish()
        except PublishFailed as exc:
            self._fail(EXIT_PUBLISH_FAILED, str(exc))
            return False
        if self.pacer is not None:
            self.pacer.published(monotonic())
        if self.sim.reached(self.options.duration):
            self._finish(f'duration {self.options.duration:g} s reached')
            return False
        return True

    # -- lockstep ----------------------------------------------------------------------------
    def _await_command(self) -> None:
        self._awaiting = self.sim.t
        self._published_wall = time.monotonic()

    def _check_lockstep_timeout(self) -> None:
        if self._awaiting is None or not self.running:
            return
        waited = time.monotonic() - self._published_wall
        if waited <= self.options.command_timeout:
            return
        last = ('no command received at all' if self._last_command_t is None else
                f'the last command answered t={self._last_command_t!r} s')
        self._fail(EXIT_TIMEOUT,
                   f'lockstep timeout: the controller stalled: no command answering '
                   f't={self._awaiting!r} s within command_timeout='
                   f'{self.options.command_timeout:g} s ({last}; command has '
                   f'{self.command_sub.get_publisher_count()} publisher(s))')

    def _lockstep_command(self, data: Any, t: float | None) -> None:
        if self._awaiting is None or t != self._awaiting:
            self.ignored += 1
            self.get_logger().warning(
                f'ignored a command for t={t!r} s while waiting for t={self._awaiting!r} s '
                f'({self.ignored} ignored so far)', throttle_duration_sec=1.0)
            return
        self._take(data)
        self._awaiting = None
        begin = monotonic()
        if not self._advance():
            return
        took = monotonic() - begin
        if took > self.options.command_timeout:
            self._fail(EXIT_TIMEOUT,
                       f'lockstep timeout: the plant is overrunning: one control period '
                       f'({self.sim.hold} steps) took {took:.3f} s > command_timeout='
                       f'{self.options.command_timeout:g} s at t={self.sim.t!r} s')
            return
        every = self.options.pace_to_subscribers
        if every and self.sim.samples % every == 0:
            self._keep_subscribers_up()
        self._await_command()

    def _keep_subscribers_up(self) -> None:
        """Lockstep with ``pace_to_subscribers``: wait until every subscriber of the samples
        has acknowledged them, so a subscriber slower than the loop (a recorder, whose keep-all
        readers stop acknowledging when their queue is full) paces the run instead of losing
        what falls out of the writer's queue. One that stays silent for _ACK_TIMEOUT (stalled)
        is left behind, with a warning."""
        for pub in (self.state_pub, self.force_pub):
            if not pub.wait_for_all_acked(Duration(seconds=_ACK_TIMEOUT)):
                self.get_logger().warning(
                    f'{pub.topic_name}: a subscriber acknowledged nothing for {_ACK_TIMEOUT:g} s'
                    f' at t={self.sim.t!r} s; continuing (it may lose samples)',
                    throttle_duration_sec=5.0)

    # -- real time ---------------------------------------------------------------------------
    def pacing_wait(self) -> float | None:
        """Seconds until the next real-time sample is due (<= 0: due now); None when no
        sample is paced (lockstep, not started, or ended). Called by the spin loop."""
        pacer = self.pacer
        if pacer is None or not self.running:
            return None
        return pacer.start + pacer.produced * pacer.period - monotonic()

    def publish_due(self) -> None:
        """Advance and publish the next real-time sample if it is due (the spin loop calls
        this when :meth:`pacing_wait` is <= 0)."""
        if self.running and self.pacer.due(monotonic()):
            self._advance()

    def _check_watchdog(self) -> None:
        if not self.running:
            return
        wd = self.options.watchdog_timeout
        if wd > 0.0 and not self._watchdog_warned and self._last_command_wall is not None:
            silent = time.monotonic() - self._last_command_wall
            if silent > wd:
                self._watchdog_warned = True
                df, dc = self.sim.command
                self.get_logger().warning(
                    f'watchdog: no command for {silent:.3f} s (watchdog_timeout={wd:g} s) at '
                    f't={self.sim.t:.6f} s; holding delta_f={df!r} rad, delta_c={dc!r} rad')

    # -- commands ----------------------------------------------------------------------------
    def _on_command_profiled(self, raw: bytes) -> None:
        t0 = perf_counter_ns()
        self._on_command(raw)
        self.profile.add(5, perf_counter_ns() - t0)

    def _on_command(self, raw: bytes) -> None:
        """A serialized ``command`` (the subscription is raw: see wire.py)."""
        if not self.running:
            return
        self.received += 1
        data = self._command_in.read(raw)
        self._last_command_t = t = answered_time(data)
        self._last_command_wall = monotonic()
        if self._watchdog_warned:
            self._watchdog_warned = False
            self.get_logger().info('watchdog: commands are arriving again')
        if self._lockstep:
            self._lockstep_command(data, t)
            return
        if t is not None:
            now = self.sim.t
            lag = now - t
            if not (0.0 <= lag <= self.options.max_command_age):
                self._stale(t, now)
                return
            if self._take(data) and lag > self._max_lag:
                self._max_lag = lag
        else:
            self._take(data)    # rejected: no finite t

    def _stale(self, t: float, now: float) -> None:
        """Reject a real-time command answering a time after the current sample or older
        than ``max_command_age``."""
        self.stale += 1
        if t > now:
            why = f"it answers t={t!r} s, after the plant's current sample t={now!r} s"
        else:
            why = (f'it answers t={t!r} s, {now - t:g} s of simulated time before the current '
                   f'sample: older than max_command_age={self.options.max_command_age:g} s')
        self._reject(f'stale command: {why}')

    def _take(self, data: Any) -> bool:
        """Hold the command in ``data`` if it is valid; else log and keep the last good one."""
        o = self.options
        try:
            _, df, dc = check_command(data, o.max_fin_deflection, o.max_cavitator_deflection)
        except CommandRejected as exc:
            self._reject(str(exc))
            return False
        self.sim.command = (df, dc)
        return True

    def _reject(self, reason: str) -> None:
        """Count and log a rejected command (the first 20 one by one, then at most one line a
        second); the last good command stays held."""
        self.rejected += 1
        df, dc = self.sim.command
        self._log_rejected(f'rejected command at t={self.sim.t!r} s: {reason}; keeping the last '
                           f'good command delta_f={df!r}, delta_c={dc!r} rad ({self.rejected} '
                           'rejected)')

    # -- reset -------------------------------------------------------------------------------
    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        if self.finished.done() or self._announced:
            response.success = False
            response.message = 'the run has ended'
            return response
        self.resets += 1
        self._samples_before += self.sim.samples
        self._steps_before += self.sim.plant.n
        self.sim.reset(self.options.initial_state)
        self._watchdog_warned = False
        self.get_logger().info(f'reset to t = 0 at {list(self.options.initial_state)}')
        if self.running:
            if self.pacer is not None:
                self.pacer.begin(time.monotonic())
            try:
                self._publish()
            except PublishFailed as exc:
                self._fail(EXIT_PUBLISH_FAILED, str(exc))
                response.success = False
                response.message = str(exc)
                return response
            if self.pacer is not None:
                self.pacer.published(time.monotonic())
            if self.options.mode == 'lockstep':
                self._await_command()
        response.success = True
        response.message = f't = {self.sim.t!r} s, state = {list(self.options.initial_state)}'
        return response

    # -- end ---------------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        """Figures of the run so far (also logged as one JSON line at the end)."""
        wall = time.monotonic() - self._run_wall_start if self.running else 0.0
        cpu = cpu_seconds() - self._cpu_start if self.running else 0.0
        # t, samples and steps count from the last /reset; the rates divide the whole run's
        # samples (samples_total) by the whole run's wall and CPU time
        total = self._samples_before + self.sim.samples
        steps = self._steps_before + self.sim.plant.n
        s: dict[str, Any] = {
            'mode': self.options.mode, 'model': self.model.model, 'solver': self.model.solver,
            'step': self.model.step, 'control_period': self.options.control_period,
            't': self.sim.t, 'samples': self.sim.samples,
            'steps': self.sim.plant.n, 'resets': self.resets, 'samples_total': total,
            'steps_total': steps, 'published_states': self.sent,
            'wall_time': wall, 'cpu_time': cpu,
            'cpu_per_sample_us': cpu / total * 1e6 if total else 0.0,
            'clock_samples': self._clock_every, 'view_samples': self._view_every,
            'views': self.views.published if self.views is not None else 0,
            'rejected_commands': self.rejected, 'ignored_commands': self.ignored,
            'publish_retries': self.publish_retries,
        }
        if self.profile is not None:
            s['profile'] = self.profile.summary()
        if self.pacer is not None:
            p = self.pacer
            s.update(real_time_factor=self.options.real_time_factor,
                     achieved_real_time_factor=(total * self.options.control_period / wall
                                                if wall > 0 else 0.0),
                     deadline_tolerance=p.tolerance,
                     deadline_misses=p.misses, samples_paced=p.produced,
                     deadline_miss_rate=p.misses / p.produced if p.produced else 0.0,
                     late_samples=p.late,
                     mean_lateness=p.lateness_sum / p.produced if p.produced else 0.0,
                     slips=p.slips, worst_lateness=p.worst_lateness,
                     max_command_lag=self._max_lag, stale_commands=self.stale)
        elif wall > 0:
            s.update(samples_per_second=total / wall, steps_per_second=steps / wall)
        return s

    def _end(self, code: int) -> None:
        if self.finished.done():
            return
        self.exit_code = code
        self.get_logger().info('summary: ' + json.dumps(self.summary()))
        self.running = False
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        self.finished.set_result(code)
        self.announce_end(f'exit code {code}', code)

    def announce_end(self, reason: str, code: int) -> None:
        """Publish :data:`~fohssv_sim.contract.RUN_END` once: the messages sent on each
        sample and view topic (not ``/clock``: keep-last 1 by design, a slow reader keeps the
        newest) and the commands received while running (a recorder hears the same
        controllers), so that a recorder can wait for them and report any it lost."""
        if self._announced:
            return
        self._announced = True
        published = {self.state_pub.topic_name: self.sent,
                     self.force_pub.topic_name: self.sent - self.forces_lost,
                     self.command_sub.topic_name: self.received}
        if self.views is not None:
            n = self.views.published
            for pub in self.views.publishers:
                published[pub.topic_name] = 2 * n if pub is self.views.marker_pub else n
        try:
            self.end_pub.publish(String(data=run_end_text(
                'plant', reason, code, self.sim.t, published)))
        except Exception as exc:  # noqa: BLE001 - the context is going down (a signal)
            final_log(self.get_name(), f'run_end not published: {exc}')

    def _finish(self, why: str) -> None:
        self.get_logger().info(f'stopping cleanly at t={self.sim.t!r} s: {why}')
        self._end(EXIT_OK)

    def _fail(self, code: int, message: str) -> None:
        self.get_logger().error(message)
        self._end(code)

    def flush(self, signals: int, timeout: float = 2.0) -> None:
        """Wait until subscribers acknowledged what was published (reliable topics): at most
        ``timeout`` s in all, and not after a signal beyond ``signals``."""
        deadline = time.monotonic() + timeout
        # run_end first: a recorder busy with a backlog must receive it before this writer
        # goes away (seen under load: the bag complete, the run_end never heard, exit 7)
        for pub in (self.end_pub, *self._sample_pubs):
            left = deadline - time.monotonic()
            if left <= 0 or STOP.count != signals:
                return
            if pub.get_subscription_count() > 0:
                pub.wait_for_all_acked(Duration(seconds=left))

    def linger(self, executor: Any, signals: int) -> None:
        """Keep the publishers (and services) up for ``end_linger`` s after the run ended, or
        until nothing subscribes to the samples (or views) any more: a reader drops what it has not
        taken yet from a writer that goes away, so a subscriber lagging behind a fast run
        would lose its tail when the plant exits. A signal after the run ended ends it
        (``STOP.count`` beyond ``signals``, the count when the run ended: a signal that
        interrupted the run does not, so a recorder still drains)."""
        deadline = time.monotonic() + self.options.end_linger
        samples = self._sample_pubs
        while (rclpy.ok() and STOP.count == signals and time.monotonic() < deadline
               and any(p.get_subscription_count() > 0 for p in samples)):
            executor.spin_once(timeout_sec=0.05)


def _interrupted(node: PlantNode) -> None:
    summary = json.dumps(node.summary())
    # the announced end is the end: nothing is stepped or published after it (the linger
    # spins the executor, and a lockstep command arriving then would advance the run)
    node.running = False
    node.pacer = None
    final_log(node.get_name(), f'interrupted; stopping cleanly. summary: {summary}')
    node.announce_end('interrupted', node.exit_code)


def _run(node: PlantNode) -> int:
    """Spin the plant until its run ends or a signal (logged as an interruption); then flush
    and linger; the node's exit code."""
    executor = make_executor()
    executor.add_node(node)
    if node.options.mode == 'realtime':
        tighten_timer_slack()
        refused = set_realtime_priority(node.options.realtime_priority)
        if refused:
            node.get_logger().warning(f'{refused}; running with the normal scheduler')
        with PausedCollector():
            spin_until(executor, node.finished, paced=node)
    else:
        spin_until(executor, node.finished, paced=node)
    code = node.exit_code
    signals = STOP.count          # a further signal ends the flush and the linger
    if STOP.received is not None and not node.finished.done():
        _interrupted(node)
    # a reader loses what it has not taken when the writer goes away: after a signal
    # too, the recorder gets the time to drain what was published (bounded waits)
    node.flush(signals)
    node.linger(executor, signals)
    return code


def _on_interrupt(node: PlantNode) -> int:
    if not node.finished.done():
        _interrupted(node)
    return node.exit_code


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run fohssv_sim plant``; exits with the node's exit code."""
    sys.exit(run_node('plant', args, PlantNode, _run, specs=PARAMETERS + NODE_PARAMETERS,
                      on_interrupt=_on_interrupt))


if __name__ == '__main__':
    main()
