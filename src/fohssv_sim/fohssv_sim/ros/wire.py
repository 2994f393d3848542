"""The contract's messages as serialized bytes: publish and take them without rclpy's
per-message conversion between Python objects and CDR.

At 10 kHz every microsecond of the per-sample path counts, and rclpy's conversion is most of
what a node spends on a message besides DDS itself: publishing a ``Float64MultiArray`` object
serializes it (about 1.5 us more than publishing ready bytes), and taking one builds a message
object with its layout (about 10 us, as much as ``deserialize_message``). Measured with the
bare round trip of ``bench/ros_echo.py`` on this 2-core machine: 40 us of CPU per round trip
in the sending process with serialized messages against 58 us with message objects, and
11.9k against 9.1k round trips/s.

* :class:`ArrayWriter` holds one serialized message of a topic (made once by rclpy's own
  serializer, so the bytes are exactly what ``publish(msg)`` would send); ``values`` is a
  writable view of its doubles (``values[i] = v`` writes into the CDR in place) and
  :meth:`ArrayWriter.payload` returns the bytes to ``publish``.
* :class:`ArrayReader` reads the doubles of a serialized message (a subscription created with
  ``raw=True`` hands the callback bytes): for a message laid out like the contract's (one
  dimension, a label of the same length, the expected number of doubles) it unpacks them at
  their known offset; anything else (another layout, a wrong length) goes through rclpy's
  ``deserialize_message`` so the caller's checks and error messages see the data as before.

* :func:`serialized` is rclpy's serialization with the CDR alignment padding zeroed: the
  serializer leaves those bytes as the buffer held them (fragments of the process's memory,
  different from run to run), and every message the plant publishes (contract and views) is
  made from it, so a bag is a function of the run. The padding is found by walking the
  message's fields (their rosidl types, ``SLOT_TYPES``) by the CDR rules; the bytes are those
  rosbags' serializer writes (tests/test_wire_padding.py compares them for every type the
  plant publishes), without building rosbags' typestore of every ROS type at each start.

Both rely on the machine's byte order being the one the serializer wrote (checked at
construction: the encapsulation must be CDR little-endian and the round trip through
``deserialize_message`` must give the written values back).
"""

from __future__ import annotations

import array
import ctypes
import struct
from collections.abc import Sequence
from typing import Any

from rclpy.serialization import deserialize_message, serialize_message
from rosidl_parser import definition as idl
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ..contract import Topic

__all__ = ['raw_publish', 'serialized', 'ArrayWriter', 'ArrayReader', 'ClockWriter',
           'WireError', 'array_message',
           'message_class']

_CDR_LE = b'\x00\x01'


class WireError(RuntimeError):
    """The serialized form is not the one this module understands (not CDR little-endian)."""


def serialized(msg: Any) -> bytearray:
    """``msg`` as rclpy serializes it (what ``publish(msg)`` sends), with the alignment padding
    (and the encapsulation's options) zeroed: the bytes a CDR serializer that writes zeros
    there (rosbags') gives for the same message.

    Raises:
        WireError: not CDR little-endian, or the bytes do not have the layout the message's
            field types give (a type this walk does not know: wide strings, long double).
    """
    raw = bytearray(serialize_message(msg))
    typename = f"{type(msg).__module__.split('.')[0]}/msg/{type(msg).__name__}"
    if raw[:2] != _CDR_LE:
        raise WireError(f'{typename}: serialized as {bytes(raw[:4])!r}, not CDR LE')
    raw[2:4] = bytes(2)
    try:
        end = _zero_struct(raw, 4, msg)
    except (WireError, struct.error) as exc:
        raise WireError(f'{typename}: cannot zero its padding ({exc})') from None
    if end != len(raw):
        raise WireError(f'{typename}: {len(raw)} bytes serialized, {end} by its field types')
    return raw


#: Sizes of the CDR primitives (bytes; each aligned to its size, from the end of the 4-byte
#: encapsulation header).
_PRIMITIVES = {'boolean': 1, 'octet': 1, 'char': 1, 'int8': 1, 'uint8': 1, 'int16': 2,
               'uint16': 2, 'int32': 4, 'uint32': 4, 'float': 4, 'int64': 8, 'uint64': 8,
               'double': 8}


def _align(raw: bytearray, pos: int, size: int) -> int:
    """Zero the padding from ``pos`` to the next multiple of ``size`` (after the header)."""
    end = 4 + (pos - 4 + size - 1) // size * size
    raw[pos:end] = bytes(end - pos)
    return end


