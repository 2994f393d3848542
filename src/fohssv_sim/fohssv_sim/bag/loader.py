"""Find and read a rosbag2 bag (MCAP storage), without rclpy.

The MCAP file is read sequentially (``mcap.stream_reader.StreamReader``, chunk and data CRCs
checked), so a bag whose recorder was killed (no summary, no footer, no ``metadata.yaml``)
is read too: everything up to the last complete chunk is recovered. :func:`locate` finds a
bag's files, :func:`scan` gives the raw records (used by the player and the repair command);
:func:`fohssv_sim.bag.run.load_run` decodes the contract topics into arrays.

Accepted paths: a bag directory (with or without ``metadata.yaml``), its ``metadata.yaml``,
or an ``.mcap`` file.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from mcap.exceptions import McapError
from mcap.records import Channel, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import CRCValidationError, StreamReader
from ruamel.yaml import YAML
from ruamel.yaml.error import YAMLError
from ruamel.yaml.events import AliasEvent

from .writer import is_run_metadata

__all__ = ['BagError', 'BagFiles', 'ChannelInfo', 'Scan', 'locate', 'scan', 'stream',
           'decode_metadata', 'run_metadata', 'basename']

MCAP_MAGIC = b'\x89MCAP0\r\n'


class BagError(Exception):
    """The path is not a readable bag. The message names the file and what is wrong."""


@dataclass(frozen=True)
class BagFiles:
    """Where a bag's pieces are: its directory, ``metadata.yaml`` (if any) and MCAP files."""

    directory: Path
    metadata_yaml: Path | None
    mcap_files: tuple[Path, ...]
    info: dict[str, Any] | None     # rosbag2_bagfile_information from metadata.yaml


@dataclass(frozen=True)
class ChannelInfo:
    """One MCAP channel with its schema."""

    id: int
    topic: str
    msgtype: str
    message_encoding: str
    schema_encoding: str
    schema: str
    metadata: dict[str, str]


@dataclass
class Scan:
    """Everything readable in a bag, in file order."""

    files: BagFiles
    channels: dict[int, ChannelInfo] = field(default_factory=dict)
    #: (channel id, log time ns, serialized data) in file (= receive) order (empty when
    #: :func:`scan` handed them to ``on_message``).
    messages: list[tuple[int, int, bytes]] = field(default_factory=list)
    #: Messages read.
    message_count: int = 0
    #: Per channel id: messages read, and the log times (ns) of its first and last.
    channel_counts: dict[int, int] = field(default_factory=dict)
    channel_times: dict[int, tuple[int, int]] = field(default_factory=dict)
    #: (name, key-value map) of every MCAP metadata record.
    metadata_records: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    header_library: str = ''
    #: True when every MCAP file ends with its footer and magic.
    complete: bool = True
    #: '' when complete; otherwise what stopped the reading and where.
    problem: str = ''
    bytes_read: int = 0
    bytes_total: int = 0

    def counts(self) -> dict[str, int]:
        """Messages per topic (channels with no message included, as 0)."""
        out = {c.topic: 0 for c in self.channels.values()}
        for cid, n in self.channel_counts.items():
            out[self.channels[cid].topic] += n
        return out

    def run_metadata(self) -> dict[str, Any]:
        """The run's metadata (:func:`run_metadata`)."""
        return run_metadata(self.files.info, self.metadata_records)


def run_metadata(info: dict[str, Any] | None, records: list[tuple[str, dict[str, str]]]
                 ) -> dict[str, Any]:
    """The run's metadata: ``metadata.yaml`` custom_data (``info``) overlaid by the MCAP
    ``fohssv`` metadata ``records``, JSON values decoded."""
    merged: dict[str, str] = {}
    if info is not None:
        merged.update(info.get('custom_data') or {})
    for name, values in records:
        if is_run_metadata(name):
            merged.update(values)
    return decode_metadata(merged)


