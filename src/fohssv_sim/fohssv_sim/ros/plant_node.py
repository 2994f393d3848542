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
run ends there with its summary and a ``run_end`` listing what was published,
10 a hosted law's call hung (no return for ``LAW_TIMEOUT`` s, logged) and a signal ended it,
11 realtime: over ``max_deadline_miss_rate`` of the deadlines missed (when set; default off).
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from time import monotonic
from typing import Any

from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from .. import control
from ..contract import CLOCK, COMMAND, PLANING_FORCE, RUN_END, STATE
from ..params import PARAMETERS, ModelParameters
from .faults import StateFault
from .inplant_record import EXIT_RECORD_LOST
from .inplant_record import start as start_recording
from .loop import SampledPlant, time_text
from .nodekit import (
    NODE_OPTIONS,
    STOP,
    ArrayReader,
    ArrayWriter,
    ClockWriter,
    LogLimiter,
    PausedCollector,
    declare,
    destroy_on_error,
    install_validation,
    make_executor,
    profile,
    refuse_unknown,
    run_node,
    spin_until,
)
from .options import NODE_PARAMETERS, PlantOptions, check_options, clock_samples, view_samples
from .plant.codes import (
    CONTROLLER_PREFIX,
    EXIT_BAD_PARAMETERS,
    EXIT_COMMAND_LAG,
    EXIT_DIVERGED,
    EXIT_NO_PEERS,
    EXIT_OK,
    EXIT_PUBLISH_FAILED,
    EXIT_SECOND_CONTROLLER,
    EXIT_SECOND_PLANT,
    EXIT_TIMEOUT,
    PublishFailed,
)
from .plant.commands import LOG_EACH, CommandIntake
from .plant.fastpath.taking import CompiledTaking
from .plant.host_tuning import tune_host
from .plant.hosted import HostedRoom
from .plant.instrumentation import Profile
from .plant.lockstep import CommandWait, Lockstep, ReaderPacing
from .plant.publishing import Publishing
from .plant.realtime import LagStop, RealTime, Watchdog
from .plant.run_end import Departure, RunEnd, on_interrupt, recorded, signals_that_ended
from .plant.start import PeerGate, RunStart
from .views import ViewPublisher
from .wire import raw_publish

__all__ = ['PlantNode', 'main', 'EXIT_OK', 'EXIT_DIVERGED', 'EXIT_BAD_PARAMETERS',
           'EXIT_TIMEOUT', 'EXIT_NO_PEERS', 'EXIT_SECOND_PLANT', 'EXIT_COMMAND_LAG',
           'EXIT_SECOND_CONTROLLER', 'CONTROLLER_PREFIX', 'EXIT_RECORD_LOST',
           'EXIT_PUBLISH_FAILED']

_MODEL_NAMES = tuple(p.name for p in PARAMETERS)
_NODE_NAMES = tuple(p.name for p in NODE_PARAMETERS)


def build_config(values: Mapping[str, Any]) -> tuple[ModelParameters, PlantOptions, int]:
    """The pure configuration from parameter values: model, options, steps per sample.

    Raises:
        ParameterError: an invalid value or combination.
    """
    model = ModelParameters.from_dict({n: values[n] for n in _MODEL_NAMES})
    options = PlantOptions(**{n: values[n] for n in _NODE_NAMES})
    hold = check_options(model, options)
    return model, options, hold