def _zero_struct(raw: bytearray, pos: int, msg: Any) -> int:
    """Zero the padding of the message ``msg`` serialized at ``pos``; the offset after it."""
    kinds = type(msg).SLOT_TYPES
    if not kinds:              # an empty message: one uint8 stands for it in CDR
        return pos + 1
    for name, kind in zip(type(msg).get_fields_and_field_types(), kinds):
        pos = _zero_value(raw, pos, getattr(msg, name), kind)
    return pos


def _zero_value(raw: bytearray, pos: int, value: Any, kind: Any) -> int:
    if isinstance(kind, idl.BasicType):
        size = _size(kind)
        return _align(raw, pos, size) + size
    if isinstance(kind, idl.AbstractString):          # uint32 length with the NUL, UTF-8
        pos = _align(raw, pos, 4)
        n = struct.unpack_from('<I', raw, pos)[0]
        if n != len(value.encode()) + 1:
            raise WireError(f'a string of {n} bytes where {value!r} was written')
        return pos + 4 + n
    if isinstance(kind, idl.NamespacedType):
        return _zero_struct(raw, pos, value)
    if isinstance(kind, idl.AbstractNestedType):      # arrays; sequences after their count
        if isinstance(kind, idl.AbstractSequence):
            pos = _align(raw, pos, 4)
            n = struct.unpack_from('<I', raw, pos)[0]
            if n != len(value):
                raise WireError(f'a sequence of {n} where {len(value)} were written')
            pos += 4
        item = kind.value_type
        if isinstance(item, idl.BasicType):           # contiguous, aligned once
            size = _size(item)
            return _align(raw, pos, size) + size * len(value) if len(value) else pos
        for v in value:
            pos = _zero_value(raw, pos, v, item)
        return pos
    raise WireError(f'no CDR layout known for {type(kind).__name__}')


def _size(kind: Any) -> int:
    size = _PRIMITIVES.get(kind.typename)
    if size is None:
        raise WireError(f'no CDR layout known for {kind.typename}')
    return size


def array_message(topic: Topic) -> Float64MultiArray:
    """A message of ``topic`` with its self-describing layout and ``data`` preallocated as an
    ``array.array('d')`` of the layout's length (zeros): fill it in place, ``msg.data[i] = v``,
    and publish the same message again (no allocation per sample)."""
    msg = Float64MultiArray()
    n = len(topic.fields)
    msg.layout.dim = [MultiArrayDimension(label=topic.label, size=n, stride=n)]
    msg.data = array.array('d', bytes(8 * n))
    return msg


_CLASSES: dict[str, type] = {}


def message_class(topic: Topic) -> type:
    """The Python message class of a contract topic's type (the contract topics and the
    typed views)."""
    if not _CLASSES:
        from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
        from rosgraph_msgs.msg import Clock
        from visualization_msgs.msg import Marker

        from .. import contract

        _CLASSES.update({
            contract.FLOAT64_ARRAY: Float64MultiArray, contract.CLOCK.type: Clock,
            contract.POSE.type: PoseStamped, contract.TWIST.type: TwistStamped,
            contract.WRENCH.type: WrenchStamped, contract.MARKER.type: Marker})
    return _CLASSES[topic.type]


def _template(topic: Topic) -> tuple[bytearray, int]:
    """The serialized message of ``topic`` (layout, zeros) and the offset of its doubles."""
    msg = array_message(topic)
    n = len(topic.fields)
    probe = tuple(float(i + 1) for i in range(n))
    msg.data = array.array('d', probe)
    raw = serialized(msg)
    offset = len(raw) - 8 * n
    if struct.unpack_from(f'<{n}d', raw, offset) != probe or tuple(
            deserialize_message(bytes(raw), Float64MultiArray).data) != probe:
        raise WireError(f'{topic.name}: the doubles are not the last {8 * n} bytes')
    struct.pack_into(f'<{n}d', raw, offset, *([0.0] * n))
    return raw, offset


class ArrayWriter:
    """A serialized ``Float64MultiArray`` of ``topic``'s layout whose doubles are written in
    place through :attr:`values` (a ``memoryview`` of format ``'d'``)."""

    def __init__(self, topic: Topic) -> None:
        self._buf, offset = _template(topic)
        self._offset = offset
        self._c: Any = None        # the ctypes export of _buf, made by address()
        self.values = memoryview(self._buf)[offset:].cast('d')

    def payload(self) -> bytes:
        """The message as bytes for ``Publisher.publish`` (a copy: publish it right away)."""
        return bytes(self._buf)

    def address(self) -> tuple[int, int, int]:
        """(the serialized message's address, its length in bytes, the offset of the doubles)
        for compiled code that writes and publishes it in place; the buffer stays where it
        is as long as this writer lives."""
        if self._c is None:
            self._c = (ctypes.c_char * len(self._buf)).from_buffer(self._buf)
        return ctypes.addressof(self._c), len(self._buf), self._offset