def decode_metadata(values: dict[str, str]) -> dict[str, Any]:
    """Decode JSON-encoded values (objects and arrays); leave plain strings as they are."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        if isinstance(value, str) and value[:1] in '{[':
            try:
                out[key] = json.loads(value)
                continue
            except ValueError:
                pass
        out[key] = value
    return out


def _read_metadata_yaml(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text('utf8')
    except (OSError, UnicodeDecodeError) as exc:
        raise BagError(f'{path}: cannot read metadata.yaml ({exc})') from None
    try:
        if any(isinstance(e, AliasEvent) for e in YAML(typ='safe', pure=True).parse(text)):
            raise BagError(f'{path}: metadata.yaml uses YAML aliases (*name), which rosbag2 '
                           'never writes and which can expand to gigabytes; rebuild it with: '
                           f'python -m fohssv_sim.bag repair {path.parent}')
        data = YAML(typ='safe', pure=True).load(text)
    except YAMLError as exc:
        raise BagError(f'{path}: metadata.yaml is not valid YAML ({str(exc).splitlines()[0]}); '
                       f'rebuild it with: python -m fohssv_sim.bag repair {path.parent}'
                       ) from None
    info = data.get('rosbag2_bagfile_information') if isinstance(data, dict) else None
    if not isinstance(info, dict):
        raise BagError(f'{path}: not a rosbag2 metadata.yaml (no rosbag2_bagfile_information)')
    _check_shape(path, info)
    return info


#: The shape of the metadata.yaml fields fohssv reads (a missing or null field is allowed:
#: ``check`` reports missing ones): field -> (accepted types, what it must be, item type).
_SHAPES: dict[str, tuple[tuple[type, ...], str, type | None]] = {
    'version': ((int,), 'an integer', None),
    'storage_identifier': ((str,), 'a string', None),
    'message_count': ((int,), 'an integer', None),
    'duration': ((dict,), 'a mapping (nanoseconds)', None),
    'starting_time': ((dict,), 'a mapping (nanoseconds_since_epoch)', None),
    'relative_file_paths': ((list,), 'a list of file names', str),
    'files': ((list,), 'a list of mappings', dict),
    'topics_with_message_count': ((list,), 'a list of mappings', dict),
    'custom_data': ((dict,), 'a mapping of names to strings', None),
}


def _check_shape(path: Path, info: dict[str, Any]) -> None:
    """Raise BagError naming the first field of the wrong shape (valid YAML is not yet a
    valid rosbag2 metadata.yaml: ``custom_data: [1, 2]``, ``relative_file_paths: 5``)."""
    for name, (types, what, item) in _SHAPES.items():
        value = info.get(name)
        if value is None:
            continue
        ok = isinstance(value, types) and not isinstance(value, bool)
        if ok and item is not None:
            ok = all(isinstance(v, item) for v in value)
        if ok and name == 'topics_with_message_count':
            ok = all(isinstance(e.get('topic_metadata', {}), dict) for e in value)
        if not ok:
            raise BagError(f'{path}: malformed metadata.yaml: {name} is {value!r}, it must be '
                           f'{what}; fix or remove the file (python -m fohssv_sim.bag repair '
                           f'then rebuilds it from the MCAP data)')


def _inside(directory: Path, path: Path) -> bool:
    """True when ``path`` (symbolic links resolved) lies in ``directory``."""
    try:
        path.resolve().relative_to(directory.resolve())
    except (ValueError, OSError, RuntimeError):
        return False
    return True


def _check_mcap_file(path: Path) -> None:
    try:
        size = path.stat().st_size
        with path.open('rb') as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise BagError(f'{path}: cannot read ({exc.strerror})') from None
    if size == 0:
        raise BagError(f'{path}: empty file (0 bytes), not an MCAP bag')
    if head != MCAP_MAGIC[:len(head)] or (len(head) < len(MCAP_MAGIC)):
        if head == MCAP_MAGIC[:len(head)]:
            raise BagError(f'{path}: truncated MCAP file ({size} bytes, shorter than its '
                           'header); nothing to recover')
        raise BagError(f'{path}: not an MCAP file (it does not start with the MCAP magic)')


def _listed_files(p: Path, meta: Path, info: dict, entries: list[Path]) -> tuple[Path, ...]:
    """The MCAP files ``metadata.yaml`` lists (or, when it lists none that exist, the folder's
    ``.mcap`` files).

    Raises:
        BagError: non-MCAP storage, listed files outside the folder, no MCAP file at all.
    """
    storage = str(info.get('storage_identifier', ''))
    if storage != 'mcap':
        raise BagError(f'{meta}: storage {storage!r} is not supported (only mcap)')
    rel = info.get('relative_file_paths') or []
    outside = [r for r in rel if not _inside(p, p / r)]
    if outside:
        raise BagError(f'{meta}: relative_file_paths {outside} lie outside the bag folder '
                       f'{p}; every file of a bag must be inside it')
    files = tuple(p / r for r in rel)
    missing = [f.name for f in files if not f.is_file()]
    if missing or not files:
        found = [e.name for e in entries if e.suffix == '.mcap']
        if not found:
            raise BagError(f'{p}: metadata.yaml lists {missing or "no files"} but the '
                           'directory holds no .mcap file')
        files = tuple(p / n for n in found)
    return files


def locate(path: str | Path) -> BagFiles:
    """Find a bag's ``metadata.yaml`` and MCAP files.

    Raises:
        BagError: missing path, empty directory, not a bag, non-MCAP storage.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f'{p}: no such file or directory')
    if p.is_file():
        if p.name == 'metadata.yaml':
            return locate(p.parent)
        _check_mcap_file(p)
        return BagFiles(p.parent, None, (p,), None)
    if not p.is_dir():
        raise BagError(f'{p}: neither a file nor a directory')
    try:
        entries = sorted(p.iterdir())
    except OSError as exc:
        raise BagError(f'{p}: cannot list the directory ({exc.strerror})') from None
    if not entries:
        raise BagError(f'{p}: empty directory, not a bag (no metadata.yaml, no .mcap file)')
    meta = p / 'metadata.yaml'
    if meta.exists() and not meta.is_file():
        raise BagError(f'{meta}: not a file; a bag folder holds metadata.yaml as a file '
                       '(move the directory away)')
    info = _read_metadata_yaml(meta) if meta.is_file() else None
    if info is not None:
        files = _listed_files(p, meta, info, entries)
    else:
        files = tuple(e for e in entries if e.suffix == '.mcap' and e.is_file())
        if not files:
            raise BagError(f'{p}: not a bag (no metadata.yaml and no .mcap file in it)')
    outside = [str(f) for f in files if not _inside(p, f)]
    if outside:
        raise BagError(f'{p}: {outside} lead outside the bag folder (symbolic links); every '
                       'file of a bag must be inside it')
    for f in files:
        _check_mcap_file(f)
    return BagFiles(p, meta if info is not None else None, files, info)


