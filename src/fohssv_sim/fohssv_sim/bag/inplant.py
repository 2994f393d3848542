"""In-plant recording: the plant's own run written to a bag by a writer process, fed through
a ring buffer in shared memory (no DDS between the loop and the bag).

The plant (``record:=PATH``, :mod:`fohssv_sim.ros.inplant_record`) copies the CDR bytes of
every message it publishes (``state``, ``planing_force``, ``/clock``, the typed views) and of
every ``command`` it takes while running into a :class:`Ring`: one record is a short header
and the bytes, written with one slice assignment (about a microsecond), then the ring's head
moves. The writer process (``python -m fohssv_sim.bag.inplant FD``, started by the plant, this
module's :func:`main`) takes the records in order and writes them with
:class:`~.writer.RunWriter`, the recorder node's bag writer: the same rosbag2 version 9 / MCAP
layout, channels, QoS profiles (``offered_qos_profiles``), log times (:class:`LogTimes`, the
recorder's rule), run metadata and ``run_end`` check. Nothing is serialized twice: the bytes in
the bag are the bytes that went out on DDS, as a reader receives them (padded to 4 bytes).

The ring (:class:`~.ring.Ring`, its one definition) is a shared file mapping (``memfd``; an
unlinked temporary file elsewhere) handed to the writer as an inherited file descriptor, so
nothing outlives the two processes.

Control goes over the writer's stdin, one length-prefixed pickle per message (the two ends are
this module, one program): ``('open', config)``, ``('metadata', values)``, ``('wake',)`` (the
plant found the ring full: write now) and ``('end', run_end_json)``. The writer answers on
its stdout with one JSON line when the bag is open, one when it is ready to write (its
compiled path loaded: :mod:`.ringpack`; the plant waits for it before its first sample) and
one when the bag is closed (:func:`read_reply`; with the writer's CPU time from open to
close). End of file on stdin
without ``end`` means the plant died (SIGKILL included): the writer takes what the ring holds,
marks the bag ``fohssv.record_interrupted`` and closes it completely. A writer killed itself
leaves a bag cut at its last flush (every ``flush_period``, default 0.1 s), which ``fohssv
repair`` completes.

When the ring is full the plant does not drop silently: in lockstep it waits for room (the
writer paces the loop; counted as ``record_waits``), in real time it counts the record as lost
(``record_lost``, logged at once, in the summary, and in the bag's ``run_end`` check: the
writer names each topic's shortfall and the plant exits 8).

A writer that cannot write (a full disk, an I/O error) answers one line, the error in words
("No space left on device"), and exits 1 without a traceback; the plant goes on unrecorded and
exits 8. Whatever ends a writer, its ring's header keeps the records it released and its last
flush mark (the file's size and the messages up to there): the plant counts what the bag
lacks exactly (:func:`unrecorded`: released records plus those left in the ring, less the
bag's messages: the mark's count plus the complete chunks the file holds after it, as a
reader of the cut file finds them). A bag
directory none of whose files holds a byte (a disk full from the start) is removed: nothing
blocks the path. At open the writer flushes the bag's first bytes, so a disk full from the
start refuses ``record`` at once (exit 2).

Pure module: no rclpy.
"""

from __future__ import annotations

import gc
import json
import os
import pickle
import select
import shutil
import signal
import struct
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, BinaryIO

from mcap.exceptions import McapError
from mcap.records import Message
from mcap.stream_reader import CRCValidationError, StreamReader

from .. import contract
from .ring import DEFAULT_RING_BYTES, MIN_RING_BYTES, Ring
from .writer import LogTimes, RunWriter, source_info

__all__ = ['Ring', 'TopicSpec', 'WriterConfig', 'send', 'read_reply',
           'main', 'DEFAULT_RING_BYTES', 'MIN_RING_BYTES', 'CHUNK_SIZE', 'EXIT_LOST',
           'EXIT_INTERRUPTED', 'EMPTY_KEY', 'unrecorded']

