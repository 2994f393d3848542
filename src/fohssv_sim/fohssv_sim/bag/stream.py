"""Read long bags in bounded memory: the contract topics straight into numpy arrays, and what a
bag holds from its MCAP summary section. Pure: no rclpy.

* :func:`read_arrays` walks an MCAP file chunk by chunk (each chunk decompressed, its CRC
  checked, then dropped; index and summary records skipped unread) and appends the doubles
  of each contract message to flat arrays: no Python object is kept per message, so memory
  is the arrays' own (8 bytes per number and per log time), whatever the bag's length. A
  time window
  (``start``, ``end``: simulation time in s, on the log times, which are the messages' t in
  ns) skips the chunks outside it without decompressing them, and ``every`` keeps every k-th
  message of each topic. A truncated or corrupt file does not raise: reading stops at the
  first incomplete or corrupt record (``problem`` says where), as the recorder's bag killed
  mid-run is read.
* :func:`summary_counts` gives the messages per topic, the time span and the run metadata
  from the summary section (statistics, channels, metadata indexes) without reading a
  message; None for a file without one (a recorder killed mid-run).
* :func:`fits` refuses a request whose arrays would not fit in the memory available, with
  the size and the remedies.

Messages are decoded as ``std_msgs/Float64MultiArray`` (CDR little-endian; a message of
another width than its topic's is rejected, as is one with a non-finite number, as the
contract says): the layout of a channel's first message is parsed once; every message of
the same size and head is unpacked at the known offset, others are parsed fully.
"""

from __future__ import annotations

import array
import io
import struct
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, get_chunk_data_stream

__all__ = ['Columns', 'FileRead', 'read_arrays', 'summary_counts', 'fits', 'available_memory',
           'float64_array']

_MESSAGE, _SCHEMA, _CHANNEL = 0x05, 0x03, 0x04
_RECORD = struct.Struct('<BQ')
_MSG_HEAD = struct.Struct('<HIQQ')        # channel id, sequence, log time, publish time
_U32 = struct.Struct('<I')


def float64_array(raw: bytes | memoryview, at: int = 0, size: int | None = None
                  ) -> tuple[tuple[float, ...], tuple[bytes, int, int, int, int]] | None:
    """The doubles of a serialized ``Float64MultiArray`` (CDR little-endian) at ``at`` of
    ``size`` bytes, and its layout (head: the first 12 bytes, the offset of the element count,
    the count, the offset of the doubles, the size) for the fast path; None when it is not
    such a message."""
    size = len(raw) - at if size is None else size
    try:
        if bytes(raw[at:at + 2]) != b'\x00\x01':
            return None
        pos = 4
        (ndim,) = _U32.unpack_from(raw, at + pos)
        pos += 4
        for _ in range(ndim):
            (length,) = _U32.unpack_from(raw, at + pos)
            pos += 4 + length
            pos = 4 + ((pos - 4 + 3) & ~3) + 8        # label aligned to 4, size, stride
        pos += 4                                       # data_offset
        count_at = pos
        (n,) = _U32.unpack_from(raw, at + pos)
        pos += 4
        pos = 4 + ((pos - 4 + 7) & ~7)
        if pos + 8 * n != size:
            return None
        values = struct.unpack_from(f'<{n}d', raw, at + pos)
    except struct.error:
        return None
    return values, (bytes(raw[at:at + 12]), count_at, n, pos, size)


class Columns:
    """Rows of one topic: ``width`` doubles and a log time (ns) each, appended to flat
    ``array`` buffers (8 bytes a number, no object per row)."""

    def __init__(self, width: int) -> None:
        self.width = width
        self.values = array.array('d')
        self.log_times = array.array('q')
        self.seen = 0            # messages of the topic in the window (decimation counter)
        self.rejected = 0

    @property
    def n(self) -> int:
        return len(self.log_times)

    def add(self, values: Sequence[float], log_time: int) -> None:
        self.values.extend(values)
        self.log_times.append(log_time)

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """The rows and log times; rows with a non-finite number are dropped (rejected, as the
        contract says such a message must be)."""
        rows = np.frombuffer(self.values, dtype=np.float64).reshape(-1, self.width)
        times = np.frombuffer(self.log_times, dtype=np.int64)
        good = np.isfinite(rows).all(axis=1)
        if not good.all():
            self.rejected += int((~good).sum())
            rows, times = rows[good], times[good]
        rows, times = rows.copy(), times.copy()
        self.values, self.log_times = array.array('d'), array.array('q')
        return rows, times


@dataclass
class FileRead:
    """What :func:`read_arrays` found in one file besides the arrays."""

    channels: dict[int, tuple[str, str, str]] = field(default_factory=dict)  # topic, type, def
    schemas: dict[int, Schema] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)     # channel id -> messages read
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    library: str = ''
    complete: bool = False
    problem: str = ''
    bytes_read: int = 0
    bytes_total: int = 0


