"""The in-plant writer's compiled path: ring records to MCAP message records in one call.

The writer process (:mod:`.inplant`) turns each record of the ring into one MCAP message
record of the chunk in progress: a log time read from the bytes (:class:`~.writer.LogTimes`),
the channel's next sequence number, the bytes padded to 4. Interpreted, that is about 2 us a
message (``bench/bench_inplant.py``): on a 2-core machine running a lockstep loop of two
processes, a fifth of what the loop takes per sample, taken from the cores the loop runs on.
:func:`pack` does the same for a run of records in one compiled call (numba): the message
records into a scratch buffer, each message's log time, offset and topic into index arrays,
which :class:`Packer` hands to the chunk in progress (:meth:`.writer._Messages.add_packed`).

It handles the records whose log time it can read with the interpreted rule's own result:

* ``clock`` and ``stamped`` topics in little-endian CDR (the stamp's seconds and nanoseconds
  at bytes 4 and 8; a negative stamp of a ``stamped`` topic takes the previous array log
  time, as the rule does);
* ``array`` topics (Float64MultiArray) whose length and first 12 bytes equal those of a
  message the interpreted rule already read (the same key :class:`~.writer.LogTimes` caches:
  they fix the offset of ``data[0]`` for a one-dimension layout).

Any other record (the first message of an array topic, another layout, big-endian CDR) stops
the call; :class:`Packer` writes that record the interpreted way (which learns its layout) and
calls again. So a bag written through :class:`Packer` is byte for byte the bag the
interpreted writer makes of the same ring (``test/test_inplant_ring.py``).

Pure module: no rclpy; needs numba (without it the writer stays interpreted).
"""

from __future__ import annotations

import numba
import numpy as np

from .ring import WRAP  # the ring's layout (this walks it, compiled)

__all__ = ['pack', 'Packer', 'warm_up', 'DONE', 'SLOW', 'CHUNK_FULL', 'OUT_FULL', 'KIND_CODES']

#: :func:`pack`'s status: every record up to ``head`` packed; the record at the returned tail
#: needs the interpreted writer; the chunk passed its size limit (end it, then call again);
#: the scratch buffer or the index arrays are full (hand them over, then call again).
DONE, SLOW, CHUNK_FULL, OUT_FULL = 0, 1, 2, 3
#: Topic kinds as :func:`pack` takes them (``TopicSpec.kind``).
KIND_CODES = {'array': 0, 'clock': 1, 'stamped': 2}
_ARRAY, _CLOCK, _STAMPED = KIND_CODES['array'], KIND_CODES['clock'], KIND_CODES['stamped']
_MESSAGE_OPCODE = 0x05
_MESSAGE_FIELDS = 22      # channel (2), sequence (4), log time (8), publish time (8)
_HEAD = 9 + _MESSAGE_FIELDS


@numba.njit(cache=True, nogil=True)
def _u32(a, p):
    return np.int64(a[p]) | np.int64(a[p + 1]) << 8 | np.int64(a[p + 2]) << 16 | \
        np.int64(a[p + 3]) << 24


@numba.njit(cache=True, nogil=True)
def _put_le(a, p, value, nbytes):
    for i in range(nbytes):
        a[p + i] = (value >> (8 * i)) & 0xFF


@numba.njit(cache=True, nogil=True)
def _log_time(data, p, n, t, kind, keylen, keys, at, last):
    """``(ok, log time, last)`` of the record of topic ``t`` at ``data[p:p + n]`` by the
    interpreted rule; ok False when the record needs the interpreted path."""
    if kind == _ARRAY:
        if keylen[t] == 0 or n != keylen[t]:
            return False, 0, last
        for i in range(12):
            if data[p + i] != keys[t, i]:
                return False, 0, last
        log = last
        if at[t] >= 0:
            v = data[p + at[t]:p + at[t] + 8].view(np.float64)[0]
            if 0.0 <= v < 9e9:
                log = np.int64(np.rint(v * 1e9))
        return True, log, log
    if n < 12 or data[p] != 0 or data[p + 1] != 1:
        return False, 0, last
    sec = _u32(data, p + 4)
    if sec >= 1 << 31:
        sec -= 1 << 32
    log = sec * 1_000_000_000 + _u32(data, p + 8)
    if log < 0:
        if kind == _CLOCK:          # not a log time: the interpreted path's error
            return False, 0, last
        log = last
    return True, log, last