#: The writer's chunk size (bytes): 1 MiB, not the recorder node's 64 KiB. Each flush (every
#: ``flush_period``) ends the chunk in progress anyway, so a chunk here is what a lockstep or
#: 10 kHz run puts in the ring in 0.1 s (0.4-0.5 MB); with 64 KiB it was cut six to eight times
#: in between, and each cut (the chunk's message indexes, its CRC, the mcap library's Python)
#: is work beside the plant's loop. The demo's loop against the 64 KiB tree (``python
#: bench/ab_lockstep.py OLD --demo --rounds 10``, bare echoes 8673-14409 round trips/s):
#: recorded / unrecorded 1.34 -> 1.12 (medians of the rounds); the writer's CPU over it, in
#: the plant's ``closed`` line, 0.080 -> 0.060 s.
CHUNK_SIZE = 1 << 20
#: Writer exit codes: the bag misses messages its run_end lists; the plant ended without
#: run_end (it died). 0: complete.
EXIT_LOST = 6
EXIT_INTERRUPTED = 7
#: Run-metadata key of a bag closed without any message (as the recorder node marks it).
EMPTY_KEY = 'fohssv.empty'
#: Longest wall time (s) between two looks at the ring (and at the control pipe): the writer
#: wakes this often (sooner for a small or fast-filling ring, a flush, a control message or a
#: plant that finds the ring full: :func:`_serve`), each time writing everything the ring holds
#: in one batch, so it takes the CPU in few, long turns (a batch's fixed cost is spread over
#: a thousand messages in a lockstep demo) instead of interrupting the loop at every sample.
_IDLE = 0.05
_LEN = struct.Struct('<I')
_PAD = (b'', b'\x00', b'\x00\x00', b'\x00\x00\x00')


@dataclass(frozen=True)
class TopicSpec:
    """One recorded topic: its resolved name, ROS type, offered QoS profiles (rosbags
    ``Qos``) and how its log time is read (``array``, ``clock`` or ``stamped``)."""

    name: str
    type: str
    qos: tuple
    kind: str


@dataclass(frozen=True)
class WriterConfig:
    """What the writer needs: the bag to create, its topics (the ring's record index is the
    position in ``topics``), the first run metadata, flush period and chunk size."""

    path: str
    topics: tuple[TopicSpec, ...]
    metadata: Mapping[str, Any]
    flush_period: float = 0.1
    chunk_size: int = CHUNK_SIZE
    #: Write through the compiled path (:mod:`.ringpack`; the same bytes) where numba is
    #: available; False: the interpreted one only.
    compiled: bool = True


def kind_of(msgtype: str) -> str:
    """How the log time of a message of ``msgtype`` is read (:class:`LogTimes`)."""
    if msgtype == contract.FLOAT64_ARRAY:
        return 'array'
    if msgtype == contract.CLOCK.type:
        return 'clock'
    return 'stamped'


def send(stream: BinaryIO, message: tuple) -> None:
    """One control message to the writer (length-prefixed pickle)."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_LEN.pack(len(data)) + data)
    stream.flush()


def read_reply(stream: BinaryIO) -> dict | None:
    """The writer's next JSON reply line (None at end of file)."""
    line = stream.readline()
    return json.loads(line) if line.strip() else None


