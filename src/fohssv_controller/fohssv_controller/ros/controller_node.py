"""The generic controller node: hosts the controller plugin its ``controller`` parameter names.

``ros2 run fohssv_controller controller --ros-args -p controller:=lqr`` (or the per-law
executables ``state_feedback`` and ``lqr``). Subscribes ``state`` and answers every sample with
one ``command`` [t, delta_f, delta_c] whose t echoes the state's time, so the node works in
lockstep and real time alike. The controller's parameters are declared from its
``Parameters`` table (descriptions, ranges); a change is validated by rebuilding the
controller and applied only when that succeeds. A state message that does not fit the
contract is dropped and logged; a state whose time goes backwards (the plant was reset) resets
the controller (a plugin whose reset raises is logged and answers on). A control law whose
output is not finite (NaN or infinite: clamping it would command a full deflection), or that
raises an exception, gets no command sent for that state:
the node logs it (the first 20 one by one, then at most one line a second, see
:class:`~fohssv_sim.ros.nodekit.LogLimiter`) and counts it; the plant keeps its last good
command (in lockstep it waits for an answer and ends with exit 3 after ``command_timeout``,
naming the stalled controller).

The per-sample path (10k states/s at the default control period) skips rclpy's message
conversion: the state arrives serialized (a raw subscription) and its doubles are unpacked at
their known offset, an affine law (eq. 31, the LQR) is evaluated as one scalar expression of
its gains (:func:`fohssv_sim.control.per_sample_command`, as the plant hosts it), the answer is
written in place into one serialized ``command`` (see :mod:`fohssv_sim.ros.wire`), and once
the command subscriptions are settled (see :class:`~fohssv_sim.ros.matching.SubscriptionGate`)
no graph query is made per sample.
A second publisher of ``state`` (two plants on one domain and namespace, whose samples the
controller would answer interleaved) is logged once as a warning naming the nodes.
``cpu_affinity`` (as the plant's: ``''`` not pinned, or CPUs such as ``1`` or ``'0,2-3'``) pins
every thread of the process once the node, its publisher and its subscription exist.
``cpu_dma_latency`` (as the plant's: 0 µs by default, -1 no request) holds Linux's CPU
wake-up latency limit while the node runs, where the process may write
``/dev/cpu_dma_latency``.

Exit codes: 0 on a clean stop, 2 for an unknown controller or invalid parameters.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from fohssv_sim import control
from fohssv_sim.contract import COMMAND, STATE, ContractError, decode
from fohssv_sim.control import Controller, NonFiniteCommand, per_sample_command
from fohssv_sim.params import ParameterSpec, field_specs
from fohssv_sim.ros.nodekit import (
    CPU_AFFINITY,
    CPU_DMA_LATENCY,
    NODE_OPTIONS,
    PLUGIN_FAULTS,
    ArrayReader,
    ArrayWriter,
    HoldReporter,
    LogLimiter,
    SecondPublisherWarning,
    SubscriptionGate,
    build_plugin,
    declare,
    declare_rows,
    destroy_on_error,
    final_log,
    hold_latency,
    install_validation,
    pin_node,
    profile,
    refuse_unknown,
    reset_plugin,
    run_node,
)
from fohssv_sim.ros.wire import raw_publish

__all__ = ['ControllerNode', 'main', 'main_state_feedback', 'main_lqr']

EXIT_OK, EXIT_BAD_CONFIG = 0, 2
_LOG_EACH = 20

#: The node's own parameter (besides the controller's table and ``controller``).
MIN_COMMAND_SUBSCRIBERS = ParameterSpec(
    'min_command_subscribers', '-', 1, '-', 'matched subscriptions of command (the plant, '
    'recorders) to wait for before the first command; 2 with a recorder, so it hears every '
    'command', low=1.0, low_open=False, high=1000.0, high_open=False)


class ControllerNode(Node):
    """See the module docstring.

    Raises:
        control.UnknownController: the ``controller`` parameter names no plugin.
        ParameterError: invalid controller parameters.
    """

    @destroy_on_error
    def __init__(self, default_controller: str | type[Controller] = 'state_feedback',
                 **kwargs: Any) -> None:
        super().__init__('controller', **NODE_OPTIONS, **kwargs)
        if isinstance(default_controller, type):
            self.cls = default_controller
        else:
            self.cls = self._plugin(default_controller)
        specs = field_specs(self.cls.Parameters)
        names = tuple(s.name for s in specs)
        values = declare(self, specs)
        # until the plant's (and a recorder's) subscription is matched a publish is lost
        own = declare(self, (MIN_COMMAND_SUBSCRIBERS, CPU_AFFINITY, CPU_DMA_LATENCY))
        minimum = own['min_command_subscribers']
        refuse_unknown(self)
        self.controller = self._build(values)
        # the law as the per-sample path calls it (an affine law as one scalar expression)
        self._law = per_sample_command(self.controller)
        install_validation(self, names, self._build, self._apply)

        self._command = ArrayWriter(COMMAND)
        self._out = self._command.values   # [t, delta_f, delta_c] inside the serialized message
        self._state_in = ArrayReader(STATE)
        self.command_pub = self.create_publisher(Float64MultiArray, COMMAND.name,
                                                 profile(COMMAND))
        # rclpy's publish_raw itself: skips Publisher.publish's type check and guard (1-1.5 us
        # on the lockstep round trip; the node publishes only from its callbacks, before it
        # destroys anything)
        self._send_command = raw_publish(self.command_pub)
        self.state_sub = self.create_subscription(Float64MultiArray, STATE.name,
                                                  self._on_state, profile(STATE), raw=True)
        self._pending: list[tuple[float, ...]] = []
        self._retry = None
        self._matched = SubscriptionGate(self, self.command_pub, minimum=minimum,
                                         follow=self.state_sub.topic_name)
        self._open = False   # True once the gate settled open: no per-sample graph queries
        self._held = HoldReporter(self, self._matched)
        self._rivals = SecondPublisherWarning(self, self.state_sub.topic_name)
        self._last_t: float | None = None
        self.answered = 0
        self.dropped = 0
        self.withheld = 0     # states whose law output was not finite: no command sent
        self.raised = 0       # states whose law raised an exception: no command sent
        # each fault its own limiter: the first 20 lines one by one, then one a second
        logger = self.get_logger()
        self._log_dropped = LogLimiter(logger, _LOG_EACH)
        self._log_withheld = LogLimiter(logger, _LOG_EACH)
        self._log_raised = LogLimiter(logger, _LOG_EACH)
        self.get_logger().info(f'controller {self.controller.describe()}')
        pin_node(self, CPU_AFFINITY.validate(own['cpu_affinity']))
        self.cpu_latency = hold_latency(self, int(own['cpu_dma_latency']))

    def _plugin(self, default_controller: str) -> type[Controller]:
        declare_rows(self, [(
            'controller', default_controller,
            ParameterDescriptor(description='name of the controller plugin (entry point in '
                                f'group {control.GROUP})', read_only=True,
                                additional_constraints='one of: '
                                + ', '.join(control.available())))])
        return control.load(self.get_parameter('controller').value)

    def _build(self, values: Mapping[str, Any]) -> Controller:
        return build_plugin(self.cls, self.cls.Parameters(**values))

    def _apply(self, controller: Controller) -> None:
        self.controller = controller
        self._law = per_sample_command(controller)
        self.get_logger().info(f'parameters changed: {controller.describe()}')

    def _on_state(self, raw: bytes) -> None:
        data = self._state_in.read(raw)
        if len(data) == 5:
            t, z, w, theta, q = data
            s = t + z + w + theta + q   # NaN when any is non-finite (or the sum overflows)
            if s - s == 0.0:
                self._answer(t, (z, w, theta, q))
                return
        try:
            t, *x = decode(STATE, data)   # the slow path: rejects with the reason, or passes
        except ContractError as exc:       # finite values whose sum overflowed
            self.dropped += 1
            self._log_dropped(f'dropped a state message: {exc} ({self.dropped} dropped)')
            return
        self._answer(t, x)

    def _answer(self, t: float, x: Sequence[float]) -> None:
        last = self._last_t
        self._last_t = t
        if last is not None and t < last:
            failed = reset_plugin(self.controller.name, self.controller.reset)
            if failed is None:
                self.get_logger().info(f'state time went back to t={t!r} s: controller reset')
            else:       # the node stays; the law answers with the memory it has
                self.get_logger().error(f'state time went back to t={t!r} s: {failed}; '
                                        'answering without a reset')
        try:
            df, dc = self._law(t, x)
        except NonFiniteCommand as exc:
            # never sent (clamped it would be a full deflection): the plant keeps its last
            # good command; in lockstep it waits, and its command_timeout names this node
            self.withheld += 1
            self._log_withheld(f'{exc}; no command sent for this state ({self.withheld} '
                               'withheld)')
            return
        except PLUGIN_FAULTS as exc:  # a plugin's bug must not end the node, nor flood the log
            self.raised += 1
            self._log_raised(f'{self.controller.name}.command(t={t!r}) raised '
                             f'{type(exc).__name__}: {exc}; no command sent ({self.raised} '
                             'raised)')
            return
        if self._open:
            out = self._out
            out[0] = t
            out[1] = df
            out[2] = dc
            self._send_command(self._command.payload())
            self.answered += 1
        else:
            self._send((t, df, dc))

    def _send(self, data: tuple[float, ...]) -> None:
        # Until the subscriptions are matched a publish would be lost to them: hold the answer.
        if self._pending or not self._matched():
            self._pending.append(data)
            if self._retry is None:
                self._retry = self.create_timer(0.005, self._flush)
            return
        self._open = self._matched.settled
        self._out[0], self._out[1], self._out[2] = data
        self._send_command(self._command.payload())
        self.answered += 1

    def _flush(self) -> None:
        if not self._matched():
            self._held.report(len(self._pending))
            return
        pending, self._pending = self._pending, []
        for data in pending:
            self._send(data)
        if self._retry is not None:
            self.destroy_timer(self._retry)
            self._retry = None


def main(args: list[str] | None = None,
         default_controller: str | type[Controller] = 'state_feedback') -> None:
    """Entry point of ``ros2 run fohssv_controller controller``; also hosts a controller class
    given directly (``main(default_controller=MyController)``, no plugin registration needed).
    """
    specs = () if isinstance(default_controller, str) else field_specs(
        default_controller.Parameters)

    def on_exit(node: ControllerNode) -> None:
        final_log(node.get_name(), f'answered {node.answered} state(s), dropped '
                  f'{node.dropped}, withheld {node.withheld} (non-finite law output), '
                  f'{node.raised} raised by the law')

    sys.exit(run_node('controller', args, lambda: ControllerNode(default_controller),
                      specs=(*specs, MIN_COMMAND_SUBSCRIBERS, CPU_AFFINITY, CPU_DMA_LATENCY),
                      refused=(control.UnknownController,), on_exit=on_exit))


def main_state_feedback(args: list[str] | None = None) -> None:
    """``ros2 run fohssv_controller state_feedback``: the node with eq. 31."""
    main(args, 'state_feedback')


def main_lqr(args: list[str] | None = None) -> None:
    """``ros2 run fohssv_controller lqr``: the node with the LQR."""
    main(args, 'lqr')


def main_fractional_pid(args: list[str] | None = None) -> None:
    """``ros2 run fohssv_controller fractional_pid``: the node with the PI^lambda D^mu."""
    main(args, 'fractional_pid')
