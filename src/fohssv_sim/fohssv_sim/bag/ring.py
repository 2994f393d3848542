"""The recording ring: one producer (the plant), one consumer (the in-plant writer), byte
records in a shared mapping. This module is the ring's one definition: its layout, the wrap
marker, :class:`Ring` (put, take, sizes) and :func:`place`, the producer's put as plain array
code that the plant's compiled fast path compiles (``fohssv_sim.ros.plant.fastpath``).

Layout: a 64-byte header of native 64-bit counters, each written by one side only: the
producer's ``head`` (bytes produced; stored after the record's bytes, so a reader that sees it
sees the record), ``lost`` (records it could not put) and ``waits`` (times a lockstep producer
waited for room); the consumer's ``tail`` (bytes consumed), ``released`` (records consumed)
and its last flush mark, ``flushed_at`` and ``flushed`` (the bag file's size after its last
flush that succeeded, and the messages it holds up to there); then ``capacity`` bytes of
records. The consumer's counters outlive it: a producer whose consumer died counts exactly
what its bag lacks from them (``fohssv_sim.ros.inplant_record``).
A record is an 8-byte header (``<IHH``: payload length, topic index, spare) and the payload,
padded to 8 bytes. A record never straddles the end: the producer skips the rest of the
area, writing the length :data:`WRAP` there when at least a header fits. Aligned 8-byte
stores are atomic and stay in order on x86-64 and ARMv8 for this one-producer,
one-consumer use.

Pure module: no rclpy, no numba.
"""

from __future__ import annotations

import ctypes
import mmap
import os
import struct
import tempfile

__all__ = ['Ring', 'place', 'DEFAULT_RING_BYTES', 'MIN_RING_BYTES', 'HEADER_BYTES', 'WRAP']

#: Default size of the ring (bytes): 32 MiB, about 8 s of a 10 kHz run with its views.
DEFAULT_RING_BYTES = 32 * 1024 * 1024
#: The smallest ring (bytes): a few records.
MIN_RING_BYTES = 4096
#: The mapping's header: head, tail, lost, waits, released, flushed_at, flushed (u64), a spare.
HEADER_BYTES = 64
#: A record length meaning "continue at the ring's start".
WRAP = 0xFFFFFFFF
_RECORD = struct.Struct('<IHH')    # payload length, topic index, spare


def place(data, cap, head, tail, index, payload, n):   # pragma: no cover - also compiled
    """Write the record of the ``n`` bytes ``payload`` for topic ``index`` into the records'
    area ``data`` (``cap`` bytes, uint8) at ``head``, the consumer at ``tail``. Returns the
    head after it, to be stored once these bytes are (the caller's fence), or -1 when there
    is no room (nothing written). :meth:`Ring.put`'s rules, as array code for compiled
    callers."""
    need = 8 + ((n + 7) & ~7)
    off = head % cap
    gap = cap - off
    room = cap - (head - tail)
    if gap < need:                         # wrap: skip the area's end
        if room < gap + need:
            return -1
        if gap >= 8:
            for i in range(4):
                data[off + i] = 0xFF
            for i in range(4, 8):
                data[off + i] = 0
        head += gap
        off = 0
    elif room < need:
        return -1
    for i in range(4):
        data[off + i] = (n >> (8 * i)) & 0xFF
    data[off + 4] = index & 0xFF
    data[off + 5] = (index >> 8) & 0xFF
    data[off + 6] = 0
    data[off + 7] = 0
    for i in range(n):
        data[off + 8 + i] = payload[i]
    return head + need