class _Control:
    """The writer's end of the control pipe: messages as they are complete, EOF as None."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self._buf = b''
        self.eof = False

    def poll(self, timeout: float) -> list[tuple]:
        """Messages that arrived within ``timeout`` s (sets :attr:`eof` at end of file)."""
        if self.eof:
            return []
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if ready:
            chunk = os.read(self.fd, 1 << 16)
            if not chunk:
                self.eof = True
            self._buf += chunk
        out = []
        while len(self._buf) >= 4:
            (n,) = _LEN.unpack_from(self._buf)
            if len(self._buf) < 4 + n:
                break
            out.append(pickle.loads(self._buf[4:4 + n]))   # noqa: S301 - our own parent
            self._buf = self._buf[4 + n:]
        return out

    def wait(self, timeout: float) -> tuple | None:
        deadline = time.monotonic() + timeout
        while not self.eof and time.monotonic() < deadline:
            got = self.poll(min(0.1, max(0.0, deadline - time.monotonic())))
            if got:
                return got[0]
        return None


class _Session:
    """The writer at work: the bag, the log times, the counts."""

    def __init__(self, config: WriterConfig, ring: Ring) -> None:
        self.ring = ring
        self.topics = config.topics
        self.writer = RunWriter(config.path, chunk_size=config.chunk_size).open()
        for t in self.topics:
            self.writer.add_topic(t.name, t.type, qos=list(t.qos))
        self.writer.add_metadata({
            **source_info(),
            'fohssv.recorder': 'in-plant (the plant node\'s writer process)',
            'fohssv.recorder_started_utc': datetime.now(timezone.utc).isoformat(),
            'fohssv.topics': [t.name for t in self.topics],
            'fohssv.log_time': 'simulation time in ns: round(data[0] * 1e9) for '
                               'Float64MultiArray topics, the stamp for /clock',
            'fohssv.flush_period_s': repr(config.flush_period),
            'fohssv.chunk_size_bytes': str(config.chunk_size),
            **config.metadata,
        })
        times = self._times = LogTimes()
        self._log = []
        for t in self.topics:
            if t.kind == 'array':
                self._log.append(times.array)
            elif t.kind == 'clock':
                self._log.append(times.clock)
            else:
                self._log.append(lambda raw, _type=t.type: times.stamped(raw, _type))
        # the bag's first bytes to the disk now: a full disk refuses the bag at its start
        self.flush()
        ids = self.writer.channel_ids()
        self._channel = [ids[t.name] for t in self.topics]
        self.expected: dict[str, int] | None = None
        self.packer: Any = None
        self._compiled = config.compiled
        self.load_cpu = 0.0        # CPU seconds loading the compiled path (use_compiled)
        self.compile_error = ''    # why the compiled path could not be loaded
        # what is alive now lives to the end: the collector's full passes need not walk it (the
        # writer makes no cycles; its batches are freed by reference counts)
        gc.collect()
        gc.freeze()
        self._cpu0 = time.process_time()      # the bag is open: the writer's work begins

    def use_compiled(self) -> bool:
        """Write through the compiled path from now on (:class:`.ringpack.Packer`), where the
        configuration asks for it and numba is available (loaded from its cache, or compiled
        the first time: the ring holds what comes meanwhile); whether it is in use. Where it
        cannot be loaded the writer stays interpreted and :attr:`compile_error` says why."""
        if self._compiled and self.packer is None and not self.compile_error:
            begin = time.process_time()
            try:
                from .ringpack import Packer, warm_up
                packer = Packer(self.ring, [t.kind for t in self.topics], self._channel,
                                self._times, self.writer, self._write)
                warm_up()
            except Exception as exc:  # noqa: BLE001 - a slower writer, not a failure
                self.compile_error = f'{type(exc).__name__}: {exc}'
                return False
            self.packer = packer
            gc.collect()           # numba's objects live to the end too (see __init__)
            gc.freeze()
            self.load_cpu = time.process_time() - begin
            self._cpu0 += self.load_cpu         # the writer's work is the messages'
        return self.packer is not None

    def drain(self, limit: int = 1 << 22) -> int:
        """Write what the ring holds (at most ``limit`` bytes of records) in one batch;
        records written."""
        if self.packer is not None:
            n = self.packer.drain(limit)
        else:
            records = self.ring.take(limit)
            if not records:
                return 0
            self._write(records)
            self.ring.release()
            n = len(records)
        return n

    def flush(self) -> None:
        """Hand the bag to the OS and mark in the ring's header how far it got (the plant
        counts a dead writer's shortfall from there)."""
        self.ring.mark_flushed(*self.writer.flush())

    def _write(self, records: list[tuple[int, memoryview]]) -> None:
        """The interpreted path: ``(index, bytes)`` records into the bag."""
        channel = self._channel
        log = self._log
        # as a DDS reader receives it (and the recorder node writes it): RTPS pads a
        # serialized payload with zeros to a multiple of 4 bytes
        self.writer.write_many([
            (channel[i], log[i](raw), bytes(raw) + _PAD[-len(raw) % 4] if len(raw) & 3 else raw)
            for i, raw in records])

    def end(self, run_end: str | None) -> dict:
        """Close the bag after ``run_end`` (the plant's JSON; None: the plant died)."""
        w = self.writer
        if run_end is None:
            w.add_metadata({'fohssv.record_interrupted': 'the plant ended without run_end '
                            '(killed?); the bag holds what it had put in the ring'})
        else:
            info = contract.parse_run_end(run_end)
            self.expected = {k: v for k, v in info['published'].items() if k in w.counts}
            w.add_metadata({'fohssv.run_end': info})
        lost = self.ring.lost
        if lost:
            w.add_metadata({'fohssv.record_lost': lost})
        total = sum(w.counts.values())
        if total == 0:
            w.add_metadata({EMPTY_KEY: 'no message was recorded before the plant stopped'})
        w.close()
        missing = {k: [w.counts.get(k, 0), v] for k, v in (self.expected or {}).items()
                   if w.counts.get(k, 0) < v}
        return {'closed': str(w.path), 'messages': total, 'counts': dict(w.counts),
                'missing': missing, 'lost': lost, 'waits': self.ring.waits,
                'interrupted': run_end is None,
                'cpu_time': time.process_time() - self._cpu0,
                'compiled': self.packer is not None, 'load_cpu_time': self.load_cpu}