def read_arrays(path: Path, pick: Callable[[Channel, Schema | None], int | None],
                columns: Sequence[Columns], decode: Sequence[Callable | None], *,
                start_ns: int | None = None, end_ns: int | None = None, every: int = 1
                ) -> FileRead:
    """Walk the MCAP file at ``path``; every message of a channel that ``pick`` maps to an index
    ``i`` (None: not wanted, only counted) and whose log time lies in [``start_ns``,
    ``end_ns``] is decoded by ``decode[i]`` (raw bytes, offset, size -> values or None =
    rejected; None: :func:`float64_array`) into ``columns[i]``, every ``every``-th."""
    reader = _Reader(pick, columns, decode, start_ns, end_ns, every)
    # a chunk outside the window may be skipped only when the channels it may define are
    # known from the summary
    summary = _summary(path) if start_ns is not None or end_ns is not None else None
    if summary is not None:
        reader.out.schemas.update(summary.schemas)
        for record in summary.channels.values():
            reader.channel(record)
    reader.walk(path, skip=summary is not None)
    return reader.out


class _Reader:
    """The state of one :func:`read_arrays` walk."""

    def __init__(self, pick: Callable, columns: Sequence[Columns],
                 decode: Sequence[Callable | None], start_ns: int | None, end_ns: int | None,
                 every: int) -> None:
        self.out = FileRead()
        self.pick, self.columns, self.decode, self.every = pick, columns, decode, every
        self.kind: dict[int, int | None] = {}
        self.fast: dict[int, tuple[bytes, int, int, int, int, struct.Struct]] = {}
        self.lo = -(1 << 63) if start_ns is None else start_ns
        self.hi = (1 << 63) if end_ns is None else end_ns

    def channel(self, record: Channel) -> None:
        out = self.out
        schema = out.schemas.get(record.schema_id)
        out.channels[record.id] = (record.topic, schema.name if schema else '',
                                   schema.data.decode('utf8', 'replace') if schema else '')
        self.kind[record.id] = self.pick(record, schema)

    def message(self, cid: int, log_time: int, raw: bytes, at: int, size: int) -> None:
        counts = self.out.counts
        counts[cid] = counts.get(cid, 0) + 1
        i = self.kind.get(cid)
        if i is None or not self.lo <= log_time <= self.hi:
            return
        col = self.columns[i]
        k = col.seen
        col.seen += 1
        if k % self.every:
            return
        decode = self.decode[i]
        values = decode(raw, at, size) if decode is not None else self._array(cid, raw, at,
                                                                               size)
        if values is None or len(values) != col.width:
            col.rejected += 1
        else:
            col.add(values, log_time)

    def _array(self, cid: int, raw: bytes, at: int, size: int) -> tuple[float, ...] | None:
        """The doubles of a Float64MultiArray: at the channel's known offset when the message
        has its first message's size and head, else parsed."""
        layout = self.fast.get(cid)
        if (layout is not None and size == layout[4] and raw.startswith(layout[0], at)
                and _U32.unpack_from(raw, at + layout[1])[0] == layout[2]):
            return layout[5].unpack_from(raw, at + layout[3])
        parsed = float64_array(raw, at, size)
        if parsed is None:
            return None
        values, (head, count_at, n, offset, length) = parsed
        self.fast.setdefault(cid, (head, count_at, n, offset, length, struct.Struct(f'<{n}d')))
        return values

    def walk(self, path: Path, skip: bool) -> None:
        """Every record of the file; chunks outside the window are not decompressed when
        ``skip``."""
        out = self.out
        out.bytes_total = size_total = path.stat().st_size
        good = 0
        with path.open('rb') as f:
            try:
                for record in _records(f, size_total):
                    self._record(record, skip)
                    good = f.tell()
            except (CRCValidationError, _Corrupt) as exc:
                out.problem = f'{path}: corrupt data at byte {good} ({exc})'
            except (McapError, struct.error, EOFError, ValueError, UnicodeDecodeError) as exc:
                kind = type(exc).__name__
                out.problem = (f'{path}: truncated or corrupt after byte {good} of '
                               f'{size_total} ({kind}{": " + str(exc) if str(exc) else ""})')
        out.bytes_read = size_total if out.complete else good
        if not out.complete and not out.problem:
            out.problem = f'{path}: no footer after byte {good} of {size_total}'

    def _record(self, record: Any, skip: bool) -> None:
        out = self.out
        if isinstance(record, Chunk):
            if not (skip and (record.message_end_time < self.lo
                              or record.message_start_time > self.hi)):
                _walk_chunk(record, out, self.channel, self.message)
        elif isinstance(record, Header):
            out.library = record.library
        elif isinstance(record, Schema):
            out.schemas[record.id] = record
        elif isinstance(record, Channel):
            self.channel(record)
        elif isinstance(record, Message):
            if record.channel_id not in out.channels:
                raise _Corrupt(f'message on unknown channel {record.channel_id}')
            self.message(record.channel_id, record.log_time, record.data, 0, len(record.data))
        elif isinstance(record, Metadata):
            out.metadata.append((record.name, dict(record.metadata)))
        elif isinstance(record, Footer):
            out.complete = True