def scan(path: str | Path,
         on_message: Callable[[int, int, bytes], None] | None = None,
         keep: Callable[[ChannelInfo], bool] | None = None) -> Scan:
    """Read every record of the bag that can be read, file by file and record by record
    (memory: one chunk at a time, and the messages kept).

    A truncated or corrupt MCAP file does not raise: reading stops at the first incomplete or
    corrupt record, ``complete`` is False and ``problem`` says where. With ``on_message``,
    each message ``(channel id, log time ns, data)`` is handed to it as it is read instead
    of kept in ``messages``: a bag of any length in bounded memory (``fohssv repair``). With
    ``keep``, only the messages of the channels it accepts are kept (the others counted).

    Raises:
        BagError: see :func:`locate`; also an MCAP file with no readable record at all.
    """
    result, messages = stream(path)
    if on_message is None:
        kept: dict[int, bool] = {}
        append = result.messages.append

        def on_message(cid: int, log_time: int, data: bytes) -> None:
            wanted = kept.get(cid)
            if wanted is None:
                wanted = kept[cid] = keep is None or keep(result.channels[cid])
            if wanted:
                append((cid, log_time, data))

    for cid, log_time, data in messages:
        on_message(cid, log_time, data)
    return result


def stream(path: str | Path) -> tuple[Scan, Iterator[tuple[int, int, bytes]]]:
    """The bag as :func:`scan` reads it, for a reader that pulls its messages: a :class:`Scan`
    (no messages kept) and an iterator of the messages ``(channel id, log time ns, data)`` in
    file order, read from the files as it is advanced; the scan fills as it goes (a channel
    before its messages; ``complete`` and ``problem`` once the iterator is exhausted, which
    raises BagError then when no channel could be read at all).

    Raises:
        BagError: see :func:`locate`.
    """
    result = Scan(files=locate(path))
    return result, _walk_files(result)


