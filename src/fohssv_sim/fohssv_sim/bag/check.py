"""Structural check of a bag: what ``pymcap-cli doctor`` checks, written with ``mcap``.

For every MCAP file: magic at both ends, header profile ``ros2``, every record readable in
order, chunk CRCs, the data section CRC and the summary CRC, a summary with statistics; each
chunk index points at a chunk of that length whose message times and per-channel counts it
states; each message index entry points at a message of its channel with its log time;
statistics equal the messages counted; metadata indexes point at metadata records; channels
name existing ``ros2msg``/``ros2idl`` schemas and ``cdr`` encoding; every message decodes
with ``mcap_ros2``'s decoder. For ``metadata.yaml``: every field ``ros2 bag info`` reads, and its
counts, start and duration equal the MCAP's. Pure: no rclpy.

Streamed: the file is read record by record and seeked to each indexed record, so the memory
a check needs is bounded by the largest chunk (plus the summary), not the bag's size: a
one-hour 10 kHz bag checks like a one-second one.
"""

from __future__ import annotations

import io
import os
import struct
import sys
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk, Footer, Header, Message, MessageIndex, Metadata
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap_ros2.decoder import DecoderFactory

from .loader import BagError, locate

__all__ = ['CheckReport', 'check', 'REQUIRED_METADATA_FIELDS']

#: metadata.yaml fields ``ros2 bag info`` (rosbag2_storage's YAML reader, version 9) reads.
REQUIRED_METADATA_FIELDS = ('version', 'storage_identifier', 'duration', 'starting_time',
                            'message_count', 'topics_with_message_count', 'compression_format',
                            'compression_mode', 'relative_file_paths', 'files', 'custom_data',
                            'ros_distro')
_TOPIC_FIELDS = ('name', 'type', 'serialization_format', 'offered_qos_profiles',
                 'type_description_hash')


@dataclass
class CheckReport:
    """Problems found (empty = the bag is sound) and facts worth printing."""

    bag: Path
    problems: list[str] = field(default_factory=list)
    facts: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


class _File:
    """An MCAP file opened for seeking reads (the check never holds the whole file)."""

    def __init__(self, f, size: int) -> None:
        self.f, self.size = f, size

    def record_at(self, offset: int, opcode: int):
        """The record with ``opcode`` at ``offset`` (raises ValueError if it is not there)."""
        if offset < 0 or offset + 9 > self.size:
            raise ValueError(f'no {Opcode(opcode).name} record at byte {offset}')
        self.f.seek(offset)
        head = self.f.read(9)
        if head[0] != opcode:
            raise ValueError(f'no {Opcode(opcode).name} record at byte {offset}')
        length = struct.unpack_from('<Q', head, 1)[0]
        if offset + 9 + length > self.size:
            raise ValueError(f'{Opcode(opcode).name} record at byte {offset} runs past the end')
        reader = StreamReader(io.BytesIO(head + self.f.read(length)), skip_magic=True,
                              emit_chunks=True)
        return next(iter(reader.records)), 9 + length

    def crc32(self, start: int, end: int) -> int:
        """CRC-32 of bytes [start, end), read in blocks of 1 MiB."""
        self.f.seek(start)
        crc, left = 0, max(0, end - start)
        while left:
            block = self.f.read(min(left, 1 << 20))
            if not block:
                break
            crc = zlib.crc32(block, crc)
            left -= len(block)
        return crc


def _check_summary_crc(data: _File, footer: Footer, name: str, p: list[str]) -> None:
    """The footer's CRC of the summary section (0 = not written): it covers the summary from
    ``summary_start`` up to the footer's ``summary_offset_start`` field (MCAP spec)."""
    if footer.summary_start == 0 or footer.summary_crc == 0:
        return
    footer_at = data.size - 8 - (1 + 8 + 20)         # magic, then opcode, length, 20 bytes
    crc = data.crc32(footer.summary_start, footer_at + 1 + 8 + 16)
    if crc != footer.summary_crc:
        p.append(f'{name}: summary CRC mismatch (footer {footer.summary_crc:#010x}, summary '
                 f'section {crc:#010x}); run: python -m fohssv_sim.bag repair')