class _Corrupt(Exception):
    pass


#: The records a walk reads (the others, indexes and the summary, are skipped unread: the
#: message indexes alone took half the time of a load when parsed).
_READ = {Opcode.HEADER: Header, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
         Opcode.MESSAGE: Message, Opcode.CHUNK: Chunk, Opcode.METADATA: Metadata,
         Opcode.FOOTER: Footer}


def _records(f: Any, size: int) -> Iterator[Any]:
    """The data records of an MCAP file in file order (each chunk's CRC is checked when it is
    walked); the index and summary records are skipped without being read.

    Raises:
        McapError: not an MCAP file; EOFError: a record cut short (a killed writer).
    """
    if f.read(8) != b'\x89MCAP0\r\n':
        raise McapError('no MCAP magic at the start of the file')
    head = _RECORD.unpack
    while True:
        raw = f.read(9)
        if len(raw) < 9:
            raise EOFError(f'{len(raw)} bytes where a record begins')
        op, length = head(raw)
        cls = _READ.get(op)
        if cls is None:
            if f.tell() + length > size:
                raise EOFError(f'a record of {length} bytes runs past the end of the file')
            f.seek(length, 1)
            continue
        body = f.read(length)
        if len(body) < length:
            raise EOFError(f'a record of {length} bytes ends after {len(body)}')
        stream = ReadDataStream(io.BytesIO(body))
        yield cls.read(stream, length) if op == Opcode.MESSAGE else cls.read(stream)
        if op == Opcode.FOOTER:
            return


def _walk_chunk(chunk: Chunk, out: FileRead, channel: Callable, message: Callable) -> None:
    """The records of one chunk: messages handed to ``message`` at their offset in the
    decompressed data (no copy), schemas and channels recorded."""
    stream, length = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(length)
    pos = 0
    unpack_record, unpack_head = _RECORD.unpack_from, _MSG_HEAD.unpack_from
    channels = out.channels
    while pos < length:
        op, size = unpack_record(data, pos)
        body = pos + 9
        end = body + size
        if end > length:
            raise _Corrupt(f'a record runs past the end of its chunk ({end} > {length})')
        if op == _MESSAGE:
            cid, _, log_time, _ = unpack_head(data, body)
            if cid not in channels:
                raise _Corrupt(f'message on unknown channel {cid}')
            message(cid, log_time, data, body + 22, size - 22)
        elif op in (_SCHEMA, _CHANNEL):

            sub = ReadDataStream(io.BytesIO(data[body:end]))
            if op == _SCHEMA:
                record = Schema.read(sub)
                out.schemas[record.id] = record
            else:
                channel(Channel.read(sub))
        pos = end


def _summary(path: Path):
    """The MCAP summary section of the file (None: none, or unreadable)."""
    try:
        with path.open('rb') as f:
            return make_reader(f).get_summary()
    except (McapError, struct.error, EOFError, ValueError, OSError, UnicodeDecodeError):
        return None


def summary_counts(path: Path) -> tuple[dict[str, int], int, int, list[tuple[str, dict]]
                                        ] | None:
    """(messages per topic, first and last log time in ns, the metadata records) from the
    summary section of the MCAP file at ``path``, without reading any message; None when the
    file has no summary with statistics (a recorder killed mid-run)."""
    try:
        with path.open('rb') as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return None
            stats = summary.statistics
            counts: dict[str, int] = {}
            for cid, chan in summary.channels.items():
                counts[chan.topic] = counts.get(chan.topic, 0) + stats.channel_message_counts.get(
                    cid, 0)
            meta = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
    except (McapError, struct.error, EOFError, ValueError, OSError, UnicodeDecodeError):
        return None
    return counts, stats.message_start_time, stats.message_end_time, meta


def available_memory() -> int:
    """Bytes of memory available to a new allocation (``MemAvailable``; a large number when
    it cannot be read)."""
    try:
        for line in Path('/proc/meminfo').read_text().splitlines():
            if line.startswith('MemAvailable:'):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 1 << 62


def fits(what: str, rows: int, bytes_per_row: int, remedy: str,
         available: int | None = None) -> None:
    """Refuse (MemoryError with one line) a load of ``rows`` rows that needs more than the
    memory ``available`` (default :func:`available_memory`) for the arrays and their copy when
    finished."""
    need = 2 * rows * bytes_per_row
    avail = available_memory() if available is None else available
    if need > avail:
        raise MemoryError(f'{what}: {rows} rows need about {need / 1e9:.2f} GB and '
                          f'{avail / 1e9:.2f} GB of memory is available; {remedy}')