@numba.njit(cache=True, nogil=True)
def pack(data, cap, tail, head, kinds, keylen, keys, at, chans, seqs, last,
         out, room, logs, offsets, topics):
    """Records of the ring ``data`` (its ``cap`` data bytes, uint8) from byte ``tail`` up to
    ``head`` as MCAP message records into ``out`` (uint8, from 0), while the chunk in progress
    has ``room`` bytes before its size limit.

    Per topic (the record's index): ``kinds`` (:data:`KIND_CODES`), the array layout key
    (``keylen`` bytes long, first 12 bytes ``keys``; ``keylen`` 0: none learned yet),
    ``at`` the offset of ``data[0]`` (-1: no data), ``chans`` the MCAP channel id, ``seqs``
    the last sequence number (advanced in place). ``last`` is the previous array log time.
    Each message's log time, offset in ``out`` and topic go to ``logs``, ``offsets``,
    ``topics``.

    Returns ``(status, tail, bytes written to out, messages, last)``.
    """
    pos = 0
    count = 0
    ntopics = kinds.shape[0]
    maxcount = logs.shape[0]
    size = out.shape[0]
    while tail < head:
        o = tail % cap
        gap = cap - o
        if gap < 8:
            tail += gap
            continue
        n = _u32(data, o)
        if n == WRAP:
            tail += gap
            continue
        t = np.int64(data[o + 4]) | np.int64(data[o + 5]) << 8
        if t >= ntopics or o + 8 + n > cap:
            return SLOW, tail, pos, count, last
        p = o + 8
        ok, log, last = _log_time(data, p, n, t, kinds[t], keylen, keys, at, last)
        if not ok:
            return SLOW, tail, pos, count, last
        padded = n + (-n % 4)
        need = _HEAD + padded
        if count == maxcount or pos + need > size:
            return OUT_FULL, tail, pos, count, last
        seq = seqs[t] + 1
        seqs[t] = seq
        out[pos] = _MESSAGE_OPCODE
        _put_le(out, pos + 1, _MESSAGE_FIELDS + padded, 8)
        _put_le(out, pos + 9, chans[t], 2)
        _put_le(out, pos + 11, seq & 0xFFFFFFFF, 4)
        _put_le(out, pos + 15, log, 8)
        _put_le(out, pos + 23, log, 8)
        out[pos + _HEAD:pos + _HEAD + n] = data[p:p + n]
        for i in range(n, padded):
            out[pos + _HEAD + i] = 0
        logs[count] = log
        offsets[count] = pos
        topics[count] = t
        count += 1
        pos += need
        tail += 8 + ((n + 7) & ~7)
        if pos > room:
            return CHUNK_FULL, tail, pos, count, last
    return DONE, tail, pos, count, last


class Packer:
    """:func:`pack` for one writer session: the per-topic tables, the scratch buffers, and the
    drain loop that hands each run of records to the chunk in progress and each record
    :func:`pack` stops at to the interpreted writer.

    Args:
        ring: the session's :class:`~.ring.Ring` (the consumer's side).
        kinds: each topic's ``TopicSpec.kind``, in ring index order.
        channels: each topic's MCAP channel id, in ring index order.
        times: the session's :class:`~.writer.LogTimes` (its ``last`` and learned layouts).
        writer: the session's :class:`~.writer.RunWriter` (:meth:`~.writer.RunWriter.
            write_packed` and the interpreted ``write_many``).
        interpreted: the session's interpreted path for a list of ``(index, bytes)`` records.
        out_bytes: the scratch buffer's size (a chunk's worth: larger runs are handed over
            in parts).
    """

    def __init__(self, ring, kinds, channels, times, writer, interpreted,
                 out_bytes: int = 1 << 20) -> None:
        n = len(kinds)
        self.ring = ring
        self.kinds = np.array([KIND_CODES[k] for k in kinds], dtype=np.int64)
        self.keylen = np.zeros(n, dtype=np.int64)
        self.keys = np.zeros((n, 12), dtype=np.uint8)
        self.at = np.full(n, -1, dtype=np.int64)
        self.chans = np.array(channels, dtype=np.int64)
        self.seqs = np.zeros(n, dtype=np.int64)
        self.times = times
        self.writer = writer
        self.interpreted = interpreted
        self.out = np.empty(out_bytes, dtype=np.uint8)
        count = out_bytes // 40 + 1                   # the smallest message record is 31 B
        self.logs = np.empty(count, dtype=np.int64)
        self.offsets = np.empty(count, dtype=np.int64)
        self.topics = np.empty(count, dtype=np.int64)

    def drain(self, limit: int) -> int:
        """Write the records the ring holds (at most ``limit`` bytes of them); records
        written."""
        ring = self.ring
        counters = ring._counters                                    # noqa: SLF001
        head = min(counters[0], ring._tail + limit)                  # noqa: SLF001
        written = 0
        sequence = self.writer.sequence
        # a view of the mapping for this call only (the ring cannot close while one exists)
        data = np.frombuffer(ring._data, dtype=np.uint8)             # noqa: SLF001
        while ring._tail < head:                                     # noqa: SLF001
            for t, ch in enumerate(self.chans):
                self.seqs[t] = sequence.get(int(ch), 0)
            status, tail, pos, count, last = pack(
                data, ring.capacity, ring._tail, head, self.kinds,   # noqa: SLF001
                self.keylen, self.keys, self.at, self.chans, self.seqs, self.times.last,
                self.out, self.writer.chunk_room(), self.logs, self.offsets, self.topics)
            self.times.last = int(last)
            if count:
                topics = self.topics[:count]
                self.writer.write_packed(self.out[:pos], self.logs[:count],
                                         self.offsets[:count], self.chans[topics],
                                         {int(ch): int(s) for ch, s in zip(self.chans,
                                                                           self.seqs)})
                written += int(count)
            ring.advance(int(tail), int(count))
            if status == SLOW or (status == OUT_FULL and count == 0):
                records = ring.take(1)
                self.interpreted(records)
                ring.release()
                written += len(records)
                for index, raw in records:
                    self._learn(index, raw)
        return written

    def _learn(self, index: int, raw) -> None:
        """After the interpreted writer read an array record: its layout, if it learned it."""
        if index >= len(self.kinds) or self.kinds[index] != KIND_CODES['array']:
            return
        key = (len(raw), bytes(raw[:12]))
        at = self.times._offsets.get(key)                            # noqa: SLF001
        if at is not None and key[0] >= 12:
            self.keylen[index] = key[0]
            self.keys[index] = np.frombuffer(key[1], dtype=np.uint8)
            self.at[index] = at


def warm_up() -> None:
    """Compile :func:`pack` (or load it from numba's cache) with the argument types
    :class:`Packer` passes, on no record."""
    i64 = np.zeros(1, dtype=np.int64)
    pack(np.zeros(8, dtype=np.uint8), 8, 0, 0, i64, i64, np.zeros((1, 12), dtype=np.uint8),
         i64, i64, i64, 0, np.zeros(64, dtype=np.uint8), 0, i64, i64, i64)
