"""Write a run to a rosbag2 bag (metadata version 9, MCAP storage) that survives a SIGKILL.

:class:`RunWriter` is the rosbags :class:`~rosbags.rosbag2.Writer` (which owns the connections
and writes ``metadata.yaml`` in the version 9 layout that ``ros2 bag info`` reads) with its
MCAP storage replaced by one built on the ``mcap`` library, because rosbags' own MCAP storage
fixes the chunk size at 1 MiB, has no flush, writes no chunk CRCs and cannot add a metadata
record. The replacement writes what rosbag2's MCAP storage writes (profile ``ros2``, schemas in
``ros2msg``, channels with ``offered_qos_profiles`` and ``topic_type_hash`` metadata, the
``rosbag2`` metadata record with the serialized bag information at close) plus:

* chunk CRCs and a data section CRC, so :mod:`.check` can verify every byte;
* :meth:`RunWriter.flush`: ends the chunk in progress and hands it to the OS. A process
  killed with SIGKILL loses only what it received after its last flush (see
  ``docs/recording.md`` for the bound the recorder guarantees);
* :meth:`RunWriter.add_metadata`: an MCAP metadata record written at once (outside any chunk),
  so the run's metadata survives a SIGKILL. The same keys go into ``metadata.yaml``
  ``custom_data`` at close. Record names are unique (MCAP tools warn about duplicates):
  ``fohssv``, then ``fohssv.2``, ``fohssv.3``, ... (:func:`is_run_metadata`); readers merge
  them in file order.

Every MCAP file written here passes ``pymcap-cli doctor`` without error or warning (tested):
no summary offset for an index group that is empty, schemas and channels in the data section
even without messages, unique metadata names.

Pure module: no rclpy.
"""

from __future__ import annotations

import json
import math
import os
import struct
import subprocess
import tempfile
from collections.abc import Iterable, Iterator, Mapping, Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as McapFileWriter
from rosbags.interfaces import Connection, MessageDefinitionFormat, Qos
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

__all__ = ['RunWriter', 'METADATA_NAME', 'DEFAULT_CHUNK_SIZE', 'typestore', 'encode_metadata',
           'library_versions', 'is_run_metadata', 'source_info', 'LogTimes']

#: Name of the first MCAP metadata record that carries the run's metadata; later ones are
#: ``fohssv.2``, ``fohssv.3``, ...
METADATA_NAME = 'fohssv'


def is_run_metadata(name: str) -> bool:
    """Whether an MCAP metadata record named ``name`` carries run metadata (``fohssv`` or
    ``fohssv.<n>``; bags written before the names were unique repeat ``fohssv``)."""
    head, _, tail = name.partition('.')
    return head == METADATA_NAME and (not tail or tail.isdigit())
#: Upper bound of one chunk's uncompressed size (bytes); a chunk also ends at every flush.
DEFAULT_CHUNK_SIZE = 64 * 1024

_TYPESTORE = None


def typestore():
    """The rosbags typestore used to describe and decode messages (ROS 2 Kilted)."""
    global _TYPESTORE
    if _TYPESTORE is None:
        _TYPESTORE = get_typestore(Stores.ROS2_KILTED)
    return _TYPESTORE


def _version(dist: str) -> str:
    try:
        return version(dist)
    except PackageNotFoundError:
        return 'unknown'


def library_versions() -> str:
    """The MCAP header's library string: who wrote the file."""
    return (f"fohssv_sim {_version('fohssv_sim')}; rosbags {_version('rosbags')}; "
            f"mcap {_version('mcap')}")


