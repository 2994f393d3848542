"""The bytes the plant publishes (and so records) are a function of the message: the CDR
alignment padding, which rclpy's serializer leaves as its buffer held it (fragments of the
process's memory), is zero. No ROS graph: rclpy's serializer in this process.

The padding of the contract's Float64MultiArray is located here by the CDR rules (XCDR1:
each primitive aligned to its size from the end of the 4-byte encapsulation header), not by
the code under test.
"""

from __future__ import annotations

import struct

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import Marker

from fohssv_sim import contract
from fohssv_sim.ros.views import _marker, _Serialized
from fohssv_sim.ros.wire import ArrayWriter, serialized


def _padding(topic: contract.Topic) -> list[int]:
    """Offsets of the padding bytes of ``topic``'s Float64MultiArray (one dimension)."""
    label = len(topic.label) + 1                      # with its NUL
    pos = 4 + 4 + 4 + label                           # header, dim count, label length, label
    pads = list(range(pos, 4 + ((pos - 4 + 3) & ~3)))
    pos = 4 + ((pos - 4 + 3) & ~3) + 4 * 4            # size, stride, data_offset, count
    pads += list(range(pos, 4 + ((pos - 4 + 7) & ~7)))
    return pads


def _churn() -> None:
    """Leave freed, non-zero memory where the serializer may allocate next."""
    junk = [bytes([0xA5]) * n for n in range(1, 600, 3)]
    del junk


@pytest.mark.parametrize('topic', [contract.STATE, contract.PLANING_FORCE, contract.COMMAND])
def test_the_contract_messages_have_zero_padding(topic):
    pads = _padding(topic)
    assert pads, 'this layout has padding to check'
    for _ in range(20):
        _churn()
        payload = ArrayWriter(topic).payload()
        assert [payload[i] for i in pads] == [0] * len(pads)
        # the element count just before the padding that aligns the doubles
        count_at = 4 + ((4 + 4 + 4 + len(topic.label) + 1 - 4 + 3) & ~3) + 12
        assert struct.unpack_from('<I', payload, count_at)[0] == len(topic.fields)
        assert payload[:4] == b'\x00\x01\x00\x00'


def test_a_marker_view_is_the_same_bytes_every_time_and_decodes_to_itself():
    """The body marker as the plant serializes it: twenty times, with memory churned between,
    the same bytes; the bytes where rclpy's own serialization differs are zero (padding),
    and the message read back equals the one written."""
    made = []
    for _ in range(20):
        _churn()
        view = _Serialized(_marker(0, (1.8, 0.1, 0.1), (0.5, 0.5, 0.5, 1.0)),
                           ['pose.position.z', 'pose.orientation.y'])
        view.write(3, 250, (-0.5, 0.125))
        made.append(view.payload())
    assert len(set(made)) == 1
    raw = serialize_message(deserialize_message(made[0], Marker))
    differs = [i for i, (a, b) in enumerate(zip(raw, made[0])) if a != b]
    assert all(made[0][i] == 0 for i in differs)
    back = deserialize_message(made[0], Marker)
    assert (back.pose.position.z, back.pose.orientation.y, back.header.stamp.sec,
            back.header.stamp.nanosec) == (-0.5, 0.125, 3, 250)
    assert serialized(back) == made[0]
