"""The serialized fast path of the nodes (fohssv_sim.ros.wire) against rclpy's own
serialization: the same bytes out, the same numbers in, and any other layout through rclpy."""

from __future__ import annotations

import array
import math

import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray

from fohssv_sim.contract import COMMAND, PLANING_FORCE, STATE
from fohssv_sim.ros.nodekit import array_message
from fohssv_sim.ros.wire import ArrayReader, ArrayWriter, ClockWriter

TOPICS = [STATE, PLANING_FORCE, COMMAND]
VALUES = [0.1 * 3, -1e-300, math.pi, 2.0**-1074, -0.0]


@pytest.mark.parametrize('topic', TOPICS, ids=lambda t: t.name)
def test_writer_sends_exactly_what_publishing_the_message_would(topic):
    n = len(topic.fields)
    w = ArrayWriter(topic)
    for i, v in enumerate(VALUES[:n]):
        w.values[i] = v
    msg = array_message(topic)
    msg.data = array.array('d', VALUES[:n])
    got = deserialize_message(w.payload(), Float64MultiArray)
    assert list(got.data) == VALUES[:n]
    assert got.layout.dim[0].label == topic.label and got.layout.dim[0].size == n
    # the same message, field for field, as rclpy's serialization of the message object
    ref = deserialize_message(serialize_message(msg), Float64MultiArray)
    assert got == ref


@pytest.mark.parametrize('topic', TOPICS, ids=lambda t: t.name)
def test_reader_fast_path_reads_the_serialized_doubles(topic):
    n = len(topic.fields)
    msg = array_message(topic)
    msg.data = array.array('d', VALUES[:n])
    got = ArrayReader(topic).read(serialize_message(msg))
    assert isinstance(got, tuple)             # the fast path
    assert list(got) == VALUES[:n]


@pytest.mark.parametrize('data', [[], [1.0, 2.0], [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]])
def test_reader_passes_other_lengths_to_rclpy(data):
    msg = array_message(COMMAND)
    msg.data = array.array('d', data)
    got = ArrayReader(COMMAND).read(serialize_message(msg))
    assert list(got) == data


def test_reader_passes_other_layouts_to_rclpy():
    msg = Float64MultiArray()                 # no layout: what a hand-written publisher sends
    msg.data = [1.0, 2.0, 3.0]
    got = ArrayReader(COMMAND).read(serialize_message(msg))
    assert list(got) == [1.0, 2.0, 3.0] and not isinstance(got, tuple)
    msg = array_message(COMMAND)
    msg.layout.dim[0].label = 'a different label'
    msg.data = [4.0, 5.0, 6.0]
    assert list(ArrayReader(COMMAND).read(serialize_message(msg))) == [4.0, 5.0, 6.0]


@pytest.mark.parametrize('ns', [0, 1, 999_999_999, 1_000_000_000, 123_456_789_012, 2**31 * 10**9
                                - 1])
def test_clock_writer_matches_time_to_msg(ns):
    sec, nanosec = divmod(ns, 1_000_000_000)
    assert ClockWriter().payload(ns) == serialize_message(
        Clock(clock=Time(sec=sec, nanosec=nanosec)))