def source_info() -> dict[str, str]:
    """Package version and the source tree's git revision (when it is a git checkout): the
    first run metadata of every bag the project records (recorder node and in-plant)."""
    info = {'fohssv.version': _version('fohssv_sim')}
    root = os.environ.get('FOHSSV_ROOT') or str(Path(__file__).resolve().parents[2])
    for key, cmd in (('fohssv.git_describe', ['describe', '--always', '--dirty', '--tags']),
                     ('fohssv.git_revision', ['rev-parse', 'HEAD'])):
        try:
            out = subprocess.run(['git', '-C', root, *cmd], capture_output=True, text=True,
                                 timeout=5)
            if out.returncode == 0:
                info[key] = out.stdout.strip()
        except (OSError, subprocess.SubprocessError):
            pass
    return info


def encode_metadata(values: Mapping[str, Any]) -> dict[str, str]:
    """Metadata values as the strings MCAP and ``custom_data`` require: strings as they are,
    everything else as JSON (decoded again by the loader)."""
    return {str(k): v if isinstance(v, str) else json.dumps(v, sort_keys=True)
            for k, v in values.items()}


_MESSAGE_HEAD = struct.Struct('<BQHIQQ')   # opcode, record length, channel, sequence, times
_MESSAGE_OPCODE = Opcode.MESSAGE
_MESSAGE_FIELDS = 22                       # channel, sequence, log and publish time (bytes)


class _MessageIndex(MessageIndex):
    """The library's message index record, written with one pack for all its entries (its own
    ``write`` makes two calls per message: a tenth of a message's cost here)."""

    def write(self, stream) -> None:
        records = self.records
        if not any(isinstance(entry, np.ndarray) for entry in records):
            flat = [v for entry in records for v in entry]
            stream.write(struct.pack(f'<BQHI{len(flat)}Q', Opcode.MESSAGE_INDEX,
                                     6 + 8 * len(flat), self.channel_id, 8 * len(flat), *flat))
            return
        # blocks of entries from the compiled path (_Messages.add_packed, (n, 2) arrays) and
        # the few single entries of the records it left to the interpreted one, in order
        flat = np.concatenate([np.asarray(entry, dtype='<u8').reshape(-1, 2)
                               for entry in records]).tobytes()
        stream.write(struct.pack('<BQHI', Opcode.MESSAGE_INDEX, 6 + len(flat), self.channel_id,
                                 len(flat)) + flat)


