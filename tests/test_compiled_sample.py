"""The plant's compiled lockstep sample (fohssv_sim.ros.plant.fastpath) against the interpreted
short path it replaces (models.HeldPeriod.run, as the node ran it before): on two FOM plants
under eq. 31, the same state, time, step counts and planing force after every period, bit for
bit, and the state, planing force and clock it publishes through rcl, received over real DDS
by subscriptions, equal to the interpreted sample's messages serialized by rclpy's path
(wire.py); the records it puts into an in-plant ring, read back by the writer's side
(bag.ring.Ring.take), equal to those messages and the command's bytes, across the ring's
wraps, and stopping at a full ring where Ring.put would; every command it must not take is
left alone (nothing published, the model untouched); a failing period raises what the
interpreted path raises. Taken in compiled code (CompiledSample.take_from: rcl's wait and
take, then the sample), commands published over real DDS give the same samples; what it does
not take is handed over byte for byte; a wait with nothing to take times out."""

from __future__ import annotations

import ctypes
import math
import time

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.bag.ring import MIN_RING_BYTES, Ring
from fohssv_sim.contract import CLOCK, COMMAND, PLANING_FORCE, STATE
from fohssv_sim.params import ModelParameters
from fohssv_sim.ros.loop import SampledPlant
from fohssv_sim.ros.plant.fastpath.sample import (
    CLOCK_PUBLISH,
    CLOCK_PUT,
    FAILED,
    FORCE_REFUSED,
    NOT_TAKEN,
    RCL_ERROR,
    TIMED_OUT,
    CompiledSample,
)
from fohssv_sim.ros.qos import profile
from fohssv_sim.ros.wire import ArrayReader, ArrayWriter, ClockWriter

import rosproc

X_START = (0.0, 1.5, 0.0, 0.0)     # w beyond the contact velocity: planing from the start
LIMIT = 0.5                        # rad, both deflections (as the plant's options)


