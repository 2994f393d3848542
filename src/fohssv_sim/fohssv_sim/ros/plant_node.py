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
  warns once per outage when no command came for ``watchdog_timeout``. The lag of every
  command (control periods between the sample it answers and the current one) is measured;
  when it stays above ``max_command_lag`` the run stops (exit 6) naming the lag, the plant's
  cost per sample and the remedies.

Hosted controller (``controller:=NAME``, a plugin of group ``fohssv.controllers``): no
external controller; the plant runs the law itself after publishing each sample and holds
its output over the next control period (lockstep: as fast as the plant runs, in chunks
between which the executor is spun; realtime: paced as above). The law's parameters are
declared as ``controller.<name>`` with the controller node's descriptors; the run-time
changeable ones change here too. The plant publishes what the law commands on ``command``
(t = the answered sample), so recorders and viewers see an ordinary run; a second publisher
of ``command`` (an external controller) stops the plant (exit 7). The hosted law counts as
one of ``min_state_subscribers`` and as the command publisher.

Start: the plant publishes nothing (no sample, no ``/clock``) until ``min_command_publishers``
controllers and ``min_state_subscribers`` readers have matched; it logs what it still waits
for whenever that changes and every 5 s. ``start_timeout`` 0 (default) waits indefinitely, so
``ros2 run fohssv_sim plant`` and a controller started later in another terminal just work; a
positive ``start_timeout`` is for scripts: exit 4 when it expires, in both modes.

Exit codes: 0 clean stop (signal or ``duration`` reached), 1 state turned non-finite,
2 invalid parameters at start, 3 lockstep timeout or plant overrun, 4 peers missing when a
positive ``start_timeout`` expired, 5 another publisher of ``state`` (a second plant) on the
same ROS_DOMAIN_ID and namespace, 6 realtime: the commands of an external controller lagged
by more than ``max_command_lag`` control periods for as long, 7 a hosted controller and
another publisher of ``command`` (an external controller) on the same domain and namespace,
8 the in-plant bag (``record``) misses messages (its writer fell behind in real time, or
failed),
9 a sample could not be published (DDS refused it for a second: rclpy's ``RCLError``, seen
on a loaded machine; ``FOHSSV_FAULT_REFUSE_STATE``, :mod:`.faults`, injects it for tests): the
run ends there with its summary and a ``run_end`` listing what was published.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import sys
import time
from collections.abc import Mapping
from time import monotonic, sleep
from typing import Any

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from .. import control
from ..contract import CLOCK, COMMAND, PLANING_FORCE, RUN_END, STATE, run_end_text
from ..control import NonFiniteCommand
from ..models import MAX_PITCH, check_state
from ..params import PARAMETERS, ModelParameters, ParameterError, ParameterSpec, field_specs
from .faults import StateFault
from .inplant_record import EXIT_RECORD_LOST
from .inplant_record import start as start_recording
from .loop import (
    PREEMPTIBLE,
    BurstWait,
    CommandLag,
    CommandRejected,
    HostedLaw,
    Pacer,
    SampledPlant,
    answered_time,
    check_command,
    cpu_seconds,
    kernel_preemption,
)
from .matching import UNKNOWN_NODE, node_path
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
    hold_latency,
    install_validation,
    make_executor,
    pin_node,
    profile,
    refuse_unknown,
    run_node,
    set_realtime_priority,
    spin_until,
    tighten_timer_slack,
)
from .options import NODE_PARAMETERS, PlantOptions, check_options, clock_samples, view_samples
from .plant.fastpath import sample as compiled_sample
from .plant.instrumentation import Profile
from .views import ViewPublisher
from .wire import raw_publish

__all__ = ['PlantNode', 'main', 'EXIT_OK', 'EXIT_DIVERGED', 'EXIT_BAD_PARAMETERS',
           'EXIT_TIMEOUT', 'EXIT_NO_PEERS', 'EXIT_SECOND_PLANT', 'EXIT_COMMAND_LAG',
           'EXIT_SECOND_CONTROLLER', 'CONTROLLER_PREFIX', 'EXIT_RECORD_LOST',
           'EXIT_PUBLISH_FAILED']

EXIT_OK, EXIT_DIVERGED, EXIT_BAD_PARAMETERS, EXIT_TIMEOUT, EXIT_NO_PEERS = 0, 1, 2, 3, 4
#: Another publisher of ``state`` on the plant's domain and namespace (a second plant).
EXIT_SECOND_PLANT = 5
#: Realtime: an external controller's commands lagged beyond ``max_command_lag``.
EXIT_COMMAND_LAG = 6
#: A hosted controller and another publisher of ``command`` (two controllers would mix).
EXIT_SECOND_CONTROLLER = 7
#: The hosted controller's parameters are declared on the plant under this prefix.
CONTROLLER_PREFIX = 'controller.'
#: With a hosted controller: the wall time (s) one chunk of samples runs before the executor
#: is spun again (services, parameters, the graph checks, signals).
_CHUNK = 0.02
#: How long a plant whose minimum peers are there waits for the other listed subscribers of
#: its sample topics to match before it starts anyway (_listed_matched).
_LISTED_WAIT = 10.0
#: Lockstep with a hosted law: samples per compiled call (between looks at the clock).
_FREE_BURST = 32
#: Most samples of one burst (a realtime backlog beyond it is taken in several).
_BURST_ROWS = 64
#: Lockstep, commands taken in compiled code (:meth:`PlantNode.spin_taking`): the longest
#: wait for a command (s) before the executor's turn, and the executor's turn at least this
#: often while commands come (timers, services, parameters; one ``spin_once`` each, about
#: 18 us of CPU here); at most an eighth of ``command_timeout`` (whose check is a timer),
#: at least _TAKE_WAIT_MIN.
_TAKE_WAIT = 0.005
_TAKE_WAIT_MIN = 0.001
#: A sample DDS refused to take for :data:`_PUBLISH_RETRY` s (retried every millisecond).
EXIT_PUBLISH_FAILED = 9
_PUBLISH_RETRY = 1.0


class PublishFailed(Exception):
    """A sample that could not be published (after retries); ends the run with exit 9."""
#: Wall seconds between two looks at the graph for a second plant (a graph query, off the
#: per-sample path).
_RIVAL_CHECK_PERIOD = 0.5
#: Rival checks (of _RIVAL_CHECK_PERIOD) a rival publisher's node name is waited for before
#: the plant stops without it.
_NAME_WAIT = 10