class _Messages:
    """Messages into the ``mcap`` Writer's chunk in progress, as its ``add_message`` puts them
    (the same bytes: tested against it), without its three record objects and a dozen calls
    per message, which were most of a recorded message's cost.

    What ``add_message`` does, on the writer's own state (mcap 1.6.0 internals, pinned): the
    message record appended to the chunk builder's buffer, the chunk's message index entry,
    start and end times and count, the file's statistics; the chunk ends (the library's
    ``__finalize_chunk``) once its size passes ``chunk_size``. Everything else (chunk records,
    CRCs, indexes, summary) stays the library's.
    """

    def __init__(self, mcap: McapFileWriter, chunk_size: int) -> None:
        try:
            self._chunk = mcap._Writer__chunk_builder                  # noqa: SLF001
            self._stats = mcap._Writer__statistics                     # noqa: SLF001
            self._finalize = mcap._Writer__finalize_chunk              # noqa: SLF001
            self._chunk.record_writer._buffer                          # noqa: B018, SLF001
        except AttributeError as exc:    # pragma: no cover - a changed mcap (it is pinned)
            raise RuntimeError(f'mcap {_version("mcap")}: the chunk builder this writer '
                               f'feeds changed ({exc}); pin mcap==1.6.0') from exc
        self._chunk_size = chunk_size
        self.sequence: dict[int, int] = {}
        self.count = 0

    def add(self, channel_id: int, log_time: int, data: bytes | memoryview) -> None:
        """One message (sequence numbers count per channel from 1, as rosbag2 writes them)."""
        self.add_many(((channel_id, log_time, data),))

    def add_many(self, messages) -> None:
        """Messages ``(channel id, log time ns, data)`` in order (an iterable)."""
        chunk = self._chunk
        stats = self._stats
        sequence = self.sequence
        counts = stats.channel_message_counts
        limit = self._chunk_size
        head = _MESSAGE_HEAD.pack
        buf = chunk.record_writer._buffer                              # noqa: SLF001
        write = buf.write
        offset = buf.tell()
        indices = chunk.message_indices
        first = chunk.num_messages == 0
        lo, hi = chunk.message_start_time, chunk.message_end_time
        written = 0
        for channel_id, t, data in messages:
            seq = sequence.get(channel_id, 0) + 1
            sequence[channel_id] = seq
            index = indices.get(channel_id)
            if index is None:
                index = indices[channel_id] = _MessageIndex(channel_id=channel_id, records=[])
            index.records.append((t, offset))
            n = len(data)
            write(head(_MESSAGE_OPCODE, _MESSAGE_FIELDS + n, channel_id, seq & 0xFFFFFFFF,
                       t, t))
            write(data)
            offset += 9 + _MESSAGE_FIELDS + n
            counts[channel_id] += 1
            written += 1
            if first:
                lo = hi = t
                first = False
            elif t < lo:
                lo = t
            if t > hi:
                hi = t
            if offset > limit:
                self._end_chunk(lo, hi, written)
                written = 0
                first = True
                lo, hi = chunk.message_start_time, chunk.message_end_time
                buf = chunk.record_writer._buffer                      # noqa: SLF001
                write = buf.write
                offset = buf.tell()
        if written:
            chunk.num_messages += written
            chunk.message_start_time, chunk.message_end_time = lo, hi
            self._count(written, lo, hi)

    def room(self) -> int:
        """Bytes the chunk in progress takes before it passes ``chunk_size`` (and ends)."""
        return self._chunk_size - self._chunk.record_writer._buffer.tell()  # noqa: SLF001

    def add_packed(self, block, logs: np.ndarray, offsets: np.ndarray, channels: np.ndarray,
                   sequence: dict[int, int]) -> None:
        """Message records packed by the compiled path (:func:`.ringpack.pack`): ``block``
        holds them end to end, ``logs``, ``offsets`` (in ``block``) and ``channels`` describe
        each, ``sequence`` is every channel's last sequence number after them. What
        :meth:`add_many` does for the same messages (the chunk ends once its size passes
        ``chunk_size``, which the packer stops at)."""
        chunk = self._chunk
        buf = chunk.record_writer._buffer                              # noqa: SLF001
        base = buf.tell()
        buf.write(block)
        indices = chunk.message_indices
        counts = self._stats.channel_message_counts
        seen, first = np.unique(channels, return_index=True)
        for ch in seen[np.argsort(first)].tolist():      # in order of appearance, as add_many
            mine = channels == ch
            entries = np.empty((int(np.count_nonzero(mine)), 2), dtype='<u8')
            entries[:, 0] = logs[mine]
            entries[:, 1] = offsets[mine] + base
            index = indices.get(ch)
            if index is None:
                index = indices[ch] = _MessageIndex(channel_id=ch, records=[])
            index.records.append(entries)
            counts[ch] += len(entries)
        self.sequence.update(sequence)
        written = len(logs)
        lo, hi = int(logs.min()), int(logs.max())
        if chunk.num_messages:
            lo = min(lo, chunk.message_start_time)
            hi = max(hi, chunk.message_end_time)
        if base + len(block) > self._chunk_size:
            self._end_chunk(lo, hi, written)
            return
        chunk.num_messages += written
        chunk.message_start_time, chunk.message_end_time = lo, hi
        self._count(written, lo, hi)

    def _end_chunk(self, lo: int, hi: int, written: int) -> None:
        chunk = self._chunk
        chunk.num_messages += written
        chunk.message_start_time, chunk.message_end_time = lo, hi
        self._count(written, lo, hi)
        self._finalize()

    def _count(self, written: int, lo: int, hi: int) -> None:
        stats = self._stats
        if stats.message_count == 0:
            stats.message_start_time = lo
        else:
            stats.message_start_time = min(lo, stats.message_start_time)
        stats.message_end_time = max(hi, stats.message_end_time)
        stats.message_count += written
        self.count += written


