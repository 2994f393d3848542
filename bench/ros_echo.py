"""The bare DDS round trip that bench_ros.py compares the lockstep loop with (bench only).

Two processes, each one rclpy node on the executor the product's nodes use
(:func:`fohssv_sim.ros.spin.make_executor`, spun the same way as :func:`spin_until`):

* ``pong`` answers every ``echo_state`` message (a ``std_msgs/Float64MultiArray`` of 5
  doubles, the ``state`` topic's QoS) with one ``echo_command`` message (3 doubles, the
  ``command`` topic's QoS) echoing ``data[0]``, like a controller that computes nothing;
* ``ping`` sends the first message once both directions are matched and answers every echo
  with the next message, like a lockstep plant that integrates and publishes nothing else;
  with ``--announce`` it prints a line ``timing`` when the timed round trips begin (for a
  harness that samples the processes meanwhile, bench_ros.py's threads case);
  with ``--cpu N`` either role pins its process's threads to CPU N once its node, publisher
  and subscription exist, as a node's ``cpu_affinity`` does (bench_ros.py's pinned case);
  with ``--cpu-dma-latency US`` (-1 by default, no request, as the product's nodes)
  either role holds Linux's CPU wake-up latency limit while it runs, as a node's
  ``cpu_dma_latency`` does, where it may (bench_ros.py's latency case compares the two);
  with ``--hops DIR`` it times each round trip as ``bench/hops.py`` times the product's nodes
  (callback entered, answer published; bench_ros.py's hops case; without it the callbacks
  are not wrapped);
  with ``--busy-before US`` / ``--busy-after US`` the ping spins that long (on
  ``perf_counter``, holding the CPU) before / after each publish, as a plant's work before its
  state goes out and after it (docs/ros.md: where the plant's work sits);
  with ``--topics STATE COMMAND`` the two topics are named so instead of ``echo_state`` and
  ``echo_command``: ``--topics state command`` makes the ping a plant that does no work at all
  against a real controller node (bench_ros.py's pinned case: the ceiling of the lockstep
  loop's rate with that controller);
  after ``--count`` round trips it prints one JSON line ``{"round_trips": n, "seconds": s,
  "round_trips_per_second": r, "cpu_dma_latency": the limit held or null}`` and exits.

Messages travel as the product's nodes send and take them: serialized once and written in
place, taken by raw subscriptions and unpacked at their known offset
(:mod:`fohssv_sim.ros.wire`).

    python bench/ros_echo.py pong &
    python bench/ros_echo.py ping --count 20000
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.task import Future
from std_msgs.msg import Float64MultiArray

from fohssv_sim.contract import COMMAND, STATE
from fohssv_sim.ros.host import pin_threads
from fohssv_sim.ros.nodekit import hold_latency
from fohssv_sim.ros.qos import profile
from fohssv_sim.ros.spin import make_executor, spin_until
from fohssv_sim.ros.wire import ArrayReader, ArrayWriter

STATE_TOPIC, COMMAND_TOPIC = 'echo_state', 'echo_command'


def _timed(stamps, callback, publish):
    """``callback`` and ``publish`` as they are, or with ``stamps`` (:class:`hops.Stamps`):
    the callback's entry and the publish's return timed."""
    if stamps is None:
        return callback, publish

    def timed_callback(raw: bytes) -> None:
        stamps.enter()
        callback(raw)

    def timed_publish(payload) -> None:
        publish(payload)
        stamps.answer()

    return timed_callback, timed_publish


def pong(node, stamps=None, topics=(STATE_TOPIC, COMMAND_TOPIC)) -> Future:
    command = ArrayWriter(COMMAND)
    out = command.values
    state = ArrayReader(STATE)
    pub = node.create_publisher(Float64MultiArray, topics[1], profile(COMMAND))

    def on_state(raw: bytes) -> None:
        out[0] = state.read(raw)[0]
        send(command.payload())

    on_state, send = _timed(stamps, on_state, pub.publish)
    node.create_subscription(Float64MultiArray, topics[0], on_state, profile(STATE),
                             raw=True)
    return Future()   # runs until SIGINT


def _busy(seconds: float) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def ping(node, count: int, timeout: float, announce: bool = False, stamps=None,
         before: float = 0.0, after: float = 0.0,
         topics: tuple[str, str] = (STATE_TOPIC, COMMAND_TOPIC)) -> Future:
    done = Future()
    state = ArrayWriter(STATE)
    out = state.values
    command = ArrayReader(COMMAND)
    pub = node.create_publisher(Float64MultiArray, topics[0], profile(STATE))
    n = 0
    start = 0.0

    def on_echo(raw: bytes) -> None:
        nonlocal n
        command.read(raw)
        n += 1
        if n >= count:
            seconds = time.perf_counter() - start
            done.set_result({'round_trips': n, 'seconds': seconds,
                             'round_trips_per_second': n / seconds})
            return
        out[0] = n * 1e-4
        if before:
            _busy(before)
        send(state.payload())
        if after:
            _busy(after)

    on_echo, send = _timed(stamps, on_echo, pub.publish)
    sub = node.create_subscription(Float64MultiArray, topics[1], on_echo, profile(COMMAND),
                                   raw=True)
    began = time.monotonic()

    matched_at: float | None = None

    def wait_for_peer() -> None:
        # both directions matched on this side, then 0.5 s for the peer's side of the
        # matches (the echo topic is volatile: an echo sent before its writer matched is lost)
        nonlocal start, matched_at
        if pub.get_subscription_count() > 0 and sub.get_publisher_count() > 0:
            if matched_at is None:
                matched_at = time.monotonic()
            if time.monotonic() - matched_at < 0.5:
                return
            node.destroy_timer(timer)
            if announce:     # for a harness that samples the processes while the loop runs
                print('timing', flush=True)
            start = time.perf_counter()
            send(state.payload())
        elif time.monotonic() - began > timeout:
            node.destroy_timer(timer)
            done.set_result({'error': f'no echo peer within {timeout:g} s'})

    timer = node.create_timer(0.01, wait_for_peer)
    return done


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('role', choices=('ping', 'pong'))
    ap.add_argument('--count', type=int, default=20000)
    ap.add_argument('--timeout', type=float, default=30.0, help='wait for the peer (s)')
    ap.add_argument('--announce', action='store_true',
                    help="ping: print a line 'timing' when the timed round trips begin")
    ap.add_argument('--cpu', type=int, default=None,
                    help="pin the process's threads to this CPU (as cpu_affinity does)")
    ap.add_argument('--cpu-dma-latency', type=int, default=-1, metavar='US',
                    help="hold this CPU wake-up latency limit (us) while the process runs, as "
                         "a node's cpu_dma_latency does; -1 (the default, as theirs): none")
    ap.add_argument('--busy-before', type=float, default=0.0, metavar='US',
                    help='ping: spin this long before each publish (work on the round trip)')
    ap.add_argument('--busy-after', type=float, default=0.0, metavar='US',
                    help='ping: spin this long after each publish (work beside it)')
    ap.add_argument('--hops', metavar='DIR', default=None,
                    help='time each round trip as bench/hops.py does, saved in DIR')
    ap.add_argument('--topics', nargs=2, metavar=('STATE', 'COMMAND'),
                    default=(STATE_TOPIC, COMMAND_TOPIC),
                    help='the two topics (default: echo_state echo_command; state command: '
                         'the ping plays a plant that does no work against a controller node)')
    a = ap.parse_args()
    stamps = None
    if a.hops is not None:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'tools' / 'diag'))
        from hops import Stamps  # tools/diag/hops.py
        stamps = Stamps(a.hops, a.role)
    rclpy.init()
    node = rclpy.create_node(f'echo_{a.role}')
    done = (ping(node, a.count, a.timeout, a.announce, stamps, a.busy_before * 1e-6,
                 a.busy_after * 1e-6, tuple(a.topics)) if a.role == 'ping'
            else pong(node, stamps, tuple(a.topics)))
    if a.cpu is not None:
        pin_threads((a.cpu,))
    held = hold_latency(node, a.cpu_dma_latency)     # as the nodes: said in one line either way
    executor = make_executor()
    executor.add_node(node)
    try:
        spin_until(executor, done)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    print(json.dumps({**done.result(), 'cpu_dma_latency': held}), flush=True)
    return 1 if 'error' in done.result() else 0


if __name__ == '__main__':
    sys.exit(main())