class _Graph:
    """One node with the publishers the compiled sample publishes on (state, planing force,
    clock) and raw subscriptions that collect what arrives."""

    def __init__(self) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=rosproc.unique_domain_id())
        self.node = rclpy.create_node('compiled_sample_test', context=self.context)
        self.pub = self.node.create_publisher(Float64MultiArray, 'state', profile(STATE))
        self.force_pub = self.node.create_publisher(Float64MultiArray, 'planing_force',
                                                    profile(PLANING_FORCE))
        self.clock_pub = self.node.create_publisher(Clock, 'clock', profile(CLOCK))
        self.got: list[bytes] = []
        self.forces: list[bytes] = []
        self.clocks: list[bytes] = []
        self.node.create_subscription(Float64MultiArray, 'state', self.got.append,
                                      profile(STATE), raw=True)
        self.node.create_subscription(Float64MultiArray, 'planing_force', self.forces.append,
                                      profile(PLANING_FORCE), raw=True)
        # /clock is keep-last 1: the test waits for each one before the next
        self.node.create_subscription(Clock, 'clock', self.clocks.append, profile(CLOCK),
                                      raw=True)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.until(lambda: all(p.get_subscription_count() == 1
                               for p in (self.pub, self.force_pub, self.clock_pub)),
                   'the subscriptions matched')

    def build(self, held, out: ArrayWriter) -> tuple[CompiledSample, ArrayWriter, ClockWriter]:
        force, clock = ArrayWriter(PLANING_FORCE), ClockWriter()
        compiled = CompiledSample.build(held, out, ArrayReader(COMMAND), self.pub.handle.pointer,
                                        (force, self.force_pub.handle.pointer),
                                        (clock, self.clock_pub.handle.pointer))
        assert not isinstance(compiled, str), compiled
        return compiled, force, clock

    def until(self, predicate, what: str, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, what
            self.executor.spin_once(timeout_sec=0.01)

    def quiet(self, seconds: float = 0.05) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@pytest.fixture()
def graph():
    g = _Graph()
    yield g
    g.close()


def _interpreted(sim, held, u, state, force) -> None:
    """One period as the node's interpreted short path runs it."""
    sim.command = u
    assert held.run(*u)
    force[1] = held.settle()
    force[0] = state[0]
    sim.took(u)


def _general(sim, u, state, force) -> None:
    """One period the general way (binds the model's kernel call)."""
    sim.command = u
    sim.advance()
    sim.write_sample(state, force)


def _compiled(sim, held, compiled, u, raw, state, force) -> int:
    code = compiled.call(raw, len(raw))
    if code >= 0:
        sim.command = u
        assert held.finish(code, *u)
        force[1] = held.settle()
        force[0] = state[0]
        sim.took(u)
    return code


def _command(t: float, df: float, dc: float) -> bytes:
    w = ArrayWriter(COMMAND)
    w.values[0], w.values[1], w.values[2] = t, df, dc
    return w.payload()


def _plants(start=X_START):
    p = ModelParameters()
    a, b = (SampledPlant(p, 1e-4, start, duration=1.0) for _ in range(2))
    sa, fa, fb = [0.0] * 5, [0.0] * 2, [0.0] * 2
    out = ArrayWriter(STATE)                   # b's state message, written in place
    return a, b, a.held_period(sa), b.held_period(out.values), sa, fa, fb, out


def _same(a, b) -> tuple:
    return ((b.samples, b.t, b.plant.n, b.plant.x, b.plant.planing_force, b.plant._stepper.n)
            == (a.samples, a.t, a.plant.n, a.plant.x, a.plant.planing_force,
                a.plant._stepper.n))


def _messages(out: ArrayWriter, force: ArrayWriter, raw: bytes, t: float
              ) -> tuple[bytes, bytes, bytes, bytes]:
    """The sample's messages as the interpreted path publishes and records them: the state's
    and the planing force's messages (``payload()``: their bytes, alignment padding
    included), the command as received and the clock serialized for ``t`` by wire.py."""
    return out.payload(), raw, force.payload(), ClockWriter().payload(round(t * 1e9))


def _values(records: list[tuple[int, bytes]]) -> list:
    """The records' contents read back: the doubles of the state, the command and the
    planing force, the clock's (sec, nanosec)."""
    readers = {0: ArrayReader(STATE), 1: ArrayReader(COMMAND), 2: ArrayReader(PLANING_FORCE)}
    return [readers[i].read(data) if i in readers else divmod(
        deserialize_message(data, Clock).clock.sec * 10**9
        + deserialize_message(data, Clock).clock.nanosec, 10**9) for i, data in records]


def _clock(k: int) -> int:
    """What the sample ``k`` asks of its clock: every combination in turn."""
    return (0, CLOCK_PUT, CLOCK_PUBLISH, CLOCK_PUBLISH | CLOCK_PUT)[k % 4]


def _records(ring: Ring) -> list[tuple[int, bytes]]:
    """The records the ring holds, as the in-plant writer takes them (then released)."""
    records = [(i, bytes(v)) for i, v in ring.take()]
    ring.release()
    return records


def test_compiled_sample_equals_the_interpreted_path_and_publishes_its_state(graph):
    a, b, held_a, held_b, sa, fa, fb, out = _plants()
    compiled, force_out, _ = graph.build(held_b, out)
    ring = Ring.create(MIN_RING_BYTES)         # about 15 samples' records: it wraps often
    compiled.record_into(ring, 0, 1, 2, 3)
    compiled.limit(LIMIT, LIMIT)
    assert not compiled.arm(0.0)                   # the kernel call is not bound yet
    _general(a, (0.0, 0.0), sa, fa)
    _general(b, (0.0, 0.0), out.values, fb)
    reader, force_reader = ArrayReader(STATE), ArrayReader(PLANING_FORCE)
    ctl = StateFeedback()
    refused = clocks = 0
    for k in range(300):
        u = ctl.command(0.0, tuple(sa[1:]))
        awaited = b.t
        assert compiled.arm(awaited, _clock(k))
        good = _command(awaited, *u)
        if k % 60 == 7:
            # commands it must leave to the interpreted path, each with nothing done
            bad = [_command(awaited + 1e-4, *u), _command(awaited - 1e-4, *u),
                   _command(awaited, LIMIT * 1.001, u[1]), _command(awaited, u[0], -0.6),
                   _command(awaited, math.nan, u[1]), _command(math.nan, *u),
                   good[:-1], good + b'\0', good[:5] + b'\7' + good[6:]]
            count_at = ArrayReader(COMMAND).layout()[1]
            bad.append(good[:count_at] + b'\4' + good[count_at + 1:])
            before = (b.plant.x, b.plant.n, b.plant._stepper.n, list(out.values))
            for raw in bad:
                assert _compiled(b, held_b, compiled, u, raw, out.values, fb) == NOT_TAKEN
                refused += 1
            compiled.disarm()
            assert _compiled(b, held_b, compiled, u, good, out.values, fb) == NOT_TAKEN
            assert compiled.arm(awaited, _clock(k))
            # limits lowered while armed (a parameter change): the awaited command beyond them
            # (0.3 rad is within LIMIT: only the new limit refuses it)
            compiled.limit(0.2, LIMIT)
            raw = _command(awaited, 0.3, u[1])
            assert _compiled(b, held_b, compiled, u, raw, out.values, fb) == NOT_TAKEN
            compiled.limit(LIMIT, 0.2)
            raw = _command(awaited, u[0], -0.3)
            assert _compiled(b, held_b, compiled, u, raw, out.values, fb) == NOT_TAKEN
            compiled.limit(LIMIT, LIMIT)
            graph.quiet()
            assert len(graph.got) == k, 'a command it did not take published a state'
            assert len(graph.forces) == k and len(graph.clocks) == clocks
            assert ring.used == 0, 'a command it did not take put a record'
            assert (b.plant.x, b.plant.n, b.plant._stepper.n, list(out.values)) == before
        _interpreted(a, held_a, u, sa, fa)
        assert _compiled(b, held_b, compiled, u, good, out.values, fb) == 5, k
        # taken once: the same command again is not (disarmed until the next sample)
        assert compiled.call(good, len(good)) == NOT_TAKEN
        assert list(out.values) == sa and fb == fa, k
        assert _same(a, b), k
        state, command, force, clock = _messages(out, force_out, good, sa[0])
        clocks += bool(_clock(k) & CLOCK_PUBLISH)
        graph.until(lambda n=k + 1, c=clocks: len(graph.got) == n == len(graph.forces)
                    and len(graph.clocks) == c, f'sample {k} received')
        assert reader.read(graph.got[-1]) == tuple(sa), k
        assert force_reader.read(graph.forces[-1]) == tuple(fa), k
        if _clock(k) & CLOCK_PUBLISH:
            assert graph.clocks[-1][:12] == clock, k
        want = [(0, state), (1, command), (2, force)] + (
            [(3, clock)] if _clock(k) & CLOCK_PUT else [])
        assert compiled.put == compiled.records == len(want) and _records(ring) == want, k
        ns = round(sa[0] * 1e9)
        assert _values(want) == [tuple(sa), (awaited, *u), tuple(fa), divmod(ns, 10**9)][
            :len(want)], k
    assert compiled.taken == 300 and refused == 50
    # each period prepared after the sample before it but the first and those armed twice
    # (k % 60 == 7: the second arm cannot know what ran in between)
    assert compiled.prepared == 300 - 1 - 5
    assert compiled.rcl_ret == compiled.force_ret == compiled.clock_ret == 0
    assert clocks == 150 and ring.lost == 0 and ring.consumed > 15 * ring.capacity   # wrapped
    assert abs(sa[2]) > 0.1 and a.plant._stepper.n == 301 * 5     # a trajectory that moved
    compiled.record_into(None)
    ring.close()


def test_compiled_sample_stops_putting_at_a_full_ring_where_ring_put_would(graph):
    """A ring with no room for the whole sample: the compiled sample still publishes, puts the
    records that fit (in order, none cut) and says how many (the node puts the rest, the
    interpreted way, once the writer made room: Ring.put after it goes on where it stopped)."""
    a, b, held_a, held_b, sa, fa, fb, out = _plants()
    compiled, force_out, _ = graph.build(held_b, out)
    ring = Ring.create(MIN_RING_BYTES)
    compiled.record_into(ring, 0, 1, 2, 3)
    compiled.limit(LIMIT, LIMIT)
    _general(a, (0.0, 0.0), sa, fa)
    _general(b, (0.0, 0.0), out.values, fb)
    ctl = StateFeedback()
    held: list[tuple[int, bytes]] = []       # what the ring holds, as Ring.take will read it
    partial = 0
    for k in range(60):
        u = ctl.command(0.0, tuple(sa[1:]))
        assert compiled.arm(b.t, CLOCK_PUT)
        good = _command(b.t, *u)
        _interpreted(a, held_a, u, sa, fa)
        assert _compiled(b, held_b, compiled, u, good, out.values, fb) == 5, k
        graph.until(lambda n=k + 1: len(graph.got) == n == len(graph.forces),
                    f'sample {k} published')
        want = list(enumerate(_messages(out, force_out, good, sa[0])))
        assert compiled.records == 4, k
        held += want[:compiled.put]
        if compiled.put < 4:              # full: the node's interpreted put, after room
            partial += 1
            assert ring.capacity - ring.used < 2 * 96, 'refused with room to spare'
            assert _records(ring) == held, k
            held = []
            for index, data in want[compiled.put:]:
                assert ring.put(index, data)
            held += want[compiled.put:]
    assert partial >= 3 and _records(ring) == held
    compiled.record_into(None)
    ring.close()


@pytest.mark.parametrize('start, u, error', [
    ((0.0, 0.0, 1.5, 40.0), (0.0, 0.0), r'state beyond physical bounds at t='),
    (X_START, (1e308, 1e308), r'state became non-finite at t='),
])
def test_compiled_sample_fails_where_the_interpreted_path_fails_with_its_words(graph, start, u,
                                                                              error):
    """A period that leaves the bounds or turns non-finite (deflections of 1e308 rad, within
    the limits it is armed with here) publishes nothing and returns a failure code; the node's
    :meth:`HeldPeriod.finish` then raises what the interpreted path raises, at the same sample,
    with the same text, the plant failed and counted as there."""
    a, b, held_a, held_b, sa, fa, fb, out = _plants(start)
    compiled, _, _ = graph.build(held_b, out)
    _general(a, (0.0, 0.0), sa, fa)
    _general(b, (0.0, 0.0), out.values, fb)
    with pytest.raises(FloatingPointError, match=error) as ia:
        for _ in range(1000):
            a.command = u
            try:
                assert held_a.run(*u)
            except FloatingPointError as exc:
                a.failed_period(exc)
                raise
            held_a.settle()
            a.took(u)
    compiled.limit(math.inf, math.inf)
    with pytest.raises(FloatingPointError, match=error) as ib:
        for _ in range(1000):
            assert compiled.arm(b.t)
            raw = _command(b.t, *u)
            code = _compiled(b, held_b, compiled, u, raw, out.values, fb)
            if code < 0:
                assert code <= FAILED, code
                b.command = u
                try:
                    held_b.finish(FAILED - code, *u)
                except FloatingPointError as exc:
                    b.failed_period(exc)
                    raise
                raise AssertionError('finish() did not raise for a failed period')
    assert (str(ib.value), type(ib.value), b.samples, b.plant.n, b.plant.status) == (
        str(ia.value), type(ia.value), a.samples, a.plant.n, a.plant.status)
    assert b.plant.status == 'failed'
    graph.quiet()
    assert len(graph.got) == compiled.taken    # the failed period published nothing
    assert np.array_equal(b.plant.x, a.plant.x, equal_nan=True)


def test_compiled_sample_reports_a_refused_planing_force_or_clock_and_records_neither(graph):
    """rcl refusing the planing force's publish (here: a publisher rcl finds invalid, its
    ``impl`` NULL) after the state went out: FORCE_REFUSED, rcl's return and error text kept
    for the node's retry, the state's and the command's records put, no clock; rcl refusing
    the clock: the sample stands, the clock is reported and not recorded (as a clock the
    interpreted path could not publish)."""
    invalid = ctypes.create_string_buffer(64)        # an rcl_publisher_t with impl NULL
    for refused in ('force', 'clock'):
        a, b, held_a, held_b, sa, fa, fb, out = _plants()
        force_w, clock_w = ArrayWriter(PLANING_FORCE), ClockWriter()
        force_pub = ctypes.addressof(invalid) if refused == 'force' else (
            graph.force_pub.handle.pointer)
        clock_pub = ctypes.addressof(invalid) if refused == 'clock' else (
            graph.clock_pub.handle.pointer)
        compiled = CompiledSample.build(held_b, out, ArrayReader(COMMAND),
                                        graph.pub.handle.pointer, (force_w, force_pub),
                                        (clock_w, clock_pub))
        assert not isinstance(compiled, str), compiled
        ring = Ring.create(MIN_RING_BYTES)
        compiled.record_into(ring, 0, 1, 2, 3)
        compiled.limit(LIMIT, LIMIT)
        _general(a, (0.0, 0.0), sa, fa)
        _general(b, (0.0, 0.0), out.values, fb)
        states = len(graph.got)
        assert compiled.arm(b.t, CLOCK_PUBLISH | CLOCK_PUT)
        u = (0.01, -0.01)
        good = _command(b.t, *u)
        code = compiled.call(good, len(good))
        graph.until(lambda n=states + 1: len(graph.got) == n, 'the state received')
        if refused == 'force':
            assert code == FORCE_REFUSED and compiled.force_ret != 0
            assert 'invalid' in compiled.take_error().lower()
            assert [i for i, _ in _records(ring)] == [0, 1]
            assert compiled.put == compiled.records == 2
        else:
            assert code == 5 and compiled.force_ret == 0 and compiled.clock_ret != 0
            assert 'invalid' in compiled.take_error().lower()
            assert [i for i, _ in _records(ring)] == [0, 1, 2]
            assert compiled.put == compiled.records == 3
        assert compiled.rcl_ret == 0
        compiled.record_into(None)
        ring.close()


def test_compiled_take_takes_the_awaited_command_over_dds_and_hands_over_the_rest(graph):
    """The plant's lockstep loop with commands taken in compiled code: commands published
    by another node's publisher over DDS, taken by rcl from a subscription no executor
    spins (a second node), the awaited one run by the compiled sample with the same result
    as the interpreted path, bit for bit, its state received by a subscriber; a command it
    must not take (another t, one while disarmed) returned as NOT_TAKEN with its bytes as
    published (one longer than the take's first buffer too); nothing to take: TIMED_OUT
    after the timeout (not before), at once with none."""
    a, b, held_a, held_b, sa, fa, fb, out = _plants()
    compiled, _, _ = graph.build(held_b, out)
    compiled.limit(LIMIT, LIMIT)
    taker = rclpy.create_node('compiled_take_test', context=graph.context)   # not spun
    try:
        sub = taker.create_subscription(Float64MultiArray, 'command', lambda raw: None,
                                        profile(COMMAND), raw=True)
        pub = graph.node.create_publisher(Float64MultiArray, 'command', profile(COMMAND))
        graph.until(lambda: pub.get_subscription_count() == 1 == sub.get_publisher_count(),
                    'the command topic matched')
        assert compiled.take_from(graph.context.handle.pointer, sub.handle.pointer, 0.3) is None
        begin = time.monotonic()
        assert compiled.take() == TIMED_OUT
        assert 0.25 <= time.monotonic() - begin < 10.0
        _general(a, (0.0, 0.0), sa, fa)
        _general(b, (0.0, 0.0), out.values, fb)
        ctl = StateFeedback()
        compiled.set_timeout(10.0)       # a message within it returns at once
        for k in range(100):
            u = ctl.command(0.0, tuple(sa[1:]))
            awaited = b.t
            good = _command(awaited, *u)
            if k % 25 == 3:
                compiled.disarm()        # not armed: taken by rcl, left to the node
                pub.publish(good)
                assert compiled.take() == NOT_TAKEN and compiled.received() == good
            assert compiled.arm(awaited)
            if k % 25 == 4:
                late = _command(awaited - 1e-4, *u)
                pub.publish(late)
                assert compiled.take() == NOT_TAKEN and compiled.received() == late
            if k % 25 == 5:
                # longer than the take's first buffer (256 B) and each time longer than
                # the last: rmw grows the buffer, maybe elsewhere; the compiled sample
                # leaves the wrong length, handed over whole, and the next command is
                # read from the buffer's new place
                extra = range(40 * (1 + k // 25))
                long = serialize_message(Float64MultiArray(data=[awaited, *u, *extra]))
                assert len(long) > 256
                pub.publish(long)
                assert compiled.take() == NOT_TAKEN and compiled.received() == long
            pub.publish(good)
            code = compiled.take()
            assert code == 5 and compiled.received() == good, k
            b.command = u
            assert held_b.finish(code, *u)
            fb[1] = held_b.settle()
            fb[0] = out.values[0]
            b.took(u)
            _interpreted(a, held_a, u, sa, fa)
            assert list(out.values) == sa and fb == fa and _same(a, b), k
            graph.until(lambda n=k + 1: len(graph.got) == n, f'sample {k} received')
            assert ArrayReader(STATE).read(graph.got[-1]) == tuple(sa), k
        assert compiled.taken == 100
        compiled.set_timeout(0.0)
        begin = time.monotonic()
        assert compiled.take() == TIMED_OUT and time.monotonic() - begin < 0.2
        assert compiled.detach_listener() == 0
        compiled.close()
        assert compiled.take is None
        assert abs(sa[2]) > 0.01           # a trajectory that moved
        assert RCL_ERROR not in (NOT_TAKEN, TIMED_OUT) and min(RCL_ERROR, TIMED_OUT) > FAILED
    finally:
        taker.destroy_node()


class _Loop:
    """A lockstep loop in one process, one executor: the plant node (the FOM, an external
    controller), eq. 31's law as a controller node answering each state, and a probe that
    keeps every state and planing force message as it arrives (bytes)."""

    def __init__(self, compiled: bool, duration: float) -> None:
        from rclpy.parameter import Parameter

        from fohssv_sim.ros.plant_node import PlantNode
        from fohssv_sim.ros.wire import raw_publish

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=rosproc.unique_domain_id())
        self.plant = PlantNode(context=self.context, parameter_overrides=[
            Parameter('model', value='fractional'), Parameter('duration', value=duration),
            Parameter('end_linger', value=0.0), Parameter('view_period', value=0.0)])
        if not compiled:                 # the interpreted path, as where none can be built
            self.plant._compiled = None
        self.built = self.plant._compiled is not None
        self.node = rclpy.create_node('loop_test', context=self.context)
        law, state_in, out = StateFeedback(), ArrayReader(STATE), ArrayWriter(COMMAND)
        send = raw_publish(self.node.create_publisher(Float64MultiArray, 'command',
                                                      profile(COMMAND)))

        def answer(raw: bytes) -> None:
            t, *x = state_in.read(raw)
            out.values[0] = t
            out.values[1], out.values[2] = law.command(t, x)
            send(out.payload())

        self.states: list[bytes] = []
        self.forces: list[bytes] = []
        self.node.create_subscription(Float64MultiArray, 'state', answer, profile(STATE),
                                      raw=True)
        self.node.create_subscription(Float64MultiArray, 'state', self.states.append,
                                      profile(STATE), raw=True)
        self.node.create_subscription(Float64MultiArray, 'planing_force', self.forces.append,
                                      profile(PLANING_FORCE), raw=True)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.plant)
        self.executor.add_node(self.node)

    def run(self, timeout: float = 120.0) -> dict:
        deadline = time.monotonic() + timeout
        while not self.plant.finished.done():
            assert time.monotonic() < deadline, 'the loop did not end'
            self.executor.spin_once(timeout_sec=0.01)
        end = time.monotonic() + 0.5                  # the last messages to the probe
        while time.monotonic() < end and len(self.forces) < self.plant.sent:
            self.executor.spin_once(timeout_sec=0.01)
        return self.plant.summary()

    def close(self) -> None:
        self.executor.shutdown()
        self.plant.destroy_node()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@pytest.mark.node
@pytest.mark.parametrize('refuse', ['', '150:3', '150'],
                         ids=['clean', 'refused-3-times', 'refused-for-good'])
def test_the_plant_node_sends_the_same_samples_and_counts_compiled_or_interpreted(
        monkeypatch, refuse):
    """One contract for both paths of the plant's lockstep sample: the same lockstep run
    (0.03 s of the FOM under eq. 31, 300 samples) through the compiled fast path and
    through the interpreted path gives the same state and planing force messages, the same
    exit code and the same counts, also when FOHSSV_FAULT_REFUSE_STATE refuses the
    state publish (retried; for good: exit 9 after the 1 s of retries)."""
    from fohssv_sim.ros.faults import REFUSE_STATE_VAR
    from fohssv_sim.ros.plant_node import EXIT_OK, EXIT_PUBLISH_FAILED

    if refuse:
        monkeypatch.setenv(REFUSE_STATE_VAR, refuse)
    runs = {}
    for compiled in (True, False):
        loop = _Loop(compiled, duration=0.03)
        try:
            summary = loop.run()
            runs[compiled] = (loop.built, loop.plant.exit_code, summary, loop.states,
                              loop.forces)
        finally:
            loop.close()
    built, code, s, states, forces = runs[True]
    _, code_i, s_i, states_i, forces_i = runs[False]
    assert built
    assert code == code_i == (EXIT_PUBLISH_FAILED if refuse == '150' else EXIT_OK)
    n = 151 if refuse == '150' else 301        # states out: t = 0 and one per period
    keys = ('published_states', 'publish_retries', 'samples', 'steps', 't',
            'rejected_commands', 'ignored_commands')
    assert {k: s[k] for k in keys} == {k: s_i[k] for k in keys}, (s, s_i)
    assert s['published_states'] == n - (1 if refuse == '150' else 0)
    assert s['publish_retries'] == (1 if refuse else 0)
    assert s['compiled_samples'] >= s['samples'] - 1 > 0 and s_i['compiled_samples'] == 0
    assert len(states) == len(states_i) == s['published_states']
    # the values, bit for bit (the raw CDR differs in its unzeroed alignment padding)
    for got, got_i, kind in ((states, states_i, STATE), (forces, forces_i, PLANING_FORCE)):
        read = ArrayReader(kind).read
        assert np.array_equal(np.array([read(r) for r in got]),
                              np.array([read(r) for r in got_i]))