def unrecorded(ring: Ring, mcap_path: str | Path) -> int:
    """The records put into ``ring`` that the bag of its writer, now dead, lacks, exactly,
    wherever the writer stopped (a full disk in the middle of a chunk, SIGKILL): those it
    released (the ring's header) and those it left in the ring, less the messages a reader
    finds in its MCAP file ``mcap_path`` (its last flush mark, then the complete chunks after
    it). Read through a second view of the mapping (``ring`` may be the producer's)."""
    view = Ring(os.dup(ring.fd), ring.size)
    try:
        left = len(view.take())
        released = view.released
        size, messages = view.flushed
    finally:
        view.close()
    return released + left - _messages_in(mcap_path, size, messages)


def _messages_in(mcap_path: str | Path, size: int, messages: int) -> int:
    """The messages a reader of the MCAP file ``mcap_path`` (its writer stopped, maybe cut in
    the middle of a record) finds, given a flush mark: ``messages`` up to byte ``size`` (a
    record boundary), plus those of every complete chunk after it (CRCs checked; reading
    stops at the first incomplete or corrupt record, as :func:`.loader.scan` does). 0 when
    the file is gone."""
    try:
        f = open(mcap_path, 'rb')  # noqa: SIM115 - closed below
    except FileNotFoundError:
        return 0
    with f:
        f.seek(size)
        try:
            for record in StreamReader(f, skip_magic=size > 0, validate_crcs=True).records:
                if isinstance(record, Message):
                    messages += 1
        except (McapError, CRCValidationError, struct.error, EOFError, ValueError):
            pass
    return messages


def _reply(out: BinaryIO, values: Mapping[str, Any]) -> None:
    try:
        out.write((json.dumps(values) + '\n').encode())
        out.flush()
    except BrokenPipeError:      # the plant is gone (killed): nobody to tell; the bag is closed
        pass