class _SpooledIndexes:
    """The ``mcap`` writer's list of chunk index records, kept serialized in an unlinked
    temporary file beside the bag instead of as objects in memory, and read back when the
    summary is written: a recorder's memory stays flat over a long run (the list grew by
    0.6-0.8 MB a minute at a flush every 0.1 s). The writer only appends to it and iterates it
    once at ``finish`` (mcap 1.6.0 internals, pinned)."""

    def __init__(self, directory: Path) -> None:
        self._file = tempfile.TemporaryFile(dir=directory)
        self._n = 0

    def append(self, index: Any) -> None:
        builder = RecordBuilder()
        index.write(builder)
        self._file.write(builder.end())
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def __iter__(self) -> Iterator[_Record]:
        self._file.seek(0)
        data = self._file.read()
        pos = 0
        while pos < len(data):
            (size,) = struct.unpack_from('<Q', data, pos + 1)
            yield _Record(data[pos:pos + 9 + size])
            pos += 9 + size

    def close(self) -> None:
        self._file.close()


class _Record:
    """One serialized record, written as it is."""

    def __init__(self, data: bytes) -> None:
        self.data = data

    def write(self, builder: RecordBuilder) -> None:
        builder.write(self.data)


class _McapStorage:
    """rosbags storage plugin writing MCAP with the ``mcap`` library (see module docstring)."""

    chunk_size = DEFAULT_CHUNK_SIZE

    def __init__(self, path: Path, compression: Any) -> None:
        _ = compression  # the bag is written uncompressed (small messages, flushed often)
        self.path = path / f'{path.name}.mcap'
        self._file = self.path.open('xb')
        # no attachment index: a run has no attachments, and the library writes a summary
        # offset for every index type it is given, even an empty group, which MCAP readers
        # (``pymcap-cli doctor``: SUMMARY_OFFSET_WITHOUT_GROUP) report as an error
        self._mcap = McapFileWriter(self._file, chunk_size=self.chunk_size,
                                    compression=CompressionType.NONE, enable_crcs=True,
                                    enable_data_crcs=True,
                                    index_types=IndexType.ALL & ~IndexType.ATTACHMENT)
        self._mcap.start(profile='ros2', library=library_versions())
        self._indexes = _SpooledIndexes(path)
        self._mcap._Writer__chunk_indices = self._indexes                # noqa: SLF001
        self.messages = _Messages(self._mcap, self.chunk_size)
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}

    def add_msgtype(self, connection: Connection) -> None:
        fmt = 'ros2idl' if connection.msgdef.format == MessageDefinitionFormat.IDL else 'ros2msg'
        self._schemas[connection.msgtype] = self._mcap.register_schema(
            connection.msgtype, fmt, connection.msgdef.data.encode())

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        ext = connection.ext
        self._channels[connection.id] = self._mcap.register_channel(
            connection.topic, getattr(ext, 'serialization_format', 'cdr'),
            self._schemas[connection.msgtype],
            {'offered_qos_profiles': offered_qos_profiles, 'topic_type_hash': connection.digest})

    def channel_id(self, connection: Connection) -> int:
        return self._channels[connection.id]

    @property
    def statistics(self):
        """The library's statistics record in progress (message count, first and last time)."""
        return self.messages._stats                                     # noqa: SLF001

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        self.messages.add(self._channels[connection.id], timestamp, data)

    def add_metadata(self, name: str, values: Mapping[str, str]) -> None:
        self._mcap.add_metadata(name, dict(values))
        self._file.flush()

    def flush(self) -> tuple[int, int]:
        self._mcap.flush()
        return self._file.tell(), self.messages.count

    def close(self, version: int, metadata: str) -> None:
        _ = version
        self._mcap.add_metadata('rosbag2', {'serialized_metadata': metadata})
        if not self.messages.count:
            self._finish_empty()
        self._mcap.finish()
        self._file.close()
        self._indexes.close()

    def _finish_empty(self) -> None:
        """Prepare a run without messages for ``finish()`` (mcap 1.6.0 internals, pinned; the
        doctor test of an empty bag fails if they change).

        The library keeps schemas and channels in the chunk in progress and never writes a
        chunk without messages, so they would be in the summary only (doctor:
        SUMMARY_SCHEMA_MISSING_IN_DATA, STATISTICS_MISMATCH): write them in the data section,
        outside any chunk, as MCAP allows. And no chunk means an empty chunk-index group,
        which would again get a summary offset (see ``__init__``), as would empty schema and
        channel groups (a recorder stopped before it declared its topics)."""
        mcap = self._mcap
        records = mcap._Writer__record_builder  # noqa: SLF001
        schemas = list(mcap._Writer__schemas.values())  # noqa: SLF001
        channels = list(mcap._Writer__channels.values())  # noqa: SLF001
        for record in (*schemas, *channels):
            record.write(records)
        mcap.flush()      # into the data section and its CRC
        mcap._Writer__index_types &= ~IndexType.CHUNK  # noqa: SLF001
        if not schemas:
            mcap._Writer__repeat_schemas = False  # noqa: SLF001
        if not channels:
            mcap._Writer__repeat_channels = False  # noqa: SLF001

    def abort(self) -> None:
        self._mcap.flush()
        self._file.close()
        self._indexes.close()