def _read_records(data: _File, name: str, p: list[str]) -> int | None:
    """Read every record in order with CRC checks: the number of messages, or None (a
    problem recorded) when the file is unreadable, truncated or has no footer."""
    stream_msgs = 0
    try:
        first = True
        saw_footer: Footer | None = None
        data.f.seek(0)
        for rec in StreamReader(data.f, validate_crcs=True).records:
            if first:
                first = False
                if not isinstance(rec, Header):
                    p.append(f'{name}: first record is {type(rec).__name__}, not Header')
                elif rec.profile != 'ros2':
                    p.append(f'{name}: header profile {rec.profile!r}, expected ros2')
            if isinstance(rec, Message):
                stream_msgs += 1
            elif isinstance(rec, Footer):
                saw_footer = rec      # its CRC is checked after the stream (that seeks)
    except (McapError, ValueError, struct.error) as exc:
        p.append(f'{name}: unreadable or truncated ({type(exc).__name__}: {exc}); '
                 'run: python -m fohssv_sim.bag repair')
        return None
    if not saw_footer:
        p.append(f'{name}: no footer')
        return None
    _check_summary_crc(data, saw_footer, name, p)
    return stream_msgs


def _check_channels(summary, name: str, p: list[str]) -> None:
    for chan in summary.channels.values():
        if chan.schema_id not in summary.schemas:
            p.append(f'{name}: channel {chan.topic} names missing schema {chan.schema_id}')
        elif summary.schemas[chan.schema_id].encoding not in ('ros2msg', 'ros2idl'):
            p.append(f'{name}: schema of {chan.topic} has encoding '
                     f'{summary.schemas[chan.schema_id].encoding!r}')
        if chan.message_encoding != 'cdr':
            p.append(f'{name}: channel {chan.topic} encoding {chan.message_encoding!r} != cdr')


def _check_message_index(data: _File, raw: bytes, cid: int, off: int, count: int, where: str,
                         p: list[str]) -> None:
    """The message index of channel ``cid`` at ``off`` lists the ``count`` messages of the
    chunk (uncompressed records ``raw``), each at its offset with its log time."""
    try:
        mi, _ = data.record_at(off, Opcode.MESSAGE_INDEX)
    except ValueError as exc:
        p.append(f'{where}: {exc}')
        return
    assert isinstance(mi, MessageIndex)
    if mi.channel_id != cid or len(mi.records) != count:
        p.append(f'{where}: message index of channel {cid} lists {len(mi.records)} '
                 f'messages, the chunk holds {count}')
    for log_time, moff in mi.records:
        try:
            stream = ReadDataStream(io.BytesIO(raw[moff:]))
            if stream.read1() != Opcode.MESSAGE:
                raise ValueError('not a message')
            msg = Message.read(stream, stream.read8())
        except (McapError, ValueError, struct.error):
            p.append(f'{where}: message index entry at {moff} is not a message')
            return
        if msg.channel_id != cid or msg.log_time != log_time:
            p.append(f'{where}: message index entry at {moff} does not match its message')
            return


def _check_chunk(data: _File, i: int, ci, name: str, p: list[str], decodes: _Decodes
                 ) -> tuple[Counter, tuple[int, int] | None]:
    """Chunk ``i`` matches its chunk index ``ci`` (length, times, message indexes): the
    per-channel counts and the first and last log times of its messages (None if it holds
    none or could not be read)."""
    where = f'{name}: chunk {i} at byte {ci.chunk_start_offset}'
    try:
        chunk, length = data.record_at(ci.chunk_start_offset, Opcode.CHUNK)
    except ValueError as exc:
        p.append(f'{where}: {exc}')
        return Counter(), None
    assert isinstance(chunk, Chunk)
    if length != ci.chunk_length:
        p.append(f'{where}: length {length} != index {ci.chunk_length}')
    inner = [r for r in breakup_chunk(chunk, validate_crc=True) if isinstance(r, Message)]
    decodes.chunk(inner)
    span = None
    if inner:
        lo = min(m.log_time for m in inner)
        hi = max(m.log_time for m in inner)
        span = (lo, hi)
        if (lo, hi) != (ci.message_start_time, ci.message_end_time):
            p.append(f'{where}: message times [{lo}, {hi}] != index '
                     f'[{ci.message_start_time}, {ci.message_end_time}]')
    per_chan = Counter(m.channel_id for m in inner)
    if set(ci.message_index_offsets) != set(per_chan):
        p.append(f'{where}: message indexes for channels {sorted(ci.message_index_offsets)}'
                 f' but messages on {sorted(per_chan)}')
    for cid, off in ci.message_index_offsets.items():
        _check_message_index(data, chunk.data, cid, off, per_chan.get(cid, 0), where, p)
    return per_chan, span


