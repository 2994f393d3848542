"""The bytes the plant publishes (and so records) are a function of the message: the CDR
alignment padding, which rclpy's serializer leaves as its buffer held it (fragments of the
process's memory), is zero. No ROS graph: rclpy's serializer in this process.

The padding of the contract's Float64MultiArray is located here by the CDR rules (XCDR1:
each primitive aligned to its size from the end of the 4-byte encapsulation header), not by
the code under test; every type the plant publishes is compared with rosbags' serializer (a
second CDR implementation, which writes zeros where the padding is).
"""

from __future__ import annotations

import struct

import pytest
from geometry_msgs.msg import Point
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, UVCoordinate

from fohssv_sim import contract
from fohssv_sim.bag.writer import typestore
from fohssv_sim.params import ModelParameters
from fohssv_sim.ros.views import _marker, _Serialized
from fohssv_sim.ros.wire import ArrayWriter, array_message, message_class, serialized


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


def _rosbags(msg) -> bytes:
    """``msg`` serialized by rosbags (deserialized from rclpy's bytes, serialized again)."""
    name = f"{type(msg).__module__.split('.')[0]}/msg/{type(msg).__name__}"
    ts = typestore()
    return bytes(ts.serialize_cdr(ts.deserialize_cdr(serialize_message(msg), name), name))


def _full_marker() -> Marker:
    """A marker with every kind of field filled: strings of odd lengths (one not ASCII),
    sequences of structs and of bytes, floats beside doubles and booleans."""
    m = _marker(7, (1.0, 2.0, 3.0), (0.1, 0.2, 0.3, 0.4))
    m.header.frame_id = 'abcde'
    m.ns = 'n\u00e9'
    m.points = [Point(x=1.0, y=2.0, z=3.0), Point(x=-1.0)]
    m.colors = [ColorRGBA(r=0.5, a=1.0)] * 3
    m.texture_resource = 'xy'
    m.texture.format = 'png'
    m.texture.data = bytes(range(5))
    m.uv_coordinates = [UVCoordinate(u=0.25, v=0.75)]
    m.text = 't'
    m.mesh_file.filename = 'mesh.dae'
    m.mesh_file.data = bytes(3)
    m.frame_locked = m.mesh_use_embedded_materials = True
    return m


def _published() -> list:
    """A message of every type the plant publishes (the contract and the views), filled as
    it fills them, and a marker with every field filled."""
    msgs = [array_message(t) for t in (contract.STATE, contract.PLANING_FORCE,
                                       contract.COMMAND)]
    msgs.append(message_class(contract.CLOCK)())
    for topic in contract.VIEW_TOPICS:
        msg = message_class(topic)()
        msg.header.frame_id = contract.VIEW_WORLD_FRAME
        msgs.append(msg)
    body = _marker(0, (ModelParameters().length, 0.2, 0.2), (0.55, 0.57, 0.6, 1.0))
    return [*msgs, body, _full_marker()]


@pytest.mark.parametrize('msg', _published(), ids=lambda m: type(m).__name__)
def test_every_published_type_has_the_bytes_rosbags_serializes(msg):
    for _ in range(5):
        _churn()
        assert serialized(msg) == _rosbags(msg)