def _serve(session: _Session, control: _Control, flush_period: float) -> str | None:
    """Write until ``end`` (its run_end JSON) or the plant's death (None).

    Between two batches the writer sleeps on the control pipe: :data:`_IDLE`, less when the
    ring, filling at the rate it did since the last look, would be a quarter full sooner (a
    small ring, a fast plant), or when the next flush is due sooner. A plant that finds the ring
    full wakes it (``wake``), as does any control message."""
    ring = session.ring
    quarter = ring.capacity / 4
    last_flush = last_look = time.monotonic()
    while True:
        now = time.monotonic()
        backlog = ring.used
        session.drain()
        rate = backlog / max(now - last_look, 1e-6)             # bytes per second
        last_look = now
        if now - last_flush >= flush_period:
            session.flush()
            last_flush = now
        sleep = min(_IDLE, quarter / rate if rate > 0 else _IDLE,
                    max(0.0, last_flush + flush_period - now))
        for message in control.poll(sleep):
            if message[0] == 'metadata':
                session.writer.add_metadata(message[1])
            elif message[0] == 'end':
                return message[1]
        if control.eof:
            return None


def _os_text(exc: Exception) -> str:
    """An error in a few words: an OSError's text ("No space left on device") without its
    number and file name (the caller names the bag)."""
    return (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc))


def _remove_if_empty(path: str) -> bool:
    """Remove the bag directory ``path`` the writer made when none of its files holds a byte
    (a disk full from the start): nothing is left to block the path. The plant checked that
    ``path`` did not exist before. Whether it was removed."""
    bag = Path(path)
    try:
        if bag.is_dir() and all(f.is_file() and f.stat().st_size == 0 for f in bag.iterdir()):
            shutil.rmtree(bag)
            return True
    except OSError:
        pass
    return False


def _yield_to_the_loop() -> None:
    """Run the writer as a batch job (SCHED_BATCH, nice 10 where permitted): a woken plant or
    controller process then never waits for the writer's turn on a core; the writer takes the
    CPU they leave (in lockstep the plant waits for it when the ring is full, in real time a
    starved writer's loss is reported)."""
    try:
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except (AttributeError, OSError):
        pass
    try:
        os.nice(10)
    except OSError:
        pass


def main(argv: Sequence[str] | None = None) -> int:
    """The writer process: ``python -m fohssv_sim.bag.inplant RING_FD RING_BYTES``."""
    argv = sys.argv[1:] if argv is None else list(argv)
    # a terminal's Ctrl-C reaches the whole process group: the plant ends the recording
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _yield_to_the_loop()
    out = sys.stdout.buffer
    ring = Ring(int(argv[0]), int(argv[1]))
    control = _Control(sys.stdin.fileno())
    opened = control.wait(60.0)
    if opened is None or opened[0] != 'open':
        _reply(out, {'error': 'no configuration from the plant'})
        return 1
    config: WriterConfig = opened[1]
    try:
        session = _Session(config, ring)
    except Exception as exc:  # noqa: BLE001 - reported to the plant in one line
        _remove_if_empty(config.path)
        _reply(out, {'error': f'{config.path}: {_os_text(exc)}'})
        return 1
    _reply(out, {'opened': config.path, 'pid': os.getpid()})
    compiled = session.use_compiled()   # before the run: the plant waits for 'ready'
    _reply(out, {'ready': True, 'compiled': compiled, 'load_cpu_time': session.load_cpu,
                 'error': session.compile_error})
    try:
        run_end = _serve(session, control, config.flush_period)
        while session.drain():
            pass
        result = session.end(run_end)
    except OSError as exc:   # a full disk, an I/O error: one line for the plant, no traceback
        _reply(out, {'error': f'{config.path}: {_os_text(exc)}',
                     'removed': _remove_if_empty(config.path)})
        return 1
    _reply(out, result)
    if result['missing'] or result['lost']:
        return EXIT_LOST
    return EXIT_INTERRUPTED if run_end is None else 0


if __name__ == '__main__':
    _code = main()
    # the bag is closed and the reply sent: no interpreter teardown (tens of ms freeing the
    # typestore and the modules), which the plant would wait for at the end of its run
    for _stream in (sys.stdout, sys.stderr):
        try:
            _stream.flush()
        except BrokenPipeError:
            pass
    os._exit(_code)
