"""A recorded run as numpy arrays: :func:`load_run` reads the contract topics of a bag in
memory bounded by the arrays themselves (:mod:`.stream`: no Python object per message), with
a time window and decimation, and refuses a request that cannot fit (:class:`TooLarge`). A
bag whose recorder was killed loads too (everything up to the last complete chunk), and
:attr:`Run.recovery` says how much. Pure: no rclpy.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Channel, Schema

from .. import contract
from .loader import BagError, BagFiles, basename, locate, run_metadata
from .stream import Columns, FileRead, fits, read_arrays, summary_counts

__all__ = ['Run', 'TooLarge', 'ContractChannels', 'load_run', 'state_count', 'problems_of']


@dataclass
class Run:
    """A recorded run as arrays. Times in s (``data[0]`` of each message, exact doubles);
    ``log_time`` holds each topic's log times in ns (the simulation time the recorder
    logged)."""

    path: Path
    t: np.ndarray                   # (N,) state times
    state: np.ndarray               # (N, 4) z, w, theta, q
    planing_force_t: np.ndarray
    planing_force: np.ndarray
    command_t: np.ndarray
    delta_f: np.ndarray
    delta_c: np.ndarray
    clock_t: np.ndarray             # /clock times (s)
    metadata: dict[str, Any]
    topics: dict[str, int]          # recorded topic name -> messages read
    log_time: dict[str, np.ndarray]  # contract topic name -> log times (ns)
    rejected: dict[str, int]        # contract topic name -> messages not fitting the contract
    truncated: bool
    recovery: str                   # '' for a complete bag, else what was recovered

    @property
    def parameters(self) -> dict[str, Any]:
        """The plant's parameters recorded with the run ({} if unknown)."""
        value = self.metadata.get('fohssv.plant_parameters')
        return value if isinstance(value, dict) else {}



class TooLarge(BagError):
    """The request's arrays would not fit in the memory available (the message names the size
    and how to ask for less)."""


def _check_request(start: float | None, end: float | None, every: int) -> None:
    for name, v in (('start', start), ('end', end)):
        if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)):
            raise ValueError(f'{name}={v!r} must be a finite time in s (simulation time)')
    if start is not None and end is not None and end < start:
        raise ValueError(f'end={end!r} s lies before start={start!r} s: give end >= start')
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f'every={every!r} must be a whole number >= 1 (every k-th message)')


def _ns(t: float | None) -> int | None:
    return None if t is None else int(math.floor(t * 1e9 + 0.5))


class ContractChannels:
    """Which channel is which contract topic, decided channel by channel as the channels are
    read: an absolute name (``/clock``) as it is; else the name in ``namespace`` when given,
    else the topic of that base name wherever it is (several such topics: :meth:`check`
    refuses the bag and lists the namespaces)."""

    TOPICS = (contract.STATE, contract.PLANING_FORCE, contract.COMMAND, contract.CLOCK)

    def __init__(self, directory: Path, namespace: str | None) -> None:
        self.directory, self.namespace = directory, namespace
        self.matched: dict[int, set[str]] = {i: set() for i in range(len(self.TOPICS))}

    def wants(self, name: str, topic: str) -> bool:
        if name.startswith('/'):
            return topic == name
        if self.namespace is not None:
            return topic == self.namespace.rstrip('/') + '/' + name
        return basename(topic) == name

    def pick(self, record: Channel, schema: Schema | None) -> int | None:
        for i, topic in enumerate(self.TOPICS):
            if self.wants(topic.name, record.topic):
                msgtype = schema.name if schema else ''
                if msgtype != topic.type:
                    raise BagError(f'{self.directory}: topic {record.topic} has type '
                                   f'{msgtype}, the contract says {topic.type}')
                self.matched[i].add(record.topic)
                return i
        return None

    def check(self) -> None:
        for i, topic in enumerate(self.TOPICS[:3]):
            topics = sorted(self.matched[i])
            if len(topics) > 1:
                spaces = sorted({t.rsplit('/', 1)[0] or '/' for t in topics})
                raise BagError(f'{self.directory}: several {topic.name!r} topics {topics}; give '
                               f"the namespace: one of {', '.join(spaces)} (fohssv plot "
                               f"--namespace NS, load_run(path, namespace='NS'))")


def _clock(raw: bytes, at: int, size: int) -> tuple[float] | None:
    """``rosgraph_msgs/Clock`` (CDR LE: sec int32, nanosec uint32) as (t,) in s."""
    if size != 12 or not raw.startswith(b'\x00\x01', at):
        return None
    sec, nanosec = struct.unpack_from('<iI', raw, at + 4)
    return (sec + nanosec * 1e-9,)