_MODEL_NAMES = tuple(p.name for p in PARAMETERS)
_NODE_NAMES = tuple(p.name for p in NODE_PARAMETERS)
#: Lockstep with pace_to_subscribers: the wait for the acknowledgements (s) after which the
#: loop goes on while that cannot lose a sample ...
_ACK_TIMEOUT = 1.0
#: ... and the longest wait once going on could overrun the writer's queue (a stalled reader).
_STALL_TIMEOUT = 10.0
#: Lockstep: how long past ``command_timeout`` the plant waits for the awaited state to be
#: acknowledged by the subscribers of ``state`` (s). A controller whose reader the plant has
#: matched may not have matched the plant's writer yet (discovery is two one-sided halves;
#: under load the second came seconds later): its timeout counts from the delivery.
_DELIVERY_GRACE = 30.0
#: Lockstep: after the plant itself was not running (a timer check more than half of
#: ``command_timeout`` late: a stopped process, a stalled host), how long past
#: ``command_timeout`` the controller's command may take (s). A command published meanwhile
#: may have been dropped at the stopped process's shared-memory port (Fast DDS gives up on a
#: port whose listener does not answer within 1 s) and comes again only at the writer's next
#: heartbeat, every 3 s in Fast DDS: a CI run under load had a plant stopped for 1.5 s blame
#: its controller about 50 ms after it resumed.
_RESUME_GRACE = 5.0
#: After the run (and ``end_linger``): the longest wait for the readers of ``run_end`` (the
#: recorders, which leave once they took it) to leave (s).
_RUN_END_WAIT = 10.0
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
        self.hosted = self._host(values['controller'])   # the hosted law, or None
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
        self._lag = CommandLag(self.options.max_command_lag, self.options.control_period)
        self._free_run = self.hosted is not None and self.options.mode == 'lockstep'
        self._clock_every = clock_samples(self.options)
        self._lockstep = self.options.mode == 'lockstep'
        self.profile: Profile | None = Profile() if self.options.profile else None
        self._cpu_start = 0.0
        self.state_pub = self.create_publisher(Float64MultiArray, STATE.name, profile(STATE))
        self._all_acked: dict[str, int] = {}   # topic -> samples when all acknowledged
        self.force_pub = self.create_publisher(Float64MultiArray, PLANING_FORCE.name,
                                               profile(PLANING_FORCE))
        self.clock_pub = self.create_publisher(Clock, CLOCK.name, profile(CLOCK))
        self._send_state = raw_publish(self.state_pub)
        # a testing aid (faults.py), on every path a state leaves by: None unless asked for
        self._fault = StateFault.from_environment()
        if self._fault is not None:
            self._send_state = self._fault.wrap(self._send_state)
            for line in self._fault.warnings():
                self.get_logger().warning(line)
        self._send_force = raw_publish(self.force_pub)
        self._send_clock = raw_publish(self.clock_pub)
        # hosted: /clock and command (volatile) are published only while someone subscribes;
        # the counts are looked at between chunks of samples (_refresh_matched). *_on: made
        # at all (published, or with record:=PATH only put into the in-plant bag)
        self._clock_wanted = self._clock_on = True
        self._command_wanted = self._command_on = True
        # typed views for viewers, every view_period (views.py); None when off
        self._view_every = view_samples(self.options)
        self.views = ViewPublisher(
            self, self.model, spread=self._view_every >= ViewPublisher.MESSAGES
        ) if self._view_every else None
        # the writers whose readers (recorders, viewers) the start, flush and linger wait for
        self._sample_pubs = (self.state_pub, self.force_pub) + (
            self.views.publishers if self.views is not None else ())
        self.command_sub = self.command_pub = None
        # an external controller's commands (lockstep: the good command's short path)
        self._command_callback = (None if self.hosted is not None else
                                  self._on_command_lockstep if self._lockstep
                                  else self._on_command)
        if self.profile is not None:   # profile:=1 times the node's own calls
            self.profile.install(self)
        if self.hosted is None:      # an external controller node answers each sample
            self.command_sub = self.create_subscription(
                Float64MultiArray, COMMAND.name, self._command_callback, profile(COMMAND),
                raw=True)
            self.command_topic = self.command_sub.topic_name
        else:                        # the plant commands itself and says what it commanded
            self.command_pub = self.create_publisher(Float64MultiArray, COMMAND.name,
                                                     profile(COMMAND))
            self.command_topic = self.command_pub.topic_name
            self._command_out = ArrayWriter(COMMAND)
            self._command_data = self._command_out.values   # [t, delta_f, delta_c]
            self._send_command = raw_publish(self.command_pub)
            # its commands are the run's output like the samples: the start waits for their
            # listed readers, pace_to_subscribers for their acknowledgements, the linger too
            self._sample_pubs += (self.command_pub,)
        self._paced_pubs = (self.state_pub, self.force_pub) + (
            () if self.command_pub is None else (self.command_pub,))
        self.reset_srv = self.create_service(Trigger, 'reset', self._on_reset)
        # once, when the run ends: what was published, for recorders to check (contract.py)
        self.end_pub = self.create_publisher(String, RUN_END.name, profile(RUN_END))
        self.sent = 0                             # samples published (state, planing_force)
        self.received = 0                         # commands received while running
        self.commanded = 0                        # hosted: commands the law gave
        self.commands_sent = 0                    # hosted: of those, published (subscribed)
                                                  # or put into the in-plant bag
        self.law_failures = 0                     # hosted: samples the law gave no command
        self._announced = False                   # run_end published
        self.forces_lost = 0                      # planing_force samples not published
        self._cut: tuple[float, int] | None = None  # (t, steps) where a burst ended the run
        self.cpu_latency: int | None = None    # the cpu_dma_latency held (us), set by _run
        self.publish_retries = 0                  # publishes DDS refused at first
        self.resets = 0
        self._samples_before = 0                  # samples and steps before the last reset
        self._steps_before = 0
        self._log_rejected = LogLimiter(self.get_logger(), _LOG_EACH)
        self._log_law = LogLimiter(self.get_logger(), _LOG_EACH)   # hosted: no command
        self._log_retry = LogLimiter(self.get_logger(), 5, level='warning')
        # record:=PATH: the plant writes its own bag (inplant_record.py); None when off
        self.record = start_recording(self)
        # the state's publish call the compiled sample stands in for (publishing, and with
        # record:=PATH putting into the in-plant bag, as _send_state does; with fault
        # injection through the same faults); a call wrapped later (a bench's stamps) is not
        self._armable_send = self._send_state
        # lockstep with an external controller, the FOM compiled, no profile: the awaited
        # command's sample is published before the model's bookkeeping
        # (_on_command_lockstep); None: every sample takes the general path
        self._quick = (self.sim.held_period(self._state_data) if self._lockstep
                       and self.hosted is None and self.profile is None else None)
        # ... and that sample's check, kernel call, write and publish in one compiled call
        # (compiled_sample.py), armed for each awaited sample; None: the interpreted path
        self._compiled: compiled_sample.CompiledSample | None = None
        self._taking = False    # its commands taken in compiled code (take_commands)
        if self._quick is not None:
            built = compiled_sample.CompiledSample.build(
                self._quick, self._state_out, self._command_in, self.state_pub.handle.pointer,
                (self._force_out, self.force_pub.handle.pointer),
                (self._clock_out, self.clock_pub.handle.pointer),
                sink=None if self._fault is None else self._fault.sink)
            if isinstance(built, str):
                self.get_logger().info(f'lockstep: the interpreted sample path ({built})')
            else:
                self._compiled = built
                built.limit(self.options.max_fin_deflection,
                            self.options.max_cavitator_deflection)
                rec = self.record
                if rec is not None:     # its records too, as _send_state & co. put them
                    built.record_into(rec.ring, rec.index(self.state_pub.topic_name),
                                      rec.command_index, rec.index(self.force_pub.topic_name),
                                      rec.index(self.clock_pub.topic_name))

        self.running = False
        self.rejected = 0
        self.stale = 0                            # realtime: of those, stale or future
        self.ignored = 0
        self.bursts: BurstWait | None = None      # hosted realtime: see _start_run
        # hosted: the rows a burst of samples is computed into (SampledPlant.advance_burst)
        # and [max |delta_f|, max |delta_c|, max |w|, max |theta|] (set at each burst: the
        # options and the model may change at run time)
        self._rows = np.zeros((_BURST_ROWS, 7))
        self._limits = np.array([0.0, 0.0, self.model.speed, MAX_PITCH])
        self._awaiting: float | None = None       # lockstep: t of the state awaiting a command
        self._published_wall = 0.0                # lockstep: when that state went out
        self._undelivered: float | None = None    # lockstep: t of a state not yet acknowledged
        self._slow: tuple[int, float] | None = None  # lockstep: (samples, CPU s), slow period
        self._checked = 0.0                       # lockstep: when the timer last checked
        self._resumed = -math.inf                 # lockstep: when it last came late
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
        self._unnamed_checks = 0
        self._rival_timer = self.create_timer(_RIVAL_CHECK_PERIOD, self._check_rivals)
        self.get_logger().info(
            f'{self.sim.plant.describe()} (ready in {self.sim.compile_seconds:.2f} s); mode '
            f'{self.options.mode}, control period '
            f'{self.options.control_period:g} s = {hold} steps (zero-order hold), duration '
            f'{self.options.duration:g} s; controller '
            + ('external (a node publishing command)' if self.hosted is None
               else self.hosted.describe()))

    # -- hosted controller (parameter ``controller``) ------------------------------------------
    def _host(self, name: str) -> HostedLaw | None:
        """The plugin ``name`` hosted in the loop, its parameters declared under
        :data:`CONTROLLER_PREFIX` from its table (the controller node's descriptors, ranges,
        units; the run-time changeable ones change here too); None for '' (external).

        Raises:
            control.UnknownController: no such plugin (the message lists the valid ones).
            ParameterError: an invalid value of one of its parameters.
        """
        if not name:
            return None
        self._controller_cls = control.load(name)
        specs: tuple[ParameterSpec, ...] = tuple(
            dataclasses.replace(spec, name=CONTROLLER_PREFIX + spec.name)
            for spec in field_specs(self._controller_cls.Parameters))
        law = HostedLaw(self._build_controller(declare(self, specs)))
        install_validation(self, tuple(s.name for s in specs), self._build_controller,
                           self._apply_controller)
        return law

    def _build_controller(self, values: Mapping[str, Any]) -> control.Controller:
        cls = self._controller_cls
        n = len(CONTROLLER_PREFIX)
        fields = {k[n:]: v for k, v in values.items() if k.startswith(CONTROLLER_PREFIX)}
        try:
            return cls(cls.Parameters(**fields))
        except ParameterError as exc:   # the dataclass names the field without the prefix
            text = str(exc)
            if any(text.startswith(f'{f}=') for f in fields):
                text = CONTROLLER_PREFIX + text
            raise ParameterError(text) from None

    def _apply_controller(self, controller: control.Controller) -> None:
        self.hosted = HostedLaw(controller)
        self.get_logger().info(f'controller parameters changed: {controller.describe()}')

    # -- parameters ------------------------------------------------------------------------
    def _apply(self, config: tuple[ModelParameters, PlantOptions, int]) -> None:
        _, options, _ = config
        self.options = options
        self._lag.limit = options.max_command_lag
        if self._compiled is not None:    # the awaited command's too
            self._compiled.limit(options.max_fin_deflection, options.max_cavitator_deflection)
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
        """Matched (state subscribers, command publishers); a hosted law counts as one of
        each (it reads every sample and commands), so the same minimums start a hosted plant
        alone and a hosted plant with a recorder."""
        subs = self.state_pub.get_subscription_count()
        if self.hosted is not None:
            return subs + 1, 1
        return subs, self.command_sub.get_publisher_count()

    def _views_matched(self) -> int:
        """The fewest matched subscribers of any typed view (a large number with views off:
        nothing to wait for)."""
        if self.views is None:
            return 1 << 30
        return min(p.get_subscription_count() for p in self.views.publishers)

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
                     'matched)' for pub in self._sample_pubs + (self.clock_pub,)
                     if pub.get_subscription_count() < (listed := self.count_subscribers(
                         pub.topic_name))]
        if not unmatched:
            return True
        if time.monotonic() - self._minimums_since > _LISTED_WAIT:
            self.get_logger().warning(
                f'starting although not every listed subscriber matched after '
                f'{_LISTED_WAIT:g} s: {", ".join(unmatched)}; those readers may miss the '
                'first samples (incompatible QoS?)')
            return True
        return False

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
        views = self._views_matched()
        if views < o.min_view_subscribers:
            missing.append(f'{o.min_view_subscribers - views} more subscriber(s) of each view '
                           '(a viewer)')
        what = ' and '.join(missing) or 'the listed subscribers to match'
        return (f'waiting for {what}: command has {pubs}/{o.min_command_publishers} '
                f'publisher(s), {self.state_pub.topic_name} has {subs}/'
                f'{o.min_state_subscribers} subscriber(s)')

    def _check_rivals(self) -> None:
        """Refuse to run beside another publisher of ``state`` (a second plant, a republishing
        player): the two would take each other's commands and publish interleaved samples.
        With a hosted controller, also beside another publisher of ``command``."""
        if self.hosted is not None:
            self._check_second_controller()
        if self.finished.done() or self.count_publishers(self.state_pub.topic_name) <= 1:
            return                                # only this plant's own publisher
        nodes = self._publisher_nodes(self.state_pub.topic_name)
        if nodes is None:
            return
        self._fail(EXIT_SECOND_PLANT,
                   f'{len(nodes)} publishers of {self.state_pub.topic_name} (nodes: '
                   f"{', '.join(nodes)}): another plant (or a republishing player) runs on this "
                   'ROS_DOMAIN_ID and namespace, and the two would take each other\'s commands; '
                   'stopping. Give each its own ROS_DOMAIN_ID or namespace.')

    def _check_second_controller(self) -> None:
        """A hosted plant and an external publisher of ``command`` (a controller node, a
        player replaying commands): two controllers must never mix, so the plant stops."""
        topic = self.command_topic
        if self.finished.done() or self.count_publishers(topic) <= 1:
            return                                # only the plant's own command publisher
        nodes = self._publisher_nodes(topic)
        if nodes is None:
            return
        self._fail(EXIT_SECOND_CONTROLLER,
                   f'{len(nodes)} publishers of {topic} (nodes: {", ".join(nodes)}): this '
                   f'plant hosts the controller {self.hosted.name!r} (controller:='
                   f'{self.options.controller}) and another node publishes commands too; two '
                   'controllers must not mix, stopping. Stop the external controller, or start '
                   "the plant with controller:='' to use it.")

    def _publisher_nodes(self, topic: str) -> list[str] | None:
        """The nodes publishing ``topic``, sorted, for the one line that stops the plant; None
        while a publisher's node is not named yet (DDS discovers an endpoint before its
        node's name: the line said ``_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_``) and the
        name has been waited for less than :data:`_NAME_WAIT` rival checks; after that the
        stop goes ahead, naming the node as not yet known."""
        infos = self.get_publishers_info_by_topic(topic)
        unnamed = sum(i.node_name == UNKNOWN_NODE for i in infos)
        if unnamed and self._unnamed_checks < _NAME_WAIT:
            self._unnamed_checks += 1
            return None
        return sorted('(a node whose name is not discovered yet)' if i.node_name == UNKNOWN_NODE
                      else node_path(i) for i in infos)

    def _wait_for_peers(self) -> None:
        if self.running or self.finished.done():
            return    # a timer event queued before _start destroyed the timer: start once
        subs, pubs = self._peers()
        o = self.options
        if (subs >= o.min_state_subscribers and pubs >= o.min_command_publishers
                and self._views_matched() >= o.min_view_subscribers):
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
        try:
            self._start_run()
        except PublishFailed as exc:
            self._fail(EXIT_PUBLISH_FAILED, str(exc))

    def _start_run(self) -> None:
        subs, pubs = self._peers()
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
            self._checked = monotonic()
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
                self._timer = self.create_timer(_WATCHDOG_CHECK, self._check_watchdog)
            else:
                self._control()

    # -- publishing (every sample: preallocated messages written in place) --------------------
    def _publish(self) -> None:
        self.sent += 1
        self.sim.write_sample(self._state_data, self._force_data)
        self._send_sample(self.sim.samples)

    def _send_sample(self, sample: int) -> None:
        """Publish sample number ``sample``, written into the state and force messages: state,
        planing_force, /clock and the views when due."""
        # a failed publish (rclpy's RCLError 'Failed to publish' under load) is retried,
        # and ends the run with exit 9 (summary, run_end) if DDS keeps refusing it
        # (each payload made once: a retry sends the same bytes)
        payload = self._state_out.payload()
        try:
            self._send_state(payload)
        except Exception as exc:  # noqa: BLE001 - RCLError is not exported by rclpy
            self._retry_publish(self._send_state, self.state_pub.topic_name, payload, exc,
                                state=True)
        self._send_rest(sample)

    def _send_rest(self, sample: int) -> None:
        """What :meth:`_send_sample` publishes after the state: planing_force, /clock and
        the views when due."""
        payload = self._force_out.payload()
        try:
            self._send_force(payload)
        except Exception as exc:  # noqa: BLE001
            self._retry_publish(self._send_force, self.force_pub.topic_name, payload, exc)
        self._send_after_force(sample)

    def _send_after_force(self, sample: int) -> None:
        """What :meth:`_send_rest` publishes after the planing force: /clock and the views
        when due."""
        if self._clock_on and sample % self._clock_every == 0:
            try:
                self._send_clock(self._clock_out.payload(round(self._state_data[0] * 1e9)))
            except Exception as exc:  # noqa: BLE001 - keep-last 1: the next one replaces it
                self._log_retry(f'/clock at t={self._state_data[0]!r} s not published: {exc}')
        self._send_views(sample)

    def _send_views(self, sample: int) -> None:
        """The views' messages of ``sample``, when due (one per sample: views.py)."""
        views = self.views
        if views is not None:     # a view's messages go out one per sample (views.py)
            try:
                if sample % self._view_every == 0:
                    views.publish(self._state_data, self._force_data[1])
                elif views.pending:
                    views.publish_next()
            except Exception as exc:  # noqa: BLE001 - views are for people: never fatal
                self._log_retry(f'views at t={self._state_data[0]!r} s not published: {exc}')

    def _retry_publish(self, send: Any, name: str, payload: Any, exc: Exception,
                       state: bool = False) -> None:
        """Publish again every millisecond for up to :data:`_PUBLISH_RETRY` s (counted, the
        first lines logged); raise :class:`PublishFailed` if DDS still refuses."""
        self.publish_retries += 1
        self._log_retry(f'{name}: publishing the sample at t={self._state_data[0]!r} '
                        f'failed ({exc}); retrying ({self.publish_retries} retried)')
        deadline = monotonic() + _PUBLISH_RETRY
        while monotonic() < deadline and rclpy.ok():
            time.sleep(0.001)
            try:
                send(payload)
                self._checked = monotonic()   # that wait was the plant's own (see _next)
                return
            except Exception as again:  # noqa: BLE001
                exc = again
        if state:
            self.sent -= 1   # the state of this sample never went out, nor (not counted in
                             # sent) its planing_force, which is not published after it
        else:
            self.forces_lost += 1              # the state went out, its planing_force not
        raise PublishFailed(f'{name}: the sample at t={self._state_data[0]!r} s '
                            f'could not be published for {_PUBLISH_RETRY:g} s ({exc}); '
                            'stopping the run')

    def _step(self) -> None:
        self.sim.advance()

    def _advance(self) -> bool:
        """One control period and its sample (and with a hosted law, its command); False when
        the run ended."""
        try:
            self._step()
        except FloatingPointError as exc:
            self._diverged(exc)
            return False
        try:
            self._publish()
        except PublishFailed as exc:
            self._fail(EXIT_PUBLISH_FAILED, str(exc))
            return False
        return self._published()

    def _published(self) -> bool:
        """After a sample went out: the real-time schedule, the run's end, a hosted law's
        command; False when the run ended."""
        if self.pacer is not None:
            self.pacer.published(monotonic())
        if self.sim.reached(self.options.duration):
            self._finish(f'duration {self.options.duration:g} s reached')
            return False
        if self.hosted is not None:
            self._control()
        return True

    def _diverged(self, exc: Exception) -> None:
        """End the run: the state turned non-finite or left the physical bounds."""
        self._fail(EXIT_DIVERGED, f'simulation failed: {exc}{self._lag_note()}')

    def _advance_burst(self, periods: int) -> bool:
        """Hosted affine law: up to ``periods`` samples (and their commands) in one compiled
        call, then each published as :meth:`_advance` and :meth:`_control` would, in order:
        the same numbers, messages and counts, one Python call into the kernel instead of one
        per sample. Plugins that are not affine, the interpreted engine and ``profile:=1`` take
        the per-sample path. False when the run ended."""
        sim = self.sim
        law = self.hosted.law
        if law is None or self.profile is not None:
            return self._advance_each(periods)
        o = self.options
        periods = min(periods, sim.samples_until(o.duration), len(self._rows))
        every = o.pace_to_subscribers if self.pacer is None else 0
        if every:
            periods = min(periods, every - sim.samples % every)
        limits = self._limits
        limits[0], limits[1] = o.max_fin_deflection, o.max_cavitator_deflection
        limits[2] = self.model.speed
        plant = sim.plant
        n0 = plant.n
        try:
            done, status = sim.advance_burst(law, periods, limits, self._rows)
        except FloatingPointError as exc:    # raised by the SOE history's own checks
            self._diverged(exc)
            return False
        if status < 0:                       # no compiled kernel
            return self._advance_each(periods)
        # Python floats (one conversion for the burst, not a numpy scalar per value)
        rows, hold, h = self._rows[:done].tolist(), sim.hold, plant.h
        state, force, pacer = self._state_data, self._force_data, self.pacer
        end = o.duration - 1e-9 * o.control_period if o.duration > 0.0 else math.inf
        last = done - 1
        for j in range(done):
            row = rows[j]
            if j == last and status == 2:   # outside the physical bounds: as advance() raises
                sim.samples += 1
                try:
                    check_state(plant)
                except FloatingPointError as exc:
                    self._diverged(exc)
                return False
            t = (n0 + (j + 1) * hold) * h
            state[0] = force[0] = t
            state[1], state[2], state[3], state[4] = row[0], row[1], row[2], row[3]
            force[1] = row[4]
            self.sent += 1
            try:
                self._send_sample(sim.samples + 1)
            except PublishFailed as exc:
                sim.samples += 1
                # the kernel computed the burst's later samples too: the run ended here
                self._cut = (t, n0 + (j + 1) * hold)
                self._fail(EXIT_PUBLISH_FAILED, str(exc))
                return False
            if pacer is not None:
                pacer.published(monotonic())
            if t >= end:
                sim.samples += 1
                self._finish(f'duration {o.duration:g} s reached')
                return False
            if j == last and status == 3:   # the law's command needs the slow path
                sim.samples += 1
                self._control()
                break
            df, dc = row[5], row[6]
            sim.took((df, dc))
            self._publish_command(t, df, dc)
        if status == 1:                      # the next period turned non-finite
            try:
                plant.raise_failure()
            except FloatingPointError as exc:
                self._diverged(exc)
            return False
        if every and sim.samples % every == 0:
            self._keep_subscribers_up()
        return True

    def _advance_each(self, periods: int) -> bool:
        """``periods`` samples one at a time (:meth:`_advance`); False when the run ended."""
        every = self.options.pace_to_subscribers if self.pacer is None else 0
        for _ in range(periods):
            if not self._advance():
                return False
            if every and self.sim.samples % every == 0:
                self._keep_subscribers_up()
        return True

    # -- hosted controller: the law in the loop, every sample --------------------------------
    def _control(self) -> None:
        """The hosted law's command for the sample just published: published on ``command``
        (t = that sample, as a controller node answers) and held over the next control period
        if within the deflection limits (else rejected, as the plant rejects an external
        one). A non-finite output or a failing plugin gives no command: the last good one
        stays held, and it is counted and logged."""
        sim = self.sim
        t = sim.plant.t
        try:
            df, dc = self.hosted.command(t, sim.plant.x)
        except Exception as exc:  # noqa: BLE001 - a plugin's bug must not kill the plant
            self._law_failed(t, exc)
            return
        self._publish_command(t, df, dc)
        o = self.options
        if abs(df) <= o.max_fin_deflection and abs(dc) <= o.max_cavitator_deflection:
            sim.command = (df, dc)
        else:
            self._take((t, df, dc))   # rejects it with the reason; the last good one stays

    def _publish_command(self, t: float, df: float, dc: float) -> None:
        """Publish what the hosted law commanded for the sample at ``t``."""
        self.commanded += 1
        if self._command_on:
            data = self._command_data
            data[0] = t
            data[1] = df
            data[2] = dc
            self._send_command(self._command_out.payload())
            self.commands_sent += 1

    def _law_failed(self, t: float, exc: Exception) -> None:
        self.law_failures += 1
        what = (str(exc) if isinstance(exc, NonFiniteCommand) else
                f'{self.hosted.name}.command(t={t!r}) raised {type(exc).__name__}: {exc}')
        df, dc = self.sim.command
        text = (f'{what}; no command for this sample, holding delta_f={df!r}, delta_c={dc!r} '
                f'rad ({self.law_failures} without a command)')
        self._log_law(text)

    # -- lockstep ----------------------------------------------------------------------------
    def _await_command(self) -> None:
        self._awaiting = t = self.sim.t
        self._published_wall = time.monotonic()
        compiled = self._compiled
        if compiled is not None:
            if self.running and self._send_state is self._armable_send:
                # (not armed when the model's kernel call is not bound yet: the first sample
                # and the first after a reset take the interpreted path, which binds it)
                clock = 0
                if self._clock_on and (self.sim.samples + 1) % self._clock_every == 0:
                    clock = ((compiled_sample.CLOCK_PUBLISH if self._clock_wanted else 0)
                             | (compiled_sample.CLOCK_PUT if self.record is not None else 0))
                compiled.arm(t, clock)
            else:
                compiled.disarm()

    def _check_lockstep_timeout(self) -> None:
        if not self.running:
            return
        self._refresh_matched()
        now = monotonic()
        late, self._checked = now - self._checked, now
        timeout = self.options.command_timeout
        waited = now - self._published_wall
        # (at least two periods of this timer, whose period command_timeout set at the start:
        # lowered during the run, it would otherwise take every check for a stopped plant)
        if late > max(timeout / 2, 2e-9 * self._timer.timer_period_ns):
            # this check (every command_timeout / 4 at most) came that late: the plant itself
            # was not running (a stalled host, a stopped process); a command that came
            # meanwhile may be waiting behind this timer, or lost on the way and sent again
            # at its writer's next heartbeat: the controller gets _RESUME_GRACE more (also
            # when the wait is not over yet: a 3 s stop with the default 5 s timeout)
            self._resumed = now
            if self._awaiting is not None and waited > timeout:
                self.get_logger().info(
                    f'lockstep: the plant did not run for {late:.3f} s (a stopped process or '
                    f'a stalled host) while awaiting the command for t={self._awaiting!r} s: '
                    f'its controller gets command_timeout + {_RESUME_GRACE:g} s from now (a '
                    'command lost meanwhile comes again at its writer\'s next heartbeat)')
            return
        if self._awaiting is None or waited <= timeout:
            return
        if now - self._resumed <= timeout + _RESUME_GRACE:
            return
        if not self.state_pub.wait_for_all_acked(Duration(seconds=0)):
            # not the controller's delay: a subscriber has not got the state yet
            if waited <= self.options.command_timeout + _DELIVERY_GRACE:
                if self._undelivered != self._awaiting:
                    self._undelivered = self._awaiting
                    self.get_logger().info(
                        f'the state for t={self._awaiting!r} s is not acknowledged by all '
                        f'{self.state_pub.get_subscription_count()} subscriber(s) of '
                        f'{self.state_pub.topic_name} after {waited:.1f} s (discovery not '
                        'finished on their side?): command_timeout counts from its delivery')
                return
            self._fail(EXIT_TIMEOUT,
                       f'lockstep timeout: the state for t={self._awaiting!r} s was not '
                       f'acknowledged by the subscribers of {self.state_pub.topic_name} within '
                       f'{waited:.1f} s (command_timeout={self.options.command_timeout:g} s + '
                       f'{_DELIVERY_GRACE:g} s for delivery; command has {self._peers()[1]} '
                       'publisher(s))')
            return
        if self._undelivered == self._awaiting:
            # delivered since the last check: the controller has its full timeout from now
            self._undelivered = None
            self._published_wall = now
            return
        last = ('no command received at all' if self._last_command_t is None else
                f'the last command answered t={self._last_command_t!r} s')
        self._fail(EXIT_TIMEOUT,
                   f'lockstep timeout: the controller stalled: no command answering '
                   f't={self._awaiting!r} s within command_timeout='
                   f'{self.options.command_timeout:g} s ({last}; command has '
                   f'{self._peers()[1]} publisher(s))')

    def _lockstep_command(self, data: Any, t: float | None) -> None:
        if self._awaiting is None or t != self._awaiting:
            self.ignored += 1
            self.get_logger().warning(
                f'ignored a command for t={t!r} s while waiting for t={self._awaiting!r} s '
                f'({self.ignored} ignored so far)', throttle_duration_sec=1.0)
            return
        self._take(data)
        self._awaiting = None
        self._stepped(monotonic())

    def _stepped(self, begin: float) -> None:
        """Lockstep: the awaited command was taken at ``begin`` (monotonic s): advance,
        publish, and await the next one."""
        if self._advance():
            self._next(begin)

    def _next(self, begin: float) -> None:
        """Lockstep: the period whose command was taken at ``begin`` is published: check
        for an overrun, pace to slow subscribers when asked, await the next command."""
        took = monotonic() - begin
        if took > self.options.command_timeout and self._overrunning(took):
            return
        every = self.options.pace_to_subscribers
        if every and self.sim.samples % every == 0:
            self._keep_subscribers_up()
            # that wait (up to _STALL_TIMEOUT, blocking the timer) was the plant's own: the
            # next lockstep check must not take the plant for stopped and grant the resume
            # grace (which hid a stopped controller's undelivered state for 5 s)
            self._checked = monotonic()
        self._await_command()

    def _overrunning(self, took: float) -> bool:
        """A control period took ``took`` s of wall time, more than ``command_timeout``:
        the plant's own work, or a wait outside it (a publish that DDS blocked: Fast DDS
        spends up to 1 s checking the shared-memory port of a stopped subscriber's process; a
        host that did not run the plant). The first such period is logged and its end marks
        the process's CPU time; when the very next period is too long as well, the plant is
        overrunning (exit 3) if it used more CPU than ``command_timeout`` since the mark
        (one period's work and the wait for its command). Nothing is added to a period that
        is not too long."""
        cpu = time.process_time()
        n = self.sim.samples
        mark, self._slow = self._slow, (n, cpu)
        timeout = self.options.command_timeout
        if mark is not None and mark[0] == n - 1 and cpu - mark[1] > timeout:
            self._fail(EXIT_TIMEOUT,
                       f'lockstep timeout: the plant is overrunning: one control period '
                       f'({self.sim.hold} steps) took {took:.3f} s > command_timeout='
                       f'{timeout:g} s at t={self.sim.t!r} s, using {cpu - mark[1]:.3f} s of '
                       'CPU with the wait for its command (the one before took too long '
                       'as well)')
            return True
        self.get_logger().warning(
            f'one control period ({self.sim.hold} steps) took {took:.3f} s > command_timeout='
            f'{timeout:g} s of wall time at t={self.sim.t!r} s: not an overrun unless the '
            'next one takes as long in CPU time (a publish blocked by DDS, e.g. for a stopped '
            'subscriber, or a stalled host)')
        return False

    def _keep_subscribers_up(self) -> None:
        """Lockstep with ``pace_to_subscribers``: wait until every subscriber of the samples
        has acknowledged them, so a subscriber slower than the loop (a recorder, whose keep-all
        readers stop acknowledging when their queue is full) paces the run instead of losing
        what falls out of the writer's queue. After _ACK_TIMEOUT the loop goes on only while
        that cannot lose a sample: the samples since the subscriber last acknowledged
        everything, plus those until the next wait, still fit the writer's queue. Otherwise it
        waits on, up to _STALL_TIMEOUT; a subscriber silent that long (stalled) is left
        behind with a warning, and from then on waited for only _ACK_TIMEOUT until it
        catches up."""
        n = self.sim.samples
        every = self.options.pace_to_subscribers
        for pub in self._paced_pubs:
            topic = pub.topic_name
            if pub.wait_for_all_acked(Duration(seconds=_ACK_TIMEOUT)):
                self._all_acked[topic] = n
                continue
            behind = n - self._all_acked.get(topic, 0)
            if behind + every <= pub.qos_profile.depth or self._all_acked.get(topic) == -1:
                continue       # nothing can be lost before the next wait (or stalled before)
            if pub.wait_for_all_acked(Duration(seconds=_STALL_TIMEOUT - _ACK_TIMEOUT)):
                self._all_acked[topic] = n
                continue
            self._all_acked[topic] = -1
            self.get_logger().warning(
                f'{topic}: a subscriber has not acknowledged up to {behind} samples for '
                f'{_STALL_TIMEOUT:g} s at t={self.sim.t!r} s (the queue holds '
                f'{pub.qos_profile.depth}); continuing (it may lose samples)')

    # -- real time ---------------------------------------------------------------------------
    def pacing_wait(self) -> float | None:
        """Seconds until the next real-time sample is due (<= 0: due now); None when no
        sample is paced (lockstep, not started, or ended). Called by the spin loop. Lockstep
        with a hosted law: always due while running (the loop runs as fast as it can)."""
        if self.hosted is not None:
            return 0.0 if self.running else None
        pacer = self.pacer
        if pacer is None or not self.running:
            return None
        return pacer.start + pacer.produced * pacer.period - monotonic()

    def publish_due(self) -> None:
        """Advance and publish the next real-time sample if it is due (the spin loop calls
        this when :meth:`pacing_wait` is <= 0). Lockstep with a hosted law: a chunk of
        samples, at most ``_FREE_RUN_CHUNK`` of wall time, then the executor's turn."""
        if not self.running:
            return
        if self.hosted is not None:
            self._run_chunk()
        elif self.pacer.due(monotonic()):
            self._advance()

    def _run_chunk(self) -> None:
        """Hosted: samples for ``_CHUNK`` s of wall time, then the executor's turn (services,
        parameters, the graph checks; a signal ends the loop there). Lockstep: back to back;
        realtime: each when due, sleeping in between: ``time.sleep`` costs about half the
        CPU of a ``spin_once`` wait, and nothing is to be taken between samples."""
        self._refresh_matched()
        now = monotonic()
        end = now + _CHUNK
        pacer, bursts = self.pacer, self.bursts
        while now < end:
            if pacer is None:
                due = _FREE_BURST
            else:
                first = pacer.next_due()
                wake = first + bursts.wait()
                if now < wake:  # asleep until a whole burst is due (one wake-up per burst)
                    sleep(wake - now)
                    now = monotonic()
                    bursts.observe(now - first, now)
                due = pacer.due(now)
            if not self._advance_burst(due):
                return
            now = monotonic()

    def _refresh_matched(self) -> None:
        """Whether anyone subscribes to ``/clock`` (and, hosted, to ``command``): a volatile
        topic nobody reads is not published (a reader that is not there gets nothing either
        way; 4-10 us of CPU per sample saved, on the lockstep round trip too; a reader
        that matches during a run gets /clock from the next look). Looked at
        between chunks of samples (hosted) or in the timer's checks (external controller:
        every 10 ms in real time, every ``min(0.05 s, command_timeout / 4)`` in lockstep),
        never per sample; at the start the plant waits for the listed ``/clock`` readers to
        match (:meth:`_listed_matched`). With ``record`` both are still made and put into
        the in-plant bag, which holds them all (inplant_record.py publishes them only while
        wanted)."""
        recording = self.record is not None
        self._clock_wanted = self.clock_pub.get_subscription_count() > 0
        self._clock_on = self._clock_wanted or recording
        if self.command_pub is not None:
            self._command_wanted = self.command_pub.get_subscription_count() > 0
            self._command_on = self._command_wanted or recording

    def _check_watchdog(self) -> None:
        if not self.running:
            return
        self._refresh_matched()
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
    def _on_command_lockstep(self, raw: bytes) -> None:
        """Lockstep, external controller (the subscription's callback): the good command,
        the one answering the awaited sample with deflections within their limits, is taken
        with the fewest steps before the next state goes out (the round trip waits for it):
        comparisons inline instead of :meth:`_on_command`'s, :meth:`_lockstep_command`'s and
        :meth:`_take`'s calls (the watchdog's flag, real time only, is not looked at). Any
        other command goes through :meth:`_on_command` (its checks, logs and counts). Armed
        for the awaited sample (by :meth:`_await_command`; it disarms itself when it takes
        the command, :meth:`_took` when the interpreted path does, and is not called once the
        run is over), the compiled sample (compiled_sample.py) takes the good command first
        and publishes its state before any of this runs."""
        compiled = self._compiled
        if compiled is not None and self.running:
            code = compiled.call(raw, len(raw))
            if code != compiled_sample.NOT_TAKEN:
                self._compiled_took(raw, code)
                return
        self._lockstep_interpreted(raw)

    def _lockstep_interpreted(self, raw: bytes) -> None:
        """:meth:`_on_command_lockstep` for a command the compiled sample did not take (or
        where there is none): the short path's inline checks, else :meth:`_on_command`."""
        data = self._command_in.read(raw)
        if len(data) == 3 and self.running:
            t, df, dc = data
            o = self.options
            if (t == self._awaiting and abs(df) <= o.max_fin_deflection
                    and abs(dc) <= o.max_cavitator_deflection):
                begin = monotonic()
                self.sim.command = (df, dc)
                quick = self._quick
                if quick is not None:
                    try:
                        if quick.run(df, dc):
                            self._quick_sample(raw, t, begin)
                            return
                    except FloatingPointError as exc:
                        self.sim.failed_period(exc)
                        self._took(raw, t, begin)
                        self._diverged(exc)
                        return
                self._took(raw, t, begin)
                self._stepped(begin)
                return
        self._on_command(raw)

    def take_commands(self) -> bool:
        """Lockstep with the compiled sample: take the commands in compiled code
        (:meth:`CompiledSample.take_from <fohssv_sim.ros.compiled_sample.CompiledSample.take_from>`)
        and spin with :meth:`spin_taking`; False (one line says why, unless the compiled
        sample is off or its publish call is wrapped: the executor's callback then) when
        not."""
        compiled = self._compiled
        if compiled is None or self._send_state is not self._armable_send:
            return False
        why = compiled.take_from(self.context.handle.pointer, self.command_sub.handle.pointer,
                                 0.0)
        if why is not None:
            self.get_logger().info(f'lockstep: commands taken by the executor ({why})')
            return False
        self._taking = True
        return True

    def spin_taking(self, executor: Any) -> None:
        """Lockstep, commands taken in compiled code (:meth:`take_commands`): until the run
        has finished, a signal came or the context shut down, wait for the next command and
        take it with rcl, the compiled sample taking the awaited one (its state published
        before any Python runs); the node's Python then finishes the sample
        (:meth:`_compiled_took`) or, for a command the compiled sample left, runs the
        interpreted checks on its bytes (:meth:`_lockstep_interpreted`, as the
        subscription's callback does after the compiled sample). The executor gets its turn (one
        ``spin_once``: timers, services, parameters) at least every :data:`_TAKE_WAIT` s
        (an eighth of ``command_timeout`` if less) and after every wait that long that
        brought nothing; before the run, the executor waits (at most :data:`_TAKE_WAIT` s)
        and the commands are taken after it without waiting. The subscription's
        new-message callback (the event executor's) is unset first and again after each
        turn."""
        compiled = self._compiled
        received, took = compiled.received, self._compiled_took
        left = self._lockstep_interpreted    # the compiled sample looked at it already
        stop, finished, spin_once = STOP, self.finished, executor.spin_once
        not_taken, timed_out = compiled_sample.NOT_TAKEN, compiled_sample.TIMED_OUT
        rcl_error, woken = compiled_sample.RCL_ERROR, compiled_sample.WOKEN
        tighten_timer_slack()         # a spin_once with no wait: 18 us of CPU, not 75 us
        compiled.detach_listener()
        running_was = None
        next_service = wait = 0.0
        while stop.received is None and not finished.done():
            running = self.running
            if running is not running_was:
                wait = self._take_wait()
                compiled.set_timeout(wait if running else 0.0)
                running_was = running
            if not running:
                compiled.disarm()
                if not rclpy.ok():
                    return
                spin_once(timeout_sec=_TAKE_WAIT)
                compiled.detach_listener()
            code = compiled.take()
            if code == not_taken:
                left(received())
            elif code == timed_out:
                next_service = 0.0
            elif code == woken:
                pass
            elif code == rcl_error:
                raise RuntimeError(f'rcl could not wait for or take a command (returned '
                                   f'{compiled.take_ret}: {compiled.take_error()})')
            else:
                took(received(), code)
            if running:
                now = monotonic()
                if now >= next_service:
                    if not rclpy.ok():
                        return
                    spin_once(timeout_sec=0.0)
                    compiled.detach_listener()
                    if wait != (wait := self._take_wait()):   # command_timeout changed
                        compiled.set_timeout(wait)
                    next_service = now + wait

    def _take_wait(self) -> float:
        """:meth:`spin_taking`'s longest wait for a command and its executor cadence (s)."""
        return max(_TAKE_WAIT_MIN, min(_TAKE_WAIT, self.options.command_timeout / 8))

    def _compiled_took(self, raw: bytes, code: int) -> None:
        """Lockstep: the compiled sample took the awaited command ``raw`` and returned
        ``code``: the period's steps when its state and planing force went out (and its
        clock, as armed; the rest of the sample follows, as :meth:`_quick_sample` does after
        its publish), a refused state or planing force publish (retried as the interpreted
        path retries it), or a failed period (settled and reported as
        :meth:`_on_command_lockstep` reports it)."""
        begin = monotonic()
        quick = self._quick
        compiled = self._compiled
        if code <= compiled_sample.FAILED:   # the period failed: finish() raises as run() does
            t, df, dc = self._command_in.read(raw)
            self.sim.command = (df, dc)
            try:
                quick.finish(compiled_sample.FAILED - code, df, dc)
            except FloatingPointError as exc:
                self.sim.failed_period(exc)
                self._took(raw, t, begin)
                self._diverged(exc)
            return
        # the entry checked the command and wrote the sample (and, but for a refused state,
        # published it): what finish() would keep, without its checks
        t, df, dc = self._command_in.unpack(raw)
        self.sim.command = (df, dc)
        quick.published()
        if code == compiled_sample.PUBLISH_REFUSED:   # retried through _send_state (recorded)
            failed = RuntimeError(f'rcl_publish_serialized_message returned '
                                  f'{compiled.rcl_ret}: {compiled.take_error()}')
            self._sample_sent(raw, t, begin, failed, self._state_out.payload())
            return
        if self.record is not None and compiled.put < compiled.records:
            self._put_rest(compiled.put, compiled.records, raw)
        self._sample_sent(raw, t, begin, None, None, code)

    def _put_rest(self, put: int, records: int, raw: bytes) -> None:
        """With ``record``: the records of the compiled sample's ``records`` (the state, the
        command, the planing force, the clock, in that order) after the ``put`` it put, which
        did not fit into the ring, put the interpreted way (which waits for room in
        lockstep)."""
        rec = self.record
        for i in range(put, records):
            if i == 0:
                rec.put_sent(self.state_pub.topic_name, self._state_out.payload())
            elif i == 1:
                rec.command(raw)
            elif i == 2:
                rec.put_sent(self.force_pub.topic_name, self._force_out.payload())
            else:
                rec.put_sent(self.clock_pub.topic_name, self._clock_out.last())

    def _took(self, raw: bytes, t: float, begin: float, compiled: bool = False) -> None:
        """Lockstep: the awaited command ``raw`` (answering ``t``) was taken at ``begin``
        (``compiled``: by the compiled sample, which disarmed itself and put its record into
        the in-plant ring)."""
        self.received += 1
        if not compiled:
            if self._compiled is not None:
                self._compiled.disarm()
            if self.record is not None:
                self.record.command(raw)
        self._last_command_t = t
        self._awaiting = None
        self._last_command_wall = begin

    def _quick_sample(self, raw: bytes, t: float, begin: float) -> None:
        """Lockstep: :class:`~fohssv_sim.models.HeldPeriod` ran the period of the command
        answering ``t`` and wrote its sample into the state message. The state goes out
        first, the round trip waits for nothing else (work before a publish costs the loop
        at least as long, work after it is free up to about 7 us: docs/ros.md); then the
        model's bookkeeping and what :meth:`_stepped` does after the state (the same
        messages, counts and checks)."""
        payload = self._state_out.payload()
        try:
            self._send_state(payload)
            failed = None
        except Exception as exc:  # noqa: BLE001 - RCLError is not exported by rclpy
            failed = exc
        self._sample_sent(raw, t, begin, failed, payload)

    def _sample_sent(self, raw: bytes, t: float, begin: float, failed: Exception | None,
                     payload: bytes | None, compiled: int | None = None) -> None:
        """Lockstep, the short path: the sample's state went out (or its publish failed with
        ``failed``: ``payload`` is retried); the model's bookkeeping and the rest. With
        ``compiled`` (the compiled sample's code): its planing force and clock went out
        already, its records are in the ring (``FORCE_REFUSED``: the planing force is
        retried here, then the clock)."""
        if compiled is None:
            force = self._force_data
            force[1] = self._quick.settle()
            force[0] = self._state_data[0]
        else:                  # the compiled sample wrote the same [t, Fp] into the message
            self._quick.settle()
        self.sim.took(self.sim.command)
        self._took(raw, t, begin, compiled is not None)
        self.sent += 1
        try:
            if failed is not None:
                self._retry_publish(self._send_state, self.state_pub.topic_name, payload,
                                    failed, state=True)
            if compiled is None:
                self._send_rest(self.sim.samples)
            elif compiled == compiled_sample.FORCE_REFUSED:
                c = self._compiled
                self._retry_publish(self._send_force, self.force_pub.topic_name,
                                    self._force_out.payload(), RuntimeError(
                                        f'rcl_publish_serialized_message returned '
                                        f'{c.force_ret}: {c.take_error()}'))
                self._send_after_force(self.sim.samples)
            else:
                self._compiled_rest(self.sim.samples)
        except PublishFailed as exc:
            self._fail(EXIT_PUBLISH_FAILED, str(exc))
            return
        if self._published():
            self._next(begin)

    def _compiled_rest(self, sample: int) -> None:
        """What :meth:`_send_after_force` does after a compiled sample, which published the
        clock itself: a clock rcl refused is said (as :meth:`_send_after_force` says it),
        and the views when due."""
        c = self._compiled
        if c.clock_asked & compiled_sample.CLOCK_PUBLISH and c.clock_ret != 0:
            self._log_retry(f'/clock at t={self._state_data[0]!r} s not published: '
                            f'rcl_publish_serialized_message returned {c.clock_ret}: '
                            f'{c.take_error()}')
        self._send_views(sample)

    def _on_command(self, raw: bytes) -> None:
        """A serialized ``command`` (the subscription is raw: see wire.py)."""
        if not self.running:
            return
        self.received += 1
        if self.record is not None:
            self.record.command(raw)
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
            if self._lag.add(now, t):
                self._lag_stop()
                return
            if self._take(data) and lag > self._max_lag:
                self._max_lag = lag
        else:
            self._take(data)    # rejected: no finite t

    # -- command lag (realtime, external controller) ---------------------------------------
    def _cost_text(self) -> str:
        samples = self.sim.samples
        if not samples or not self.running:
            return 'plant CPU per sample unknown'
        cpu = (cpu_seconds() - self._cpu_start) / samples
        period = self.options.control_period / self.options.real_time_factor
        text = (f'plant CPU {cpu * 1e6:.0f} us per sample = {100 * cpu / period:.0f} % of the '
                f'{period * 1e6:.0f} us period')
        if self.pacer is not None and self.pacer.produced:
            p = self.pacer
            text += f', deadline misses {p.misses}/{p.produced}'
        return text

    def _remedies(self) -> str:
        longer = min(1.0, 10.0 * self.options.control_period)
        return ('remedies: mode:=lockstep (deterministic, at the speed of the loop), a longer '
                f'control_period (e.g. control_period:={longer:g}), or the law hosted in the '
                'plant, controller:=NAME (e.g. controller:=state_feedback: no DDS in the loop)')

    def _lag_stop(self) -> None:
        lag, o = self._lag, self.options
        self._fail(EXIT_COMMAND_LAG,
                   f'command lag: the external controller\'s commands lagged by more than '
                   f'max_command_lag={o.max_command_lag:g} control periods for as long (at '
                   f'least {lag.over_least:.0f} periods since t={lag.over_since:.6g} s, now '
                   f'{lag.last:.0f}; mean {lag.mean:.1f}, worst {lag.worst:.0f} over the run) '
                   f'at t={self.sim.t!r} s: the plant and its controller cannot keep up with '
                   f'control_period={o.control_period:g} s in real time here '
                   f'({self._cost_text()}); stopping before late commands lose the vehicle. '
                   + self._remedies())

    def _lag_note(self) -> str:
        """For a failure in realtime with an external controller: the command lag, and when
        it was beyond the limit, that the run was probably lost to it."""
        lag = self._lag
        if self.hosted is not None or self.pacer is None or not lag.count:
            return ''
        text = (f'; command lag: now {lag.last:.1f}, mean {lag.mean:.1f}, worst '
                f'{lag.worst:.1f} control periods (worst {lag.worst * lag.period * 1e3:.3g} ms '
                f'of simulated time; max_command_lag={self.options.max_command_lag:g})')
        if lag.lagging():
            text += (': the commands were late, and the loop may have been lost to their lag '
                     f'rather than to the model ({self._cost_text()}); ' + self._remedies())
        return text

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
        if self.hosted is not None:
            self.hosted.reset()
        self._lag.over_since = None
        self._watchdog_warned = False
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

    # -- end ---------------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        """Figures of the run so far (also logged as one JSON line at the end)."""
        wall = time.monotonic() - self._run_wall_start if self.running else 0.0
        cpu = cpu_seconds() - self._cpu_start if self.running else 0.0
        # t, samples and steps count from the last /reset; the rates divide the whole run's
        # samples (samples_total) by the whole run's wall and CPU time
        total = self._samples_before + self.sim.samples
        t, n = self._made()
        steps = self._steps_before + n
        s: dict[str, Any] = {
            'mode': self.options.mode, 'model': self.model.model, 'solver': self.model.solver,
            'step': self.model.step, 'control_period': self.options.control_period,
            't': t, 'samples': self.sim.samples,
            'steps': n, 'resets': self.resets, 'samples_total': total,
            'steps_total': steps, 'published_states': self.sent,
            'wall_time': wall, 'cpu_time': cpu,
            'cpu_per_sample_us': cpu / total * 1e6 if total else 0.0,
            'clock_samples': self._clock_every, 'view_samples': self._view_every,
            'views': self.views.published if self.views is not None else 0,
            'rejected_commands': self.rejected, 'ignored_commands': self.ignored,
            'controller': self.options.controller or 'external',
            'publish_retries': self.publish_retries,
            'cpu_affinity': list(self.options.cpu_affinity),
            'cpu_dma_latency': self.cpu_latency,
        }
        if self.hosted is not None:
            s.update(hosted_commands=self.commanded, commands_published=self.commands_sent,
                     law_failures=self.law_failures)
        elif self._lockstep:       # samples the compiled sample took (compiled_sample.py)
            s['compiled_samples'] = self._compiled.taken if self._compiled is not None else 0
            s['compiled_take'] = self._taking   # commands taken by rcl in compiled code
        if self.profile is not None:
            s['profile'] = self.profile.summary()
        if self.record is not None:
            s.update(self.record.summary())
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
                     max_command_lag=self._max_lag, stale_commands=self.stale,
                     cpu_share_of_period=(cpu / total / p.period if total else 0.0))
            if self.hosted is None:
                s.update(self._lag.summary())
            elif self.bursts is not None:   # hosted: wake-ups, and how often they backed off
                s.update(wake_ups=self.bursts.wake_ups, burst_backoffs=self.bursts.near_misses,
                         samples_per_wake_up=(p.produced / self.bursts.wake_ups
                                              if self.bursts.wake_ups else 0.0))
        elif wall > 0:
            s.update(samples_per_second=total / wall, steps_per_second=steps / wall)
        return s

    def _made(self) -> tuple[float, int]:
        """(t, steps) of the run's last sample: the plant's, unless a refused publish ended
        the run inside a burst whose later samples the kernel had computed already."""
        return self._cut if self._cut is not None else (self.sim.t, self.sim.plant.n)

    def _end(self, code: int) -> None:
        if self.finished.done():
            return
        self.exit_code = code
        self.flush_views()      # the summary counts a view's last messages too
        self.get_logger().info('summary: ' + json.dumps(self.summary()))
        self.running = False
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        self.finished.set_result(code)
        self.announce_end(f'exit code {code}', code)

    def flush_views(self) -> None:
        """Publish a view's last messages, if pending (before the summary and run_end)."""
        if self.views is not None and self.views.pending:
            with contextlib.suppress(Exception):   # the context may be going down (a signal)
                self.views.flush()

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
                     self.command_topic: self.received if self.hosted is None
                     else self.commands_sent}
        if self.views is not None:
            self.flush_views()
            n = self.views.published
            for pub in self.views.publishers:
                published[pub.topic_name] = 2 * n if pub is self.views.marker_pub else n
        text = run_end_text('plant', reason, code, self._made()[0], published)
        if self.record is not None:
            self.record.end(text)
        try:
            self.end_pub.publish(String(data=text))
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
        would lose its tail when the plant exits. Then, up to _RUN_END_WAIT s, while a reader
        of ``run_end`` is still there (a recorder leaves once it took it). A signal after the
        run ended ends it (``STOP.count`` beyond ``signals``, the count when the run ended: a
        signal that interrupted the run does not, so a recorder still drains)."""
        deadline = time.monotonic() + self.options.end_linger
        samples = self._sample_pubs
        while (rclpy.ok() and STOP.count == signals and time.monotonic() < deadline
               and any(p.get_subscription_count() > 0 for p in samples)):
            executor.spin_once(timeout_sec=0.05)
        # run_end too, as the player keeps its own: a recorder that has not taken it yet loses
        # it with this writer (seen under load: every sample in the bag, the run_end never
        # heard, exit 7); a recorder leaves once it has it. Bounded by _RUN_END_WAIT.
        end = self.end_pub
        deadline = time.monotonic() + _RUN_END_WAIT
        while (rclpy.ok() and STOP.count == signals and time.monotonic() < deadline
               and (end.get_subscription_count() > 0
                    or self.count_subscribers(end.topic_name) > 0)):
            executor.spin_once(timeout_sec=0.05)


def _interrupted(node: PlantNode) -> None:
    node.flush_views()
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
    if node.record is not None:     # the in-plant writer ready before any sample (and peer)
        node.record.ready()
    executor = make_executor()
    executor.add_node(node)
    pinned = pin_node(node, node.options.cpu_affinity)   # after the in-plant writer started
    node.cpu_latency = hold_latency(node, node.options.cpu_dma_latency,
                                    warn=node.options.mode == 'realtime')
    if node.options.mode == 'realtime':
        tighten_timer_slack()
        refused = set_realtime_priority(node.options.realtime_priority)
        model, hz = kernel_preemption()
        if model is not None and model not in PREEMPTIBLE:
            node.get_logger().info(
                f'kernel preemption {model!r}' + (f' ({hz} Hz tick)' if hz else '') + ': the '
                'pacing thread, SCHED_FIFO or not, waits for any kernel path another task runs '
                'on its CPU (milliseconds at worst); for deadlines of a 1e-4 s control period, '
                'a kernel with preempt=full (boot parameter, PREEMPT_DYNAMIC kernels) or '
                'PREEMPT_RT')
        if refused:
            node.get_logger().warning(f'{refused}; running with the normal scheduler')
        elif pinned and node.options.realtime_priority and len(node.options.cpu_affinity) == 1:
            node.get_logger().warning(
                'cpu_affinity names one CPU and the pacing thread runs under SCHED_FIFO: '
                "behind schedule it can keep the process's own DDS threads (commands, "
                'acknowledgements) off that CPU; give the plant two CPUs or realtime_priority:=0')
        with PausedCollector():
            spin_until(executor, node.finished, paced=node)
    elif node.take_commands():        # lockstep: the awaited command taken in compiled code
        try:
            node.spin_taking(executor)
        finally:
            node._compiled.close()
    else:
        spin_until(executor, node.finished, paced=node)
    code = node.exit_code
    signals = STOP.count          # a further signal ends the flush and the linger
    if STOP.received is not None and not node.finished.done():
        _interrupted(node)
    # a reader loses what it has not taken when the writer goes away: after a signal
    # too, the recorder gets the time to drain what was published (bounded waits)
    node.flush(signals)
    if node.record is not None:       # the controller's name for the bag, if still asked
        node.record.settle(executor)
    code = _recorded(node, code)      # the bag closed before the linger (which may wait 1 s)
    node.linger(executor, signals)
    if node.record is not None:       # the writer process ended meanwhile
        node.record.reap()
    return code


def _recorded(node: PlantNode, code: int) -> int:
    """With ``record``: wait until the writer closed the bag; exit 8 when it misses messages."""
    if node.record is None:
        return code
    if node._compiled is not None:    # the ring closes: the compiled sample puts no more
        node._compiled.disarm()
        node._compiled.record_into(None)
    return node.record.finish(code)


def _on_interrupt(node: PlantNode) -> int:
    if not node.finished.done():
        _interrupted(node)
    code = _recorded(node, node.exit_code)
    if node.record is not None:
        node.record.reap()
    return code


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run fohssv_sim plant``; exits with the node's exit code."""
    sys.exit(run_node('plant', args, PlantNode, _run, specs=PARAMETERS + NODE_PARAMETERS,
                      refused=(control.UnknownController,), on_interrupt=_on_interrupt))


if __name__ == '__main__':
    main()
