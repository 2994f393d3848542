"""Support for the graph tests (no tests here): an in-process probe node and batch references.

The probe is a real rclpy node in the test process, on the test's own ROS_DOMAIN_ID, spun by
a background thread. It records ``state`` and ``planing_force`` as they arrive and can act as
the controller (answering each state with whatever ``answer(t, x)`` returns), call the plant's
``reset`` service and set its parameters through the parameter services.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import HistoryPolicy, QoSProfile
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from fohssv_sim.contract import CLOCK, COMMAND, PLANING_FORCE, STATE
from fohssv_sim.params import ModelParameters
from fohssv_sim.ros.nodekit import array_message
from fohssv_sim.ros.qos import profile
from fohssv_sim.simulate import simulate

import rosproc

__test__ = False  # nothing to collect

#: The tests' example controllers (the README's, a late one)
EXAMPLES = Path(__file__).parent / 'examples'

Answer = Callable[[float, tuple], Sequence[float] | None]


def keep_all(topic) -> QoSProfile:
    base = profile(topic)
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=base.depth,
                      reliability=base.reliability, durability=base.durability)


class Probe:
    """A test node: records states and forces; optionally answers them with commands."""

    def __init__(self, domain_id: int, answer: Answer | None = None, *,
                 command_publisher: bool = True, clock: bool = False) -> None:
        """``command_publisher=False``: a passive listener (the plant counts it as a state
        subscriber, never as a controller); ``clock=True``: also record ``/clock`` times
        (ns) in ``clocks``."""
        # the nodes' discovery settings: discovered as fast as a node, whatever the load
        self.context = rosproc.init_context(domain_id)
        self.node = rclpy.create_node('probe', context=self.context)
        self.states: list[tuple] = []
        self.forces: list[tuple] = []
        self.commands: list[tuple] = []
        self.answer = answer
        self._lock = threading.Lock()
        self._pending: list[Sequence[float]] = []
        self._msg = array_message(COMMAND)
        n = self.node
        # keep-all, as the recorder: a probe slower than a fast lockstep run stops acknowledging
        # instead of overwriting what it has not taken (a plant with pace_to_subscribers waits)
        n.create_subscription(Float64MultiArray, STATE.name, self._on_state, keep_all(STATE))
        n.create_subscription(Float64MultiArray, PLANING_FORCE.name,
                              lambda m: self.forces.append(tuple(m.data)),
                              keep_all(PLANING_FORCE))
        n.create_subscription(Float64MultiArray, COMMAND.name,
                              lambda m: self.commands.append(tuple(m.data)), profile(COMMAND))
        self.clocks: list[int] = []
        if clock:
            n.create_subscription(Clock, CLOCK.name, lambda m: self.clocks.append(
                m.clock.sec * 1_000_000_000 + m.clock.nanosec), profile(CLOCK))
        self.command_pub = (n.create_publisher(Float64MultiArray, COMMAND.name, profile(COMMAND))
                            if command_publisher else None)
        self.reset_client = n.create_client(Trigger, 'reset')
        self.params = AsyncParameterClient(n, 'plant')
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(n)
        self._stop = False
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop and self.context.ok():
            self.executor.spin_once(timeout_sec=0.02)
            if self._pending and self._plant_matched():
                pending, self._pending = self._pending, []
                for data in pending:
                    self.publish(data)

    def _plant_matched(self) -> bool:
        # the probe's own command subscription counts as one match
        return self.command_pub.get_subscription_count() >= 2

    def _on_state(self, msg: Float64MultiArray) -> None:
        data = tuple(msg.data)
        with self._lock:
            self.states.append(data)
        if self.answer is not None:
            out = self.answer(data[0], data[1:])
            if out is not None:
                if self._pending or not self._plant_matched():
                    self._pending.append(out)
                else:
                    self.publish(out)

    def publish(self, data: Sequence[float]) -> None:
        self._msg.data = [float(v) for v in data]
        self.command_pub.publish(self._msg)

    def publish_state(self, data: Sequence[float]) -> None:
        """Publish on ``state`` (to test a controller node with bad input)."""
        if not hasattr(self, '_state_pub'):
            self._state_pub = self.node.create_publisher(Float64MultiArray, STATE.name,
                                                         profile(STATE))
            self._state_msg = array_message(STATE)
        self._state_msg.data = [float(v) for v in data]
        self._state_pub.publish(self._state_msg)

    def wait(self, predicate: Callable[[], Any], timeout: float, what: str) -> Any:
        return rosproc.wait_for(predicate, timeout, what=what)

    def result(self, future: Any, timeout: float = 10.0) -> Any:
        rosproc.wait_for(future.done, timeout, what='a service response')
        return future.result()

    def reset_plant(self) -> Trigger.Response:
        rosproc.wait_for(lambda: self.reset_client.service_is_ready(), 10.0,
                         what='the reset service')
        return self.result(self.reset_client.call_async(Trigger.Request()))

    def set_plant_parameters(self, **values: Any) -> list:
        rosproc.wait_for(lambda: self.params.services_are_ready(), 10.0,
                         what='the plant parameter services')
        params = [Parameter(k, value=v) for k, v in values.items()]
        return self.result(self.params.set_parameters(params)).results

    def get_plant_parameters(self, *names: str) -> list:
        return [Parameter.from_parameter_msg(p) if hasattr(Parameter, 'from_parameter_msg')
                else p for p in self.result(self.params.get_parameters(list(names))).values]

    def state_array(self) -> np.ndarray:
        with self._lock:
            return np.array(self.states, dtype=float)

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def bag_messages(bag: Any) -> dict[str, list]:
    """Every message of the bag at ``bag``, decoded, by topic (in recorded order)."""
    from fohssv_sim.bag.loader import scan
    from fohssv_sim.bag.writer import typestore

    sc, ts = scan(bag), typestore()
    out: dict[str, list] = {}
    for cid, _, raw in sc.messages:
        chan = sc.channels[cid]
        out.setdefault(chan.topic, []).append(ts.deserialize_cdr(raw, chan.msgtype))
    return out


def stamp_ns(stamp: Any) -> int:
    """A ``builtin_interfaces/Time`` in nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def batch_samples(model: str, controller: Any, duration: float, control_period: float = 1e-4,
                  **params: Any) -> tuple[np.ndarray, np.ndarray]:
    """The in-process batch run at the published samples: rows [t, z, w, theta, q] and
    [t, Fp], every control period."""
    p = ModelParameters(model=model, **params)
    hold = round(control_period / p.step)
    r = simulate(p, controller, duration, control_period=control_period, sample_every=hold)
    return (np.column_stack([r.t, r.state]), np.column_stack([r.t, r.planing_force]))