def _check_statistics(stats, summary, counts: Counter, indexed: int, stream_msgs: int,
                      times: tuple[int | None, int | None], name: str, p: list[str]) -> None:
    if indexed != stream_msgs:
        p.append(f'{name}: {stream_msgs} messages in the file, {indexed} in indexed chunks')
    if stats.message_count != indexed or dict(stats.channel_message_counts) != dict(counts):
        p.append(f'{name}: statistics say {stats.message_count} messages '
                 f'{dict(stats.channel_message_counts)}, found {indexed} {dict(counts)}')
    if stats.chunk_count != len(summary.chunk_indexes):
        p.append(f'{name}: statistics say {stats.chunk_count} chunks, index has '
                 f'{len(summary.chunk_indexes)}')
    if indexed and (stats.message_start_time, stats.message_end_time) != times:
        p.append(f'{name}: statistics times differ from the messages\'')


def _check_metadata_indexes(data: _File, summary, stats, name: str, p: list[str]) -> None:
    for mi in summary.metadata_indexes:
        try:
            rec, length = data.record_at(mi.offset, Opcode.METADATA)
        except ValueError as exc:
            p.append(f'{name}: metadata index: {exc}')
            continue
        if not isinstance(rec, Metadata) or rec.name != mi.name or length != mi.length:
            p.append(f'{name}: metadata index entry {mi.name!r} does not match its record')
    if stats.metadata_count != len(summary.metadata_indexes):
        p.append(f'{name}: statistics say {stats.metadata_count} metadata records, index has '
                 f'{len(summary.metadata_indexes)}')


class _Decodes:
    """Every message decodes with ``mcap_ros2``'s decoder, checked chunk by chunk as the
    chunks are read (mcap's own ``iter_decoded_messages(log_time_order=False)`` reads every
    chunk before it yields a message: the whole file in memory). The first failure is the
    finding."""

    def __init__(self, summary, name: str, p: list[str]) -> None:
        self.summary, self.name, self.p = summary, name, p
        self.factory = DecoderFactory()
        self.decoders: dict[int, Any] = {}
        self.failed = False
        self.topic = '?'

    def chunk(self, messages: list[Message]) -> None:
        if self.failed:
            return
        try:
            for m in messages:
                decode = self.decoders.get(m.channel_id)
                chan = self.summary.channels[m.channel_id]
                if decode is None:
                    schema = self.summary.schemas.get(chan.schema_id)
                    decode = self.factory.decoder_for(chan.message_encoding, schema)
                    if decode is None:
                        raise ValueError(f'no decoder for {chan.message_encoding!r}')
                    self.decoders[m.channel_id] = decode
                decode(m.data)
                self.topic = chan.topic
        except Exception as exc:  # noqa: BLE001 - any decoder failure is a finding
            self.failed = True
            self.p.append(f'{self.name}: a message after one on {self.topic} does not decode '
                          f'with mcap_ros2 ({type(exc).__name__}: {exc})')


def _check_mcap(path: Path, report: CheckReport) -> tuple[Counter, int, int] | None:
    with path.open('rb') as f:
        return _check_open_mcap(_File(f, os.fstat(f.fileno()).st_size), path.name, report)