def _rosbag2_writer(path: Path, chunk_size: int) -> Writer:
    """A rosbags Writer whose MCAP storage is :class:`_McapStorage` with ``chunk_size``."""
    storage = type('_McapStorageSized', (_McapStorage,), {'chunk_size': chunk_size})
    writer_cls = type('_Rosbag2Writer', (Writer,),
                      {'STORAGE_PLUGINS': {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: storage}})
    return writer_cls(path, version=9, storage_plugin=StoragePlugin.MCAP)


class RunWriter:
    """A rosbag2 bag (version 9, MCAP) being written. Use as a context manager or call
    :meth:`open` / :meth:`close`.

    Args:
        path: the bag directory to create (must not exist); the MCAP file is
            ``<path>/<path name>.mcap``.
        chunk_size: a chunk ends when its uncompressed size exceeds this (bytes).

    Raises:
        rosbags.rosbag2.WriterError: ``path`` exists already.
    """

    def __init__(self, path: str | Path, *, chunk_size: int = DEFAULT_CHUNK_SIZE) -> None:
        self.path = Path(path)
        self.chunk_size = int(chunk_size)
        if self.chunk_size < 1:
            raise ValueError(f'chunk_size={chunk_size!r} must be a positive number of bytes')
        self._bag = _rosbag2_writer(self.path, self.chunk_size)
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        self._metadata: dict[str, str] = {}
        self._records = 0

    @property
    def mcap_path(self) -> Path:
        return self.path / f'{self.path.name}.mcap'

    def open(self) -> RunWriter:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._bag.open()
        return self

    def __enter__(self) -> RunWriter:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def add_topic(self, topic: str, msgtype: str, *, qos: Sequence[Qos] = (),
                  msgdef: str | None = None, rihs01: str | None = None) -> None:
        """Declare ``topic`` of type ``msgtype`` (description from the Kilted typestore unless
        ``msgdef`` and ``rihs01`` are given)."""
        if msgdef is None or rihs01 is None:
            conn = self._bag.add_connection(topic, msgtype, typestore=typestore(),
                                            offered_qos_profiles=qos)
        else:
            conn = self._bag.add_connection(topic, msgtype, msgdef=msgdef, rihs01=rihs01,
                                            offered_qos_profiles=qos)
        self._connections[topic] = conn
        self.counts[topic] = 0

    @property
    def topics(self) -> tuple[str, ...]:
        return tuple(self._connections)

    @property
    def newest(self) -> int | None:
        """The latest log time written (ns); None before the first message."""
        return self._bag.max_timestamp if any(self.counts.values()) else None

    def write(self, topic: str, log_time: int, data: bytes | memoryview) -> None:
        """Write one serialized (CDR) message of ``topic`` at ``log_time`` (ns).

        What rosbags' ``Writer.write`` does for an uncompressed bag (the storage's write, the
        connection's count and the bag's time span for ``metadata.yaml``) without its search
        of the connection list: a quarter of the cost of a message here (the recorder and the
        in-plant writer call this for every message)."""
        bag = self._bag
        storage = bag.storage
        if storage is None:
            raise RuntimeError(f'{self.path}: the bag is not open')
        conn = self._connections[topic]
        t = int(log_time)
        storage.write(conn, t, data)
        bag.counts[conn.id] += 1
        if t < bag.min_timestamp:
            bag.min_timestamp = t
        if t > bag.max_timestamp:
            bag.max_timestamp = t
        self.counts[topic] += 1

    def channel_ids(self) -> dict[str, int]:
        """The MCAP channel id of each topic (for :meth:`write_many`)."""
        storage = self._storage()
        return {topic: storage.channel_id(conn) for topic, conn in self._connections.items()}

    def write_many(self, messages: Iterable[tuple[int, int, bytes | memoryview]]) -> None:
        """Write serialized messages ``(channel id, log time ns, CDR)`` in order, channel ids
        from :meth:`channel_ids`: what :meth:`write` does for each, in one call (the in-plant
        writer's batches)."""
        storage = self._storage()
        sink = storage.messages
        before = sink.count
        sink.add_many(messages)
        if sink.count != before:
            self._counted(storage)

    @property
    def sequence(self) -> dict[int, int]:
        """Each channel's last sequence number (the number of its messages written)."""
        return self._storage().messages.sequence

    def chunk_room(self) -> int:
        """Bytes the chunk in progress takes before it ends."""
        return self._storage().messages.room()

    def write_packed(self, block, logs: np.ndarray, offsets: np.ndarray,
                     channels: np.ndarray, sequence: dict[int, int]) -> None:
        """Message records the compiled path packed (:class:`.ringpack.Packer`), what
        :meth:`write_many` does for the same messages."""
        storage = self._storage()
        storage.messages.add_packed(block, logs, offsets, channels, sequence)
        self._counted(storage)

    def _counted(self, storage: _McapStorage) -> None:
        """The topics' counts and the bag's time span after messages were added."""
        bag = self._bag
        sequence = storage.messages.sequence
        for topic, conn in self._connections.items():
            n = sequence.get(storage.channel_id(conn), 0)
            self.counts[topic] = n
            bag.counts[conn.id] = n
        stats = storage.statistics
        bag.min_timestamp = min(bag.min_timestamp, stats.message_start_time)
        bag.max_timestamp = max(bag.max_timestamp, stats.message_end_time)

    def add_metadata(self, values: Mapping[str, Any]) -> None:
        """Write ``values`` now as an MCAP metadata record (named :data:`METADATA_NAME` the first
        time, ``fohssv.<n>`` the n-th) and keep them for ``metadata.yaml`` ``custom_data``
        (non-string values are stored as JSON)."""
        encoded = encode_metadata(values)
        self._metadata.update(encoded)
        self._records += 1
        name = METADATA_NAME if self._records == 1 else f'{METADATA_NAME}.{self._records}'
        self._storage().add_metadata(name, encoded)

    def flush(self) -> tuple[int, int]:
        """End the chunk in progress (if any) and hand everything written to the OS; the
        file's size then and the messages it holds (a reader of the file cut there finds
        them all)."""
        return self._storage().flush()

    def close(self) -> None:
        """Write the summary, the index and ``metadata.yaml``. Idempotent."""
        if self._bag.storage is None:
            return
        for key, value in self._metadata.items():
            self._bag.set_custom_data(key, value)
        self._bag.close()

    def _storage(self) -> _McapStorage:
        storage = self._bag.storage
        if storage is None:
            raise RuntimeError(f'{self.path}: the bag is not open')
        return storage  # type: ignore[return-value]