def _walk_files(result: Scan) -> Iterator[tuple[int, int, bytes]]:
    for mcap_path in result.files.mcap_files:
        with mcap_path.open('rb') as f:
            yield from _walk(mcap_path, f, result)
    if not result.channels and not result.complete:
        raise BagError(f'{result.problem}; no channel could be read, nothing to recover')


class _Corrupt(Exception):
    pass


def _add_channel(record: Channel, schemas: dict[int, Schema], result: Scan) -> int:
    """The id in ``result`` of a file's channel (one id per topic and type across files)."""
    schema = schemas.get(record.schema_id)
    msgtype = schema.name if schema else ''
    cid = next((c.id for c in result.channels.values()
                if (c.topic, c.msgtype) == (record.topic, msgtype)),
               len(result.channels) + 1)
    if cid not in result.channels:
        result.channels[cid] = ChannelInfo(
            cid, record.topic, msgtype,
            record.message_encoding, schema.encoding if schema else '',
            schema.data.decode('utf8', 'replace') if schema else '',
            dict(record.metadata))
    return cid


def _walk(mcap_path: Path, stream: BinaryIO, result: Scan) -> Iterator[tuple[int, int, bytes]]:
    """The messages of one MCAP file, every other readable record added to ``result``; a
    truncated or corrupt file sets ``complete`` False and ``problem``."""
    schemas: dict[int, Schema] = {}
    size = os.fstat(stream.fileno()).st_size
    result.bytes_total += size
    reader = StreamReader(stream, validate_crcs=True)
    saw_footer = False
    good = 0  # offset after the last complete top-level record
    ids: dict[int, int] = {}  # channel id in this file -> id in result
    try:
        for record in reader.records:
            if isinstance(record, Header):
                result.header_library = record.library
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                ids[record.id] = _add_channel(record, schemas, result)
            elif isinstance(record, Message):
                if record.channel_id not in ids:
                    raise _Corrupt(f'message on unknown channel {record.channel_id}')
                cid, log_time = ids[record.channel_id], record.log_time
                result.message_count += 1
                counts = result.channel_counts
                counts[cid] = counts.get(cid, 0) + 1
                first = result.channel_times.get(cid)
                result.channel_times[cid] = (log_time if first is None else first[0], log_time)
                yield cid, log_time, bytes(record.data)
            elif isinstance(record, Metadata):
                result.metadata_records.append((record.name, dict(record.metadata)))
            elif isinstance(record, Footer):
                saw_footer = True
            good = stream.tell()
    except (CRCValidationError, _Corrupt) as exc:
        result.problem = f'{mcap_path}: corrupt data at byte {good} ({exc})'
    except (McapError, struct.error, EOFError, ValueError, UnicodeDecodeError) as exc:
        kind = type(exc).__name__
        result.problem = (f'{mcap_path}: truncated or corrupt after byte {good} of '
                          f'{size} ({kind}{": " + str(exc) if str(exc) else ""})')
    result.bytes_read += good if not saw_footer else size
    if not saw_footer:
        result.complete = False
        if not result.problem:
            result.problem = f'{mcap_path}: no footer after byte {good} of {size}'


def basename(topic: str) -> str:
    """The last part of a topic name (``/a/state`` -> ``state``)."""
    return topic.rstrip('/').rsplit('/', 1)[-1]