def _check_open_mcap(data: _File, name: str, report: CheckReport
                     ) -> tuple[Counter, int, int] | None:
    p = report.problems
    stream_msgs = _read_records(data, name, p)
    if stream_msgs is None:
        return None
    report.facts.append(f'{name}: {data.size} bytes, every record read, chunk and data CRCs '
                        'valid')
    try:
        data.f.seek(0)
        reader = make_reader(data.f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
    except (McapError, ValueError, struct.error) as exc:
        p.append(f'{name}: summary unreadable ({exc})')
        return None
    if summary is None or summary.statistics is None:
        p.append(f'{name}: no summary or no statistics record')
        return None
    stats = summary.statistics
    _check_channels(summary, name, p)
    counts: Counter = Counter()
    times: list[int] = []
    indexed = 0
    decodes = _Decodes(summary, name, p)
    for i, ci in enumerate(summary.chunk_indexes):
        per_chan, span = _check_chunk(data, i, ci, name, p, decodes)
        counts.update(per_chan)
        indexed += sum(per_chan.values())
        if span is not None:
            times = [min([span[0], *times[:1]]), max([span[1], *times[1:]])]
    t_min, t_max = (times[0], times[1]) if times else (None, None)
    _check_statistics(stats, summary, counts, indexed, stream_msgs, (t_min, t_max), name, p)
    _check_metadata_indexes(data, summary, stats, name, p)
    report.facts.append(f'{name}: {indexed} messages in {len(summary.chunk_indexes)} indexed '
                        f'chunks, {len(summary.channels)} channels, '
                        f'{len(summary.metadata_indexes)} metadata records, all decode')
    topics = Counter()
    for cid, n in counts.items():
        topics[summary.channels[cid].topic] += n
    for chan in summary.channels.values():
        topics.setdefault(chan.topic, 0)
    return topics, t_min or 0, t_max or 0


def _check_metadata_yaml(info: dict, topics: Counter, t0: int, t1: int,
                         hashes: dict[str, tuple[str, str]], report: CheckReport) -> None:
    p = report.problems
    missing = [f for f in REQUIRED_METADATA_FIELDS if f not in info]
    if missing:
        p.append(f'metadata.yaml: missing {missing}')
        return
    if info['version'] != 9:
        p.append(f"metadata.yaml: version {info['version']}, expected 9")
    try:
        start = info['starting_time']['nanoseconds_since_epoch']
        duration = info['duration']['nanoseconds']
    except (KeyError, TypeError):
        p.append('metadata.yaml: starting_time/duration lack their nanoseconds fields')
        return
    total = sum(topics.values())
    if info['message_count'] != total:
        p.append(f"metadata.yaml: message_count {info['message_count']} != {total} in MCAP")
    if total and (start, duration) != (t0, t1 - t0):
        p.append(f'metadata.yaml: starting_time/duration {start}/{duration} != MCAP '
                 f'{t0}/{t1 - t0}')
    listed = {}
    for entry in info['topics_with_message_count'] or []:
        tm = entry.get('topic_metadata', {})
        lack = [f for f in _TOPIC_FIELDS if f not in tm]
        if lack or 'message_count' not in entry:
            p.append(f"metadata.yaml: topic {tm.get('name')} lacks {lack or ['message_count']}")
            continue
        listed[tm['name']] = entry['message_count']
        if tm['name'] in hashes:
            msgtype, rihs = hashes[tm['name']]
            if tm['type'] != msgtype:
                p.append(f"metadata.yaml: {tm['name']} type {tm['type']} != MCAP {msgtype}")
            if rihs and tm['type_description_hash'] != rihs:
                p.append(f"metadata.yaml: {tm['name']} type hash differs from the MCAP's")
    if listed != dict(topics):
        p.append(f'metadata.yaml: topic counts {listed} != MCAP {dict(topics)}')
    for f in info['files'] or []:
        if not {'path', 'starting_time', 'duration', 'message_count'} <= set(f):
            p.append(f'metadata.yaml: files entry {f} lacks fields')


def check(path: str | Path) -> CheckReport:
    """Check the bag at ``path``; the report lists every problem found.

    Raises:
        BagError: the path is not a bag at all (see :func:`.loader.locate`).
    """
    files = locate(path)
    report = CheckReport(files.directory)
    total: Counter = Counter()
    t0, t1 = None, None
    hashes: dict[str, tuple[str, str]] = {}
    for mcap_path in files.mcap_files:
        res = _check_mcap(mcap_path, report)
        if res is None:
            continue
        topics, lo, hi = res
        total.update(topics)
        for chan_topic in topics:
            total.setdefault(chan_topic, 0)
        if topics and sum(topics.values()):
            t0 = lo if t0 is None else min(t0, lo)
            t1 = hi if t1 is None else max(t1, hi)
        with mcap_path.open('rb') as f:
            summary = make_reader(f).get_summary()
        if summary is not None:
            for chan in summary.channels.values():
                schema = summary.schemas.get(chan.schema_id)
                hashes[chan.topic] = (schema.name if schema else '',
                                      chan.metadata.get('topic_type_hash', ''))
    if files.info is None:
        report.problems.append(f'{files.directory}: no metadata.yaml; run: python -m '
                               'fohssv_sim.bag repair')
    elif not report.problems:
        _check_metadata_yaml(files.info, total, t0 or 0, t1 or 0, hashes, report)
    return report


def main_check(argv: list[str]) -> int:
    """``check BAG``: print the facts and problems; exit 0 if sound, 1 otherwise."""
    if len(argv) != 1:
        print('usage: python -m fohssv_sim.bag check BAG', file=sys.stderr)
        return 2
    try:
        report = check(argv[0])
    except BagError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
    for fact in report.facts:
        print(fact)
    for problem in report.problems:
        print(f'problem: {problem}')
    print(f'{report.bag}: ' + ('OK' if report.ok else f'{len(report.problems)} problem(s)'))
    return 0 if report.ok else 1