class PlantNode(RunStart, Publishing, HostedRoom, Lockstep, CompiledTaking, RealTime,
                CommandIntake, RunEnd, Node):
    """See the module docstring. Raises ParameterError from the constructor on bad values.

    The node wires its rooms (:mod:`fohssv_sim.ros.plant`). Objects that own their state,
    each given what it reads and the calls back it makes: the start gate
    (:class:`~.plant.start.PeerGate`), the lockstep command wait and reader pacing
    (:class:`~.plant.lockstep.CommandWait`, :class:`~.plant.lockstep.ReaderPacing`), real
    time's watchdog and lag stop (:class:`~.plant.realtime.Watchdog`,
    :class:`~.plant.realtime.LagStop`), the hosted law's hang watch
    (:class:`~.plant.hosted.LawWatch`), the flush and linger after the run
    (:class:`~.plant.run_end.Departure`), the in-plant recording, the views, host tuning (a
    function). Mixins, each declaring its own counters and flags in its module, for the
    per-sample paths, where an object's attribute hop would cost each sample: publishing,
    lockstep, the compiled taking, real time's pacing, command intake, the hosted law's
    bursts, the run's start and reset, the run's end (which reads every room's figures)."""

    #: the ``cpu_dma_latency`` held (us), None when none: :func:`.plant.host_tuning.tune_host`'s
    cpu_latency: int | None = None

    @destroy_on_error
    def __init__(self, **kwargs: Any) -> None:
        super().__init__('plant', **NODE_OPTIONS, **kwargs)
        values = declare(self, PARAMETERS + NODE_PARAMETERS)
        self.hosted = self._host(values['controller'])   # the hosted law (hosted.py), or None
        refuse_unknown(self)
        self.model, self.options, hold = build_config(values)
        self.sim = SampledPlant(self.model, self.options.control_period,
                                self.options.initial_state, self.options.duration)
        install_validation(self, _MODEL_NAMES + _NODE_NAMES, build_config, self._apply)
        self.finished = Future()   # done with the exit code when the run ends (run_end.py)
        self._lockstep = self.options.mode == 'lockstep'
        self._free_run = self.hosted is not None and self._lockstep
        self.profile: Profile | None = Profile() if self.options.profile else None
        self._open_topics()
        log = self.get_logger()
        self._log_rejected = LogLimiter(log, LOG_EACH)             # commands.py
        self._log_retry = LogLimiter(log, 5, level='warning')      # publishing.py
        # record:=PATH: the plant writes its own bag (inplant_record.py); None when off
        self.record = start_recording(self)
        self._open_fast_path()
        # pace_to_subscribers: the readers of the samples (and a hosted law's commands)
        self.reader_pacing = ReaderPacing((self.state_pub, self.force_pub) + (
            () if self.command_pub is None else (self.command_pub,)), log)
        # real time, an external controller: its silence, and the lag of its commands
        self.watchdog = Watchdog(log)
        self.lag_stop = LagStop(self.options.max_command_lag, self.options.control_period)
        # the start gate: the run starts once the peers matched (a second plant ends it)
        self.gate = PeerGate(
            self, lambda: self.options, None if self.hosted is None else self.hosted.name,
            self.state_pub, self.clock_pub, self._sample_pubs, self.views, self.command_sub,
            self.command_topic, self.finished, start=self._start, fail=self._fail)
        # lockstep: the awaited command's timeout and graces, a period's overrun
        self.command_wait = CommandWait(log, self.state_pub, self.gate.peers, self._fail)
        # after the run: the readers' time to take what was published (flush, linger)
        self.departure = Departure(self, self.end_pub, self._sample_pubs)
        log.info(
            f'{self.sim.plant.describe()} (ready in {self.sim.compile_seconds:.2f} s); mode '
            f'{self.options.mode}, control period '
            f'{self.options.control_period:g} s = {hold} steps (zero-order hold), duration '
            f'{self.options.duration:g} s; controller '
            + ('external (a node publishing command)' if self.hosted is None
               else self.hosted.describe()))

    def _open_topics(self) -> None:
        """The run's messages, publishers and publish calls, the views, the command
        subscription (an external controller) or publisher (a hosted law), ``reset`` and
        ``run_end`` (publishing.py sends the samples through them)."""
        # the messages of every sample, serialized once and written in place (wire.py)
        self._state_out = ArrayWriter(STATE)
        self._force_out = ArrayWriter(PLANING_FORCE)
        self._state_data = self._state_out.values   # [t, z, w, theta, q] inside the CDR
        self._force_data = self._force_out.values
        self._clock_out = ClockWriter()
        self._command_in = ArrayReader(COMMAND)
        self._clock_every = clock_samples(self.options)
        self.state_pub = self.create_publisher(Float64MultiArray, STATE.name, profile(STATE))
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
        self.reset_srv = self.create_service(Trigger, 'reset', self._on_reset)
        # once, when the run ends: what was published, for recorders to check (contract.py)
        self.end_pub = self.create_publisher(String, RUN_END.name, profile(RUN_END))

    def _open_fast_path(self) -> None:
        """Lockstep with an external controller: the short path of the awaited command's
        sample and, where it can be built, the compiled sample (fastpath/); after the
        in-plant recording, whose ring and publish calls they use."""
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
        # (fastpath/sample.py), armed for each awaited sample; None: the interpreted path
        self._compiled = self._build_compiled() if self._quick is not None else None

    def _apply(self, config: tuple[ModelParameters, PlantOptions, int]) -> None:
        _, options, _ = config
        self.options = options
        self.lag_stop.lag.limit = options.max_command_lag
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
                f'max_cavitator_deflection={lc:g} rad at t={time_text(self.sim.t)} s: the held '
                'command '
                f'delta_f={df!r}, delta_c={dc!r} rad is beyond them; holding the clamped '
                f'command delta_f={held[0]!r}, delta_c={held[1]!r} rad')

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
            return self.running      # False when the law hung and a signal ended the run
        return True

    def _diverged(self, exc: Exception) -> None:
        """End the run: the state turned non-finite or left the physical bounds."""
        self._fail(EXIT_DIVERGED, f'simulation failed: {exc}{self._lag_note()}')


def _run(node: PlantNode) -> int:
    """Spin the plant until its run ends or a signal (logged as an interruption); then flush
    and linger; the node's exit code."""
    if node.record is not None:     # the in-plant writer ready before any sample (and peer)
        node.record.ready()
    executor = make_executor()
    executor.add_node(node)
    node.cpu_latency = tune_host(node, node.options)   # after the in-plant writer started
    if node.options.mode == 'realtime':
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
    signals = signals_that_ended(node)   # a further signal ends the linger
    # a reader loses what it has not taken when the writer goes away: after a signal too
    # (even one that came as the run ended by itself), the recorder gets the time to drain
    # what was published (bounded waits; a further signal ends it)
    node.departure.flush(STOP.count)
    if node.record is not None:       # the controller's name for the bag, if still asked
        node.record.settle(executor)
    code = recorded(node, code)      # the bag closed before the linger (which may wait 1 s)
    node.departure.linger(executor, signals, node.options.end_linger)
    if node.record is not None:       # the writer process ended meanwhile
        node.record.reap()
    return code


def main(args: list[str] | None = None) -> None:
    """Entry point of ``ros2 run fohssv_sim plant``; exits with the node's exit code."""
    sys.exit(run_node('plant', args, PlantNode, _run, specs=PARAMETERS + NODE_PARAMETERS,
                      refused=(control.UnknownController,), on_interrupt=on_interrupt))


if __name__ == '__main__':
    main()