class Ring:
    """One-producer, one-consumer ring of byte records in a shared mapping (the module docstring).

    Args:
        fd: the file descriptor of the mapping (from :meth:`create` or inherited).
        size: the mapping's size in bytes (header included).
    """

    def __init__(self, fd: int, size: int) -> None:
        self.fd = fd
        self.size = size
        # populated at once (page tables filled, the memory allocated): no page fault on
        # the per-sample path, which would cost the plant microseconds at every new page
        self._map = mmap.mmap(fd, size, flags=mmap.MAP_SHARED | getattr(mmap, 'MAP_POPULATE', 0))
        self._buf = memoryview(self._map)
        self._counters = self._buf[:HEADER_BYTES].cast('Q')
        self._data = self._buf[HEADER_BYTES:]
        self.capacity = size - HEADER_BYTES
        self._c: ctypes.c_char | None = None   # the mapping's ctypes export (address())
        self._limit = self._counters[1] + self.capacity   # head may grow to this (producer)
        self._tail = self._counters[1]      # consumer's copy
        self._taken = self._tail            # consumer: the end of the last take()
        self._taken_n = 0                   # consumer: the records of the last take()

    @classmethod
    def create(cls, size: int = DEFAULT_RING_BYTES) -> Ring:
        """A new zeroed ring of ``size`` bytes (rounded up to 8) whose descriptor a child
        process inherits (``pass_fds``)."""
        size = max(MIN_RING_BYTES, (int(size) + 7) & ~7) + HEADER_BYTES
        if hasattr(os, 'memfd_create'):
            fd = os.memfd_create('fohssv-record-ring', 0)      # no name in the file system
        else:                                                     # pragma: no cover
            fd = os.dup(tempfile.TemporaryFile().fileno())
        os.ftruncate(fd, size)
        os.set_inheritable(fd, True)
        return cls(fd, size)

    # -- producer (the plant) ---------------------------------------------------------------
    def put(self, index: int, data: bytes) -> bool:
        """Copy one record (topic ``index``, ``data``); False when there is no room (nothing
        is written then). The common case is one header pack and one slice assignment. The
        head is read from the mapping: compiled code of the same process may have put
        records too (:meth:`address`)."""
        n = len(data)
        need = 8 + ((n + 7) & ~7)
        head = self._counters[0]
        off = head % self.capacity
        if off + need > self.capacity or head + need > self._limit:
            return self._put_slow(index, data, n, need)
        self._data[off:off + 8 + n] = _RECORD.pack(n, index, 0) + data
        self._counters[0] = head + need       # after the bytes: the record is published
        return True

    def _put_slow(self, index: int, data: bytes, n: int, need: int) -> bool:
        """:meth:`put` at the ring's end (a wrap) or when the room known is not enough (the
        writer's tail is read again)."""
        cap = self.capacity
        head = self._counters[0]
        tail = self._counters[1]
        self._limit = tail + cap
        off = head % cap
        gap = cap - off
        room = cap - (head - tail)
        if gap < need:                        # wrap: skip the ring's end
            if room < gap + need:
                return False
            if gap >= 8:
                _RECORD.pack_into(self._data, off, WRAP, 0, 0)
            head += gap
            off = 0
        elif room < need:
            return False
        self._data[off:off + 8 + n] = _RECORD.pack(n, index, 0) + data
        self._counters[0] = head + need
        return True

    def address(self) -> tuple[int, int, int]:
        """(the address of the records' area, its capacity in bytes, the address of the head
        and tail counters, two native 64-bit integers) for compiled code of the producer's
        process that puts records as :meth:`put` does (:func:`place`, compiled); valid
        until :meth:`close`."""
        if self._c is None:
            self._c = ctypes.c_char.from_buffer(self._map)
        base = ctypes.addressof(self._c)
        return base + HEADER_BYTES, self.capacity, base

    def add_lost(self, n: int = 1) -> None:
        self._counters[2] += n

    def add_wait(self) -> None:
        self._counters[3] += 1

    # -- both -------------------------------------------------------------------------------
    @property
    def lost(self) -> int:
        return self._counters[2]

    @property
    def waits(self) -> int:
        return self._counters[3]

    @property
    def released(self) -> int:
        """Records the consumer took and released so far."""
        return self._counters[4]

    @property
    def flushed(self) -> tuple[int, int]:
        """The consumer's last flush mark (:meth:`mark_flushed`): (its file's size in bytes,
        the messages in the file up to there); (0, 0) before the first."""
        return self._counters[5], self._counters[6]

    @property
    def consumed(self) -> int:
        """Bytes the consumer took so far (its tail)."""
        return self._counters[1]

    @property
    def used(self) -> int:
        """Bytes produced and not yet consumed."""
        return self._counters[0] - self._counters[1]

    # -- consumer (the writer) --------------------------------------------------------------
    def take(self, limit: int = 1 << 30) -> list[tuple[int, memoryview]]:
        """The records produced so far (at most ``limit`` bytes of them), in order, as
        ``(index, bytes view)``, in one list: the writer's batch. The tail stays until
        :meth:`release` (the views are valid until then)."""
        cap = self.capacity
        tail = self._tail
        head = min(self._counters[0], tail + limit)
        data = self._data
        unpack = _RECORD.unpack_from
        out = []
        append = out.append
        while tail < head:
            off = tail % cap
            gap = cap - off
            if gap < 8:
                tail += gap
                continue
            n, index, _ = unpack(data, off)
            if n == WRAP:
                tail += gap
                continue
            append((index, data[off + 8:off + 8 + n]))
            tail += 8 + ((n + 7) & ~7)
        self._taken = tail
        self._taken_n = len(out)
        return out

    def release(self) -> None:
        """Move the tail past the records of the last :meth:`take` (room for the plant)."""
        self._tail = self._taken
        self._counters[1] = self._taken
        self._counters[4] += self._taken_n
        self._taken_n = 0

    def advance(self, tail: int, records: int) -> None:
        """Move the tail to ``tail``, past ``records`` records the consumer wrote (compiled
        consumers, which walk the records themselves)."""
        self._tail = self._taken = tail
        self._counters[1] = tail
        self._counters[4] += records

    def mark_flushed(self, size: int, messages: int) -> None:
        """The consumer's file was flushed: ``size`` bytes holding ``messages`` messages."""
        self._counters[6] = messages
        self._counters[5] = size

    def close(self) -> None:
        self._c = None                        # the export, before the mapping closes
        self._counters.release()
        self._data.release()
        self._buf.release()
        self._map.close()
        os.close(self.fd)