def _refuse_too_large(files: BagFiles, topics: ContractChannels, columns: list[Columns],
                      start: int | None, end: int | None, every: int) -> None:
    """Refuse a load whose arrays cannot fit (:class:`TooLarge`), from the summaries' counts
    (the part of the time span the window covers)."""
    rows = [0] * len(columns)
    for mcap_path in files.mcap_files:
        found = summary_counts(mcap_path)
        if found is None:
            return           # no summary (a killed recorder's bag): the arrays grow instead
        counts, first, last, _ = found
        span = max(last - first, 1)
        lo = first if start is None else max(start, first)
        hi = last if end is None else min(end, last)
        share = 0.0 if hi < lo else min(1.0, (hi - lo + 1) / span)
        for i, topic in enumerate(topics.TOPICS):
            n = sum(c for name, c in counts.items() if topics.wants(topic.name, name))
            rows[i] += math.ceil(n * share / every)
    total = sum(r * (c.width + 1) * 8 for r, c in zip(rows, columns))
    try:
        fits(f'{files.directory}', sum(rows), max(1, total // max(1, sum(rows))),
             'load a time window or every k-th message (load_run(path, start=, end=, every=); '
             'fohssv plot --start/--end/--every)')
    except MemoryError as exc:
        raise TooLarge(str(exc)) from None


def problems_of(reads: list[FileRead]) -> list[str]:
    """What stopped the reading of each file that is not complete.

    Raises:
        BagError: no channel could be read from any file (nothing to recover).
    """
    problems = [r.problem for r in reads if not r.complete]
    if problems and not any(r.channels for r in reads):
        raise BagError(f'{problems[0]}; no channel could be read, nothing to recover')
    return problems


def state_count(path: str | Path, namespace: str | None = None) -> int:
    """The state messages of the bag from its summary section (no message read); 0 when a
    file has no summary (a killed recorder's bag)."""
    files = locate(path)
    topics = ContractChannels(files.directory, namespace)
    n = 0
    for mcap_path in files.mcap_files:
        found = summary_counts(mcap_path)
        if found is None:
            return 0
        n += sum(c for name, c in found[0].items() if topics.wants(contract.STATE.name, name))
    return n


def load_run(path: str | Path, *, namespace: str | None = None, start: float | None = None,
             end: float | None = None, every: int = 1) -> Run:
    """Load a recorded run: the contract topics as arrays, plus the run metadata, in memory
    bounded by the arrays themselves (:mod:`.stream`: no Python object per message).

    Args:
        path: bag directory, its metadata.yaml, or an .mcap file.
        namespace: the vehicle's namespace when the bag holds several (default: the only
            ``state`` topic, wherever it is).
        start, end: load only messages whose time (log time: the message's t) lies in
            [start, end] s; None = from the first, to the last. Chunks outside the window are
            not decompressed; ``topics`` then counts the messages of the chunks read.
        every: keep every ``every``-th message of each topic (of those in the window).

    Raises:
        BagError: missing, empty, not a bag, unreadable, or truncated before any channel;
            :class:`TooLarge` when the arrays asked for cannot fit in the memory available.
        ValueError: a window or ``every`` that is no such thing.
    """
    _check_request(start, end, every)
    files = locate(path)
    topics = ContractChannels(files.directory, namespace)
    columns = [Columns(len(t.fields)) for t in topics.TOPICS[:3]] + [Columns(1)]
    start_ns, end_ns = _ns(start), _ns(end)
    _refuse_too_large(files, topics, columns, start_ns, end_ns, every)
    reads = []
    counts: dict[str, int] = {}
    for mcap_path in files.mcap_files:
        try:
            got = read_arrays(mcap_path, topics.pick, columns, (None, None, None, _clock),
                              start_ns=start_ns, end_ns=end_ns, every=every)
        except MemoryError:
            raise TooLarge(f'{files.directory}: the arrays outgrew the memory available after '
                           f'{sum(c.n for c in columns)} rows; load a time window or every '
                           'k-th message (load_run(path, start=, end=, every=); fohssv plot '
                           '--start/--end/--every)') from None
        reads.append(got)
        for cid, (topic, _, _) in got.channels.items():
            counts[topic] = counts.get(topic, 0) + got.counts.get(cid, 0)
    topics.check()
    problems = problems_of(reads)
    (st, st_t), (fp, fp_t), (cmd, cmd_t), (clock, _) = (c.finish() for c in columns)
    recovery = ''
    if problems:
        n = sum(counts.values())
        recovery = (f'recovered {n} messages ({st.shape[0]} states, last t = '
                    f'{st[-1, 0] if st.shape[0] else float("nan"):.9g} s) from the first '
                    f'{sum(r.bytes_read for r in reads)} of {sum(r.bytes_total for r in reads)} '
                    f'bytes; {problems[0]}')
    records = [m for r in reads for m in r.metadata]
    return Run(path=Path(path), t=st[:, 0].copy(), state=st[:, 1:].copy(),
               planing_force_t=fp[:, 0].copy(), planing_force=fp[:, 1].copy(),
               command_t=cmd[:, 0].copy(), delta_f=cmd[:, 1].copy(), delta_c=cmd[:, 2].copy(),
               clock_t=clock[:, 0].copy(), metadata=run_metadata(files.info, records),
               topics=counts,
               log_time={t.name: v for t, v in zip(topics.TOPICS[:3], (st_t, fp_t, cmd_t))},
               rejected={t.name: c.rejected for t, c in zip(topics.TOPICS[:3], columns)},
               truncated=bool(problems), recovery=recovery)
