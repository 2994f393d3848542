"""The plant's compiled lockstep sample (fohssv_sim.ros.compiled_sample) against the interpreted
short path it replaces (models.HeldPeriod.run, as the node ran it before): on two FOM plants
under eq. 31, the same state, time, step counts and planing force after every period, bit for
bit, and the state it publishes through rcl, received over real DDS by a subscription, equal
to the interpreted sample; every command it must not take is left alone (nothing published,
the model untouched); a failing period raises what the interpreted path raises."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64MultiArray

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.contract import COMMAND, STATE
from fohssv_sim.params import ModelParameters
from fohssv_sim.ros.compiled_sample import FAILED, NOT_TAKEN, CompiledSample
from fohssv_sim.ros.loop import SampledPlant
from fohssv_sim.ros.qos import profile
from fohssv_sim.ros.wire import ArrayReader, ArrayWriter

import rosproc

X_START = (0.0, 1.5, 0.0, 0.0)     # w beyond the contact velocity: planing from the start
LIMIT = 0.5                        # rad, both deflections (as the plant's options)


class _Graph:
    """One node with the state publisher the compiled sample publishes on and a raw
    subscription that collects what arrives."""

    def __init__(self) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=rosproc.unique_domain_id())
        self.node = rclpy.create_node('compiled_sample_test', context=self.context)
        self.pub = self.node.create_publisher(Float64MultiArray, 'state', profile(STATE))
        self.got: list[bytes] = []
        self.node.create_subscription(Float64MultiArray, 'state', self.got.append,
                                      profile(STATE), raw=True)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.until(lambda: self.pub.get_subscription_count() == 1, 'the subscription matched')

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


def test_compiled_sample_equals_the_interpreted_path_and_publishes_its_state(graph):
    a, b, held_a, held_b, sa, fa, fb, out = _plants()
    compiled = CompiledSample.build(held_b, out, ArrayReader(COMMAND), graph.pub.handle.pointer)
    assert not isinstance(compiled, str), compiled
    compiled.limit(LIMIT, LIMIT)
    assert not compiled.arm(0.0)                   # the kernel call is not bound yet
    _general(a, (0.0, 0.0), sa, fa)
    _general(b, (0.0, 0.0), out.values, fb)
    reader = ArrayReader(STATE)
    ctl = StateFeedback()
    refused = 0
    for k in range(300):
        u = ctl.command(0.0, tuple(sa[1:]))
        awaited = b.t
        assert compiled.arm(awaited)
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
            assert compiled.arm(awaited)
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
            assert (b.plant.x, b.plant.n, b.plant._stepper.n, list(out.values)) == before
        _interpreted(a, held_a, u, sa, fa)
        assert _compiled(b, held_b, compiled, u, good, out.values, fb) == 5, k
        # taken once: the same command again is not (disarmed until the next sample)
        assert compiled.call(good, len(good)) == NOT_TAKEN
        assert list(out.values) == sa and fb == fa, k
        assert _same(a, b), k
        graph.until(lambda n=k + 1: len(graph.got) == n, f'sample {k} received')
        assert reader.read(graph.got[-1]) == tuple(sa), k
    assert compiled.taken == 300 and refused == 50
    assert compiled.rcl_ret == 0
    assert abs(sa[2]) > 0.1 and a.plant._stepper.n == 301 * 5     # a trajectory that moved


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
    compiled = CompiledSample.build(held_b, out, ArrayReader(COMMAND), graph.pub.handle.pointer)
    assert not isinstance(compiled, str), compiled
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