def plant_args(**params: Any) -> list[str]:
    """``--ros-args -p k:=v ...`` for the plant."""
    out = ['--ros-args']
    for k, v in params.items():
        if isinstance(v, (list, tuple)):
            v = '[' + ','.join(repr(float(x)) for x in v) + ']'
        out += ['-p', f'{k}:={v}']
    return out


def late_controller(env: dict[str, str], where: Any, answer_delay: float, *settings: str,
                    log: Any = None) -> Any:
    """The generic controller node hosting the test plugin ``late_law`` (tests/examples:
    eq. 31, each answer ``answer_delay`` s of wall time late), registered under ``where`` as
    ``pip install`` would register it, with the ``-p`` ``settings``. At a lockstep plant it
    makes a run last in wall time (a process stopped in its middle, a signal during it) with
    few samples: the controller sleeps, where eq. 31's node at full speed would make the two
    processes spend a quarter of a millisecond of CPU on each sample."""
    dist = Path(where) / 'late_law_example-0.1.dist-info'
    dist.mkdir(exist_ok=True)
    (dist / 'METADATA').write_text('Metadata-Version: 2.1\nName: late-law-example\n'
                                   'Version: 0.1\n')
    (dist / 'entry_points.txt').write_text('[fohssv.controllers]\nlate_law = late_law:LateLaw\n')
    env = dict(env, PYTHONPATH=f"{where}:{EXAMPLES}:{env.get('PYTHONPATH', '')}")
    return rosproc.start('fohssv_controller', 'controller', rosproc.param_args(
        'controller:=late_law', f'answer_delay:={answer_delay}', *settings), env=env, log=log)


def finish(proc: Any, timeout: float) -> tuple[int, str]:
    """Wait for a process to exit by itself; return its code and output."""
    code = rosproc.wait_exit(proc, timeout)
    return code, rosproc.output(proc)


def stop_all(*procs: Any) -> str:
    """Stop processes (SIGINT, then SIGKILL) and return their output."""
    text = []
    for p in procs:
        if p is not None:
            rosproc.stop(p)
            text.append(rosproc.output(p))
    return '\n'.join(text)


def since(t0: float) -> float:
    return time.monotonic() - t0