class ArrayReader:
    """Reads the doubles of serialized ``Float64MultiArray`` messages laid out like
    ``topic``'s (see the module docstring)."""

    def __init__(self, topic: Topic) -> None:
        buf, offset = _template(topic)
        self.size = len(buf)
        self.n = len(topic.fields)
        self.offset = offset
        # encapsulation, number of dimensions (1), length of the label: the 12 bytes that
        # fix where everything after them lies (the label's text itself may differ)
        self._head = bytes(buf[:12])
        # CDR: label text after its length, aligned to 4 (from the end of the encapsulation),
        # then size, stride, data_offset and the number of doubles
        end = 12 + struct.unpack_from('<I', buf, 8)[0]
        self._count_at = 4 + ((end - 4 + 3) & ~3) + 12
        if struct.unpack_from('<I', buf, self._count_at)[0] != self.n:
            raise WireError(f'{topic.name}: no element count at byte {self._count_at}')
        self._format = f'<{self.n}d'
        self._unpack = struct.Struct(self._format).unpack_from

    def layout(self) -> tuple[bytes, int, int, int, int]:
        """(the first 12 bytes every message of the layout starts with, the offset of the
        element count, the count, the offset of the doubles, the message's length): what
        :meth:`read`'s fast path checks, for compiled code that reads the doubles itself."""
        return self._head, self._count_at, self.n, self.offset, self.size

    def unpack(self, raw: bytes) -> tuple[float, ...]:
        """The doubles of a message already known to have the layout (checked by compiled
        code, :meth:`layout`): :meth:`read`'s fast path without its checks."""
        return self._unpack(raw, self.offset)

    def read(self, raw: bytes) -> Sequence[float]:
        """The message's doubles: a tuple on the fast path, else rclpy's ``data`` array."""
        if (len(raw) == self.size and raw.startswith(self._head)
                and struct.unpack_from('<I', raw, self._count_at)[0] == self.n):
            return struct.unpack_from(self._format, raw, self.offset)
        return deserialize_message(raw, Float64MultiArray).data


class ClockWriter:
    """A serialized ``rosgraph_msgs/Clock`` written in place: :meth:`payload` for a time in
    nanoseconds (``sec, nanosec = divmod(ns, 10**9)``, as ``rclpy.time.Time.to_msg`` splits
    it)."""

    def __init__(self) -> None:
        from builtin_interfaces.msg import Time
        from rosgraph_msgs.msg import Clock

        raw = bytearray(serialize_message(Clock(clock=Time(sec=12345, nanosec=678))))
        if raw[:2] != _CDR_LE or len(raw) != 12 or struct.unpack_from('<iI', raw, 4) != (
                12345, 678):
            raise WireError(f'/clock: unexpected serialized form {bytes(raw)!r}')
        self._buf = raw
        self._c: Any = None        # the ctypes export of _buf, made by address()

    def payload(self, nanoseconds: int) -> bytes:
        struct.pack_into('<iI', self._buf, 4, *divmod(nanoseconds, 1_000_000_000))
        return bytes(self._buf)

    def last(self) -> bytes:
        """The message as last written (by :meth:`payload` or by compiled code in place)."""
        return bytes(self._buf)

    def address(self) -> tuple[int, int]:
        """(the serialized message's address, its length in bytes: the stamp's ``sec`` and
        ``nanosec`` are at bytes 4 and 8) for compiled code that writes and publishes it in
        place; the buffer stays where it is as long as this writer lives."""
        if self._c is None:
            self._c = (ctypes.c_char * len(self._buf)).from_buffer(self._buf)
        return ctypes.addressof(self._c), len(self._buf)


def raw_publish(pub: Any) -> Any:
    """The call that publishes serialized bytes on ``pub``: rclpy's C++ ``publish_raw``
    itself where this rclpy has it (``Publisher.publish`` checks the message's type and
    takes the handle's guard first, 1-1.5 us of each of the per-sample publishes; the plant
    only publishes while running, before it destroys anything), else ``pub.publish``."""
    inner = getattr(pub, '_Publisher__publisher', None)
    raw = getattr(inner, 'publish_raw', None)
    return raw if callable(raw) else pub.publish