_CDR_LE = b'\x00\x01'
_F64 = struct.Struct('<d')
_FLOAT64_ARRAY = 'std_msgs/msg/Float64MultiArray'
_CLOCK = 'rosgraph_msgs/msg/Clock'


class LogTimes:
    """The recorder's log times (ns) from the raw CDR of a message (``docs/recording.md``):
    ``round(data[0] * 1e9)`` for the Float64MultiArray topics (the previous log time when
    ``data[0]`` is not a time), the stamp for ``/clock``, ``header.stamp`` for the typed views
    (the previous log time when it is negative)."""

    def __init__(self) -> None:
        self.last = 0
        self._offsets: dict[tuple[int, bytes], int] = {}
        self._ts = typestore()

    def array(self, raw: bytes | memoryview) -> int:
        at = self._offsets.get((len(raw), bytes(raw[:12])))
        t = self._first(raw) if at is None else _F64.unpack_from(raw, at)[0] if at >= 0 \
            else math.nan
        # False for NaN and both infinities too
        log = round(t * 1e9) if 0 <= t < 9e9 else self.last
        self.last = log
        return log

    def clock(self, raw: bytes | memoryview) -> int:
        if raw[:2] == _CDR_LE and len(raw) >= 12:
            sec, nanosec = struct.unpack_from('<iI', raw, 4)
        else:
            c = self._ts.deserialize_cdr(bytes(raw), _CLOCK).clock
            sec, nanosec = c.sec, c.nanosec
        return sec * 1_000_000_000 + nanosec

    def stamped(self, raw: bytes | memoryview, msgtype: str) -> int:
        if raw[:2] == _CDR_LE and len(raw) >= 12:
            sec, nanosec = struct.unpack_from('<iI', raw, 4)
        else:
            stamp = self._ts.deserialize_cdr(bytes(raw), msgtype).header.stamp
            sec, nanosec = stamp.sec, stamp.nanosec
        log = sec * 1_000_000_000 + nanosec
        return log if log >= 0 else self.last

    def _first(self, raw: bytes | memoryview) -> float:
        """``data[0]`` of a Float64MultiArray (NaN when empty); the offset is found once per
        layout (the length and the first 12 bytes fix it for a one-dimension layout)."""
        key = (len(raw), bytes(raw[:12]))
        at = self._offsets.get(key)
        if at is None:
            at = self._locate(raw)
            if at is None:
                data = self._ts.deserialize_cdr(bytes(raw), _FLOAT64_ARRAY).data
                return float(data[0]) if len(data) else math.nan
            if struct.unpack_from('<I', raw, 4)[0] <= 1:
                self._offsets[key] = at
        return struct.unpack_from('<d', raw, at)[0] if at >= 0 else math.nan

    @staticmethod
    def _locate(raw: bytes | memoryview) -> int | None:
        """Offset of ``data[0]`` in a little-endian CDR Float64MultiArray (-1: no data);
        None when the bytes are not one (the typestore then decodes them)."""
        try:
            if raw[:2] != _CDR_LE:
                return None
            pos = 4
            (ndim,) = struct.unpack_from('<I', raw, pos)
            pos += 4
            for _ in range(ndim):
                (slen,) = struct.unpack_from('<I', raw, pos)
                pos += 4 + slen
                pos = 4 + ((pos - 4 + 3) & ~3)
                pos += 8                                 # size, stride
            pos = 4 + ((pos - 4 + 3) & ~3)
            pos += 4                                     # data_offset
            (count,) = struct.unpack_from('<I', raw, pos)
            pos += 4
            if count == 0:
                return -1
            pos = 4 + ((pos - 4 + 7) & ~7)
            if pos + 8 * count != len(raw):
                return None
            return pos
        except struct.error:
            return None
