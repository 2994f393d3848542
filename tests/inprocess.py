"""Nodes built in the test process: the in-process layer of the tests (no child process).

A :class:`Graph` is rclpy's default context, as a node's process has it, initialised on the
test's own ROS_DOMAIN_ID (with the nodes' discovery settings, :func:`rosproc.init_context`)
for the test and shut down after it, and one executor, the one the nodes' processes spin on
(:func:`fohssv_sim.ros.spin.make_executor`: rclpy's EventsExecutor unless
``FOHSSV_EXECUTOR=single``; a fraction of the single-threaded executor's cost per callback,
which a lockstep run in one executor pays three times a sample), that spins every node of
the test: the plant and controller nodes the executables build, given their parameters as
``parameter_overrides`` (what ``--ros-args -p name:=value`` gives them), and a
:class:`Probe` that records what they publish and can play the controller with whatever
answers a test needs. The plant is spun the way its process spins it
(:func:`fohssv_sim.ros.spin.spin_until`, paced by the node) until its run ends. The nodes
log as in their processes (rcutils, to stderr): read their lines with pytest's ``capfd``.

What is between processes (exit codes, signals, a stopped process, transport, a second plant,
the recorder's bag) stays with the process tests (``tests/test_graph_*.py``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.task import Future
from rclpy.utilities import get_default_context
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray
from test_graph_support import keep_all

from fohssv_controller.ros.controller_node import ControllerNode
from fohssv_sim.contract import CLOCK, COMMAND, STATE
from fohssv_sim.ros.nodekit import array_message
from fohssv_sim.ros.plant_node import PlantNode
from fohssv_sim.ros.qos import profile
from fohssv_sim.ros.spin import make_executor, spin_until

import rosproc

__test__ = False  # nothing to collect

#: ``answer(t, x)``: the command ``[t, delta_f, delta_c]`` (any length) for the state
#: ``x = (z, w, theta, q)`` sampled at ``t``, or None for no answer.
Answer = Callable[[float, tuple], Sequence[float] | None]


def overrides(params: dict[str, Any]) -> list[Parameter]:
    """``parameter_overrides`` for ``params``, typed as ``-p k:=v`` types them: a list of
    whole numbers an integer array, any other list a double array."""
    def typed(v: Any) -> Any:
        if not isinstance(v, (list, tuple)):
            return v
        return list(v) if all(type(x) is int for x in v) else [float(x) for x in v]
    return [Parameter(k, value=typed(v)) for k, v in params.items()]


class Probe:
    """A node that records every state (keep-all, as the recorder). With ``answer`` it is the
    controller, answering each state with ``answer(t, x)`` on ``command``; without, a
    listener that records every command too and publishes nothing (never a second
    controller)."""

    def __init__(self, context: Any, answer: Answer | None = None, clock: bool = False) -> None:
        self.node = rclpy.create_node('probe', context=context)
        self.answer = answer
        #: called with (t, x) on each state before any answer (a test's hook into the run)
        self.on_state: Callable[[float, tuple], None] | None = None
        self.states: list[tuple] = []
        self.commands: list[tuple] = []
        self._msg = array_message(COMMAND)
        self._state_pub = None
        self.pub = (self.node.create_publisher(Float64MultiArray, COMMAND.name,
                                               profile(COMMAND)) if answer else None)
        self.node.create_subscription(Float64MultiArray, STATE.name, self._on_state,
                                      keep_all(STATE))
        #: with ``clock``: the /clock times received (ns)
        self.clocks: list[int] = []
        if clock:
            self.node.create_subscription(Clock, CLOCK.name, lambda m: self.clocks.append(
                m.clock.sec * 1_000_000_000 + m.clock.nanosec), profile(CLOCK))
        if answer is None:     # a controller knows its commands (one callback less a sample)
            self.node.create_subscription(Float64MultiArray, COMMAND.name,
                                          lambda m: self.commands.append(tuple(m.data)),
                                          keep_all(COMMAND))

    def _on_state(self, msg: Float64MultiArray) -> None:
        data = tuple(msg.data)
        self.states.append(data)
        if self.on_state is not None:
            self.on_state(data[0], data[1:])
        if self.answer is not None:
            out = self.answer(data[0], data[1:])
            if out is not None:
                self._msg.data = [float(v) for v in out]
                self.pub.publish(self._msg)

    def publish_state(self, data: Sequence[float]) -> None:
        """Publish ``data`` on ``state``, as a plant would (to test a controller node)."""
        if self._state_pub is None:
            self._state_pub = self.node.create_publisher(Float64MultiArray, STATE.name,
                                                         profile(STATE))
        msg = array_message(STATE)
        msg.data = [float(v) for v in data]
        self._state_pub.publish(msg)

    def state_array(self) -> np.ndarray:
        return np.array(self.states, dtype=float)

    def command_array(self) -> np.ndarray:
        return np.array(self.commands, dtype=float)


class Graph:
    """One context on its own domain and one executor for the nodes of a test."""

    def __init__(self) -> None:
        self.domain = rosproc.unique_domain_id()
        # the default context: what the node's process spins on (rclpy.ok() included)
        self.context = rosproc.init_context(self.domain, get_default_context())
        self.executor = make_executor()    # what the nodes spin on in their processes
        self.nodes: list[Any] = []
        self._threads: list[tuple] = []      # (stop, thread, executor, node) of threaded probes

    def add(self, node: Any) -> Any:
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def plant(self, **params: Any) -> PlantNode:
        """The plant node ``ros2 run fohssv_sim plant --ros-args -p ...`` builds."""
        return self.add(PlantNode(context=self.context, parameter_overrides=overrides(params)))

    def controller(self, law: str = 'state_feedback', **params: Any) -> ControllerNode:
        """The controller node ``ros2 run fohssv_controller <law> --ros-args -p ...`` builds."""
        return self.add(ControllerNode(law, context=self.context,
                                       parameter_overrides=overrides(params)))

    def probe(self, answer: Answer | None = None, *, thread: bool = False,
              clock: bool = False) -> Probe:
        """A :class:`Probe` on this graph: the controller with ``answer``, else a listener.
        On the graph's executor, or with ``thread`` on its own executor in its own thread,
        as a controller process would be: a real-time plant serves its executor only
        between samples, one callback at a time, and a probe served there falls behind."""
        probe = Probe(self.context, answer, clock)
        if thread:
            executor = SingleThreadedExecutor(context=self.context)
            executor.add_node(probe.node)
            stop = threading.Event()

            def spin() -> None:
                while not stop.is_set() and self.context.ok():
                    executor.spin_once(timeout_sec=0.01)

            spinner = threading.Thread(target=spin, daemon=True)
            spinner.start()
            self._threads.append((stop, spinner, executor, probe.node))
        else:
            self.add(probe.node)
        return probe

    def run(self, plant: PlantNode, timeout: float = 60.0) -> int:
        """Spin every node until the plant's run ends; its exit code. Fails after
        ``timeout`` s of wall time with the run still going."""
        done = Future()
        plant.finished.add_done_callback(lambda _: done.set_result(True))
        timer = plant.create_timer(timeout, lambda: done.done() or done.set_result(False))
        try:
            spin_until(self.executor, done, paced=plant)
        finally:
            plant.destroy_timer(timer)
        if not plant.finished.done():
            raise AssertionError(f'the plant run did not end within {timeout} s')
        return plant.exit_code

    def run_until(self, plant: PlantNode, predicate: Callable[[], Any], timeout: float,
                  what: str) -> None:
        """Spin every node as :meth:`run` does (a real-time plant paced as its process paces
        it), the run going on, until ``predicate()`` is truthy (checked every 10 ms); fail
        after ``timeout`` s naming ``what``."""
        done = Future()
        check = plant.create_timer(0.01, lambda: done.done() or (
            predicate() and done.set_result(True)))
        limit = plant.create_timer(timeout, lambda: done.done() or done.set_result(False))
        try:
            spin_until(self.executor, done, paced=plant)
        finally:
            plant.destroy_timer(check)
            plant.destroy_timer(limit)
        if not (done.done() and done.result()):
            raise AssertionError(f'timed out after {timeout} s waiting for {what}')

    def wait(self, predicate: Callable[[], Any], timeout: float, what: str) -> Any:
        """Spin every node until ``predicate()`` is truthy (e.g. a probe has taken the last
        samples of an ended run); fail after ``timeout`` s naming ``what``."""
        deadline = time.monotonic() + timeout
        while not (value := predicate()):
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout} s waiting for {what}')
            self.executor.spin_once(timeout_sec=0.01)
        return value

    def remove(self, node: Any) -> None:
        """Take ``node`` off the graph and destroy it (a peer that leaves)."""
        self.executor.remove_node(node)
        self.nodes.remove(node)
        node.destroy_node()

    def spin_for(self, seconds: float) -> None:
        """Spin every node for ``seconds`` of wall time."""
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.executor.spin_once(timeout_sec=min(left, 0.05))

    def close(self) -> None:
        """Destroy the nodes and shut the context down, whatever fails on the way: a context
        left initialised would fail every later test of this process at its ``rclpy.init``."""
        try:
            for stop, spinner, executor, node in self._threads:
                stop.set()
                spinner.join(timeout=5)
                executor.shutdown()
                node.destroy_node()
            for node in self.nodes:
                self.executor.remove_node(node)
                node.destroy_node()
            self.executor.shutdown()
        finally:
            rclpy.shutdown()      # the default context: the next rclpy.init makes a new one
