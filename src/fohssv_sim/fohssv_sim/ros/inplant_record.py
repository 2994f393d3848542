"""The plant's side of in-plant recording (``record:=PATH``): start the writer process, copy
every published message and every taken command into the ring, end the bag with the run.

The writer and the ring are :mod:`fohssv_sim.bag.inplant` (pure); this module only knows the
plant's message writers and publishers. :func:`start` is the plant's one hook at construction:
it checks ``record`` (:func:`check_record`), starts the writer, and wraps the plant's publish
calls of its serialized ``state``, ``planing_force``, ``/clock`` (and hosted ``command``)
messages and the ``publish`` of its view publishers, so that each message is also put into
the ring once published: the bytes DDS took (a view message object is serialized by the tap
and published as those bytes; a sample DDS refused is not recorded, as ``run_end`` does not
count it). A hosted plant's ``/clock`` and ``command`` are put into the ring even while it
does not publish them, nobody subscribing (:meth:`InPlantRecording.tap_send`).
:meth:`InPlantRecording.command` takes the raw bytes of each
command the plant takes while running, :meth:`InPlantRecording.end` the run_end JSON, and
:meth:`InPlantRecording.finish` waits for the writer to close the bag.

Cost on the per-sample path: one record copy per message (about 1 us here); measured with
``bench/bench_ros.py`` (in-plant recorded vs unrecorded).
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from rclpy.serialization import serialize_message

from .. import contract
from ..bag.inplant import Ring, TopicSpec, WriterConfig, kind_of, read_reply, send, unrecorded
from . import controller_name
from .controller_name import command_topic
from .loop import time_text
from .options import NODE_PARAMETER_BY_NAME, PlantOptions
from .qos import offered_qos

__all__ = ['InPlantRecording', 'start', 'check_record', 'EXIT_RECORD_LOST']

#: Plant exit code when its in-plant bag misses messages (a realtime writer that fell
#: behind, or a writer that died); the run itself ended well otherwise. A writer's death
#: does not stop the run: it goes on at full speed, each message it can no longer record
#: costs a failed put and a count (``record_lost`` in the summary).
EXIT_RECORD_LOST = 8
#: Wall seconds to wait for the writer to open the bag.
_OPEN_TIMEOUT = 60.0
#: Wall seconds the writer may go without progress while it closes the bag.
_CLOSE_STALL = 30.0
#: Wall seconds a run that ended waits for the controller node's name (the bag's
#: ``fohssv.controller``) before its bag is closed without it.
_NAME_WAIT = 5.0
#: Wall seconds between two "the writer fell behind" lines (and checks of the writer's life).
_SAY_EVERY = 1.0
#: Wall seconds the run's start waits for the writer to be ready (its compiled path loaded:
#: 0.4-0.5 s from numba's cache, a few seconds the first time).
_READY_TIMEOUT = 30.0


def check_record(options: PlantOptions) -> Path | None:
    """The bag directory ``record`` names, or None when it is off.

    Raises:
        ParameterError: it exists already (a bag is never overwritten), or its parent
            cannot be created or written.
    """
    if not options.record:
        return None
    spec = NODE_PARAMETER_BY_NAME['record']
    path = Path(options.record)
    if path.exists() or path.is_symlink():
        raise spec.refuse(options.record, 'exists already: the plant never overwrites a bag')
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise spec.refuse(options.record, f'cannot be created: {parent} is not a directory')
    if not os.access(parent, os.W_OK | os.X_OK):
        raise spec.refuse(options.record, f'cannot be created: {parent} is not writable')
    return path


class InPlantRecording:
    """The writer process of one plant and the ring that feeds it (module docstring)."""

    def __init__(self, node: Any, path: Path, topics: list[tuple[str, contract.Topic]]
                 ) -> None:
        self.node = node
        self.path = path
        self.lockstep = node.options.mode == 'lockstep'
        self.ring = Ring.create(node.options.record_buffer)
        #: the per-message put: the ring's, or once the writer is dead :meth:`_lose`
        self.put = self.ring.put
        self.waits = 0
        self.wait_seconds = 0.0
        self.lost = 0
        self._woken_at = -1
        #: records put into the ring that a dead writer's bag lacks (:meth:`_unrecorded`)
        self._unrecorded_n: int | None = None
        self._say_at = 0.0        # monotonic time of the next "fell behind" line (_fell_behind)
        self.failed = ''
        self.result: dict | None = None
        self._ended = False
        self._naming = False      # the controller node's name is being asked (name_controller)
        self._end_text: str | None = None   # run_end held until that answer (settle)
        specs = []
        self._index: dict[str, int] = {}
        for name, topic in topics:
            if name not in self._index:
                self._index[name] = len(specs)
                specs.append(TopicSpec(name, topic.type, (offered_qos(topic),),
                                       kind_of(topic.type)))
        self.command_index = -1
        self.config = WriterConfig(str(path), tuple(specs), {
            'fohssv.plant_node': node.get_fully_qualified_name().lstrip('/'),
            'fohssv.record_buffer_bytes': str(self.ring.capacity)})
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'fohssv_sim.bag.inplant', str(self.ring.fd),
             str(self.ring.size)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            pass_fds=(self.ring.fd,), start_new_session=True)
        # the replies read unbuffered, a line at a time: a buffered readline could take two
        # lines ('opened' and 'ready') at once, and select would not see the second
        self._replies = open(self.proc.stdout.fileno(), 'rb', buffering=0,  # noqa: SIM115
                             closefd=False)
        send(self.proc.stdin, ('open', self.config))
        reply = self._reply(_OPEN_TIMEOUT)
        if reply is None or 'opened' not in reply:
            self.proc.kill()
            self.proc.wait()
            self.ring.close()
            why = (reply or {}).get('error', 'the writer process did not start')
            raise NODE_PARAMETER_BY_NAME['record'].refuse(str(path), f'cannot be recorded: {why}')
        self.pid = reply['pid']

    def ready(self, timeout: float = _READY_TIMEOUT) -> None:
        """Wait until the writer is ready to write (its compiled path loaded), so that its
        heaviest half-second is not spent beside the run's first samples: the plant calls this
        once, before it spins (and so before it waits for its peers), and says so in one line.
        A writer still loading after ``timeout`` is said in one line and the plant goes on
        (:meth:`_wait_closed` passes over a late 'ready')."""
        begin = time.monotonic()
        reply = self._reply(timeout)
        log = self.node.get_logger()
        if reply is not None and 'ready' in reply:
            waited = f'waited {time.monotonic() - begin:.2f} s'
            if reply.get('error'):
                log.warning(f'in-plant recording: writer ready (interpreted path: its compiled '
                            f'path could not be loaded: {reply["error"]}; {waited})')
            else:
                how = 'compiled' if reply.get('compiled') else 'interpreted'
                log.info(f'in-plant recording: writer ready ({how} path, {waited})')
            return
        try:           # its pipe closes just before it can be reaped: a moment for that
            self.proc.wait(timeout=0.5)
        except subprocess.TimeoutExpired:
            pass
        if self.proc.poll() is not None:
            self._writer_failed()
            return
        log.warning(
            f'in-plant recording: the writer is not ready after {timeout:g} s (still loading '
            'its compiled path); starting the run (the ring holds what comes meanwhile)')

    def _reply(self, timeout: float) -> dict | None:
        """The writer's next reply line (None when it exited or stayed silent)."""
        ready, _, _ = select.select([self._replies], [], [], timeout)
        if not ready:
            return None
        try:
            return read_reply(self._replies)
        except (ValueError, OSError):
            return None

    # -- the per-sample path ----------------------------------------------------------------
    def index(self, topic_name: str) -> int:
        """The ring's record index of a recorded topic."""
        return self._index[topic_name]

    def tap(self, pub: Any) -> None:
        """Put every message ``pub`` publishes into the ring too (``pub.publish`` wrapped). A
        message object is serialized here and its bytes published: what DDS sends is then
        what the bag holds (the serializer leaves alignment padding undefined)."""
        index = self._index[pub.topic_name]
        publish = pub.publish
        rec = self
        full = self._full

        def publish_recorded(msg: Any) -> None:
            data = msg if isinstance(msg, (bytes, bytearray)) else serialize_message(msg)
            publish(data)
            if not rec.put(index, data):
                full(index, data)

        pub.publish = publish_recorded

    def tap_send(self, node: Any, attr: str, topic_name: str, wanted: str = '') -> None:
        """Put every message the plant's publish call ``node.<attr>`` (``_send_state`` & co.,
        serialized bytes from ``wire.ArrayWriter`` and ``ClockWriter``) publishes into the ring
        too, once it was published: a sample DDS refused (retried, or never sent before an
        exit 9) is recorded once, or not at all, as ``run_end`` counts it. With ``wanted``
        (the name of the node's flag, ``_clock_wanted`` or ``_command_wanted``): published
        only while that flag says someone subscribes (a hosted plant's volatile topics nobody
        reads), and put into the ring either way."""
        index = self._index[topic_name]
        send = getattr(node, attr)
        rec = self
        full = self._full

        def send_recorded(data: bytes) -> Any:
            result = send(data)
            if not rec.put(index, data):
                full(index, data)
            return result

        def send_if_wanted(data: bytes) -> Any:
            result = send(data) if getattr(node, wanted) else None
            if not rec.put(index, data):
                full(index, data)
            return result

        setattr(node, attr, send_if_wanted if wanted else send_recorded)

    def put_sent(self, topic_name: str, data: bytes) -> None:
        """Put a message the plant published without its tapped publish call (the compiled
        lockstep sample's state) into the ring, as :meth:`tap_send`'s call does."""
        index = self._index[topic_name]
        if not self.put(index, data):
            self._full(index, data)

    def command(self, raw: bytes) -> None:
        """A command the plant took while running (the raw bytes it received)."""
        if not self.put(self.command_index, raw):
            self._full(self.command_index, raw)

    def _full(self, index: int, data: bytes) -> None:
        """The ring is full: lockstep waits for the writer (it paces the run), real time
        counts the record as lost, says so at once and then at most once a second. Once the
        writer is dead (said once, with its cause, by :meth:`_writer_failed`) :attr:`put` is
        :meth:`_lose`: a record costs its count only, no wait, no wake, no log line; the run
        goes on at full speed and ends with :data:`EXIT_RECORD_LOST` (:meth:`finish`)."""
        if not self.failed:
            if self.lockstep:
                begin = time.monotonic()
                self.waits += 1
                self.ring.add_wait()
                self._send(('wake',))            # the writer sleeps between batches: now
                while not self.ring.put(index, data):
                    if self.proc.poll() is not None:
                        self._writer_failed()
                        break
                    time.sleep(0.0002)
                self.wait_seconds += time.monotonic() - begin
                if not self.failed:
                    return
            else:
                self._fell_behind(index)
        self.lost += 1
        self.ring.add_lost()

    def _lose(self, index: int, data: bytes) -> bool:
        """:attr:`put` once the writer is dead: the record counted as lost, nothing else."""
        self.lost += 1
        return True

    def _fell_behind(self, index: int) -> None:
        """A live writer's ring is full in real time: wake it once per batch it took, check
        that it lives and say so at the first loss, then at most every
        :data:`_SAY_EVERY` wall seconds (checked here, not by a throttled logger, whose
        call-site lookup costs more than the put)."""
        tail = self.ring.consumed
        if tail != self._woken_at:           # once per batch the writer took since: wake it
            self._woken_at = tail
            self._send(('wake',))
        now = time.monotonic()
        if now < self._say_at:
            return
        self._say_at = now + _SAY_EVERY
        if self.proc.poll() is not None:
            self._writer_failed()
            return
        name = self.config.topics[index].name
        self.node.get_logger().error(
            f'in-plant recording: the writer fell behind: ring of {self.ring.capacity} bytes '
            f'full at t={time_text(self.node.sim.t)} s, a {name} message not recorded '
            f'({self.lost + 1} lost so far; record_buffer is the ring size)')

    def _writer_failed(self, cause: str = '', reply: dict | None = None) -> None:
        """The writer process died (or ``cause``): said once, with its cause: its own line
        (``reply``, or read now: "No space left on device"), else how it ended."""
        if self.failed:
            return
        while reply is None and not cause:
            reply = self._reply(0)
            if reply is None:
                break
            if not _failure(reply):
                reply = None                # a late 'ready': the next line
        held = f'{self.path} holds what it wrote (fohssv repair completes a cut bag)'
        code = self.proc.returncode
        if reply is not None:
            cause = f'failed: {reply["error"]}'
            if reply.get('removed'):
                held = f'nothing was written: {self.path} removed'
        elif not cause:
            cause = (f'was killed by {signal.Signals(-code).name}' if code is not None
                     and code < 0 and -code in signal.valid_signals()
                     else f'exited with code {code}')
        self.failed = f'the writer process {cause}'
        self.put = self._lose
        self.node.get_logger().error(
            f'in-plant recording: {self.failed} (noticed at t={time_text(self.node.sim.t)} s): '
            f'from then on the run is not recorded (counted as record_lost; exit '
            f'{EXIT_RECORD_LOST}); {held}')

    # -- start and end ----------------------------------------------------------------------
    def metadata(self, values: dict[str, Any]) -> None:
        if not self._ended:
            self._send(('metadata', values))

    def name_controller(self, hosted: str | None) -> None:
        """At the run's start: the law answering the plant, stored as the recorder node
        stores it (``fohssv.controller_node``, ``fohssv.controller``; ``fohssv plot`` names it
        in its titles). ``hosted``: the plant's own law; else the ``controller`` parameter of
        the node publishing ``command``, asked without blocking the run (written when the
        reply comes, if before the run's end)."""
        node = self.node
        if hosted is not None:
            self.metadata({'fohssv.controller_node': node.get_fully_qualified_name(),
                           'fohssv.controller': hosted})
            return
        topic = command_topic(node)
        if node.get_publishers_info_by_topic(topic):
            self._naming = True
            controller_name.ask(node, topic, self._named, timeout=10.0)

    def _named(self, values: dict[str, Any]) -> None:
        """The controller's name came (or its lookup gave up): into the metadata, and the
        run_end held for it goes to the writer."""
        self.metadata(values)
        self._release_end()

    def end(self, run_end: str) -> None:
        """The run's run_end JSON: the writer takes what the ring holds, checks it, closes.
        While the controller node's name is still being asked (a short lockstep run, or a
        loaded machine, ends before the answer), the run_end is held for :meth:`settle`."""
        if self._naming:
            self._end_text = run_end
            return
        if not self._ended:
            self._ended = True
            self._send(('end', run_end))

    def settle(self, executor: Any, timeout: float = _NAME_WAIT) -> None:
        """After the run: spin ``executor`` until the controller's name came, at most
        ``timeout`` s (the plant's services and the reply need the executor), then hand the
        writer the run_end held (without the name if it did not come)."""
        deadline = time.monotonic() + timeout
        while self._naming and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        self._release_end()

    def _release_end(self) -> None:
        """No longer waiting for the controller's name: the run_end held for it (if any)
        goes to the writer."""
        self._naming = False
        if self._end_text is not None:
            self.end(self._end_text)

    def _send(self, message: tuple) -> None:
        try:
            send(self.proc.stdin, message)
        except (BrokenPipeError, OSError, ValueError):
            if not self.failed and self.proc.poll() is not None:
                self._writer_failed()

    def _close_control(self) -> None:
        try:
            self.proc.stdin.close()
        except OSError:
            pass

    def finish(self, code: int) -> int:
        """Wait until the writer closed the bag (while it makes progress); log its counts;
        the plant's exit code: ``code``, or :data:`EXIT_RECORD_LOST` when ``code`` is 0 and
        the bag misses messages."""
        if self.result is None:
            self._release_end()          # a run_end held for the controller's name
            if not self._ended:          # no run_end (an error): the writer takes EOF as such
                self._close_control()
            self.result = self._wait_closed()
            self._unrecorded_n = self._unrecorded() if self.failed else 0
            self._close_control()
            self.ring.close()
        r = self.result or {}
        log = self.node.get_logger()
        if 'closed' not in r:
            if not self.failed:        # a dead writer was said when it was found dead
                log.error(f'in-plant recording: the writer did not close the bag; {self.path} '
                          'holds what it wrote (fohssv repair completes a cut bag)')
            return code or EXIT_RECORD_LOST
        counts = ', '.join(f'{k}: {v}' for k, v in r['counts'].items())
        if r['missing'] or r['lost']:
            detail = ', '.join(f'{k} {a} of {b}' for k, (a, b) in r['missing'].items())
            log.error(f'in-plant recording: {r["lost"]} message(s) lost (the writer fell '
                      f'behind): the bag holds {detail} published (run_end); {r["closed"]} is '
                      'closed and readable')
            return code or EXIT_RECORD_LOST
        cpu = (f' (writer CPU {r["cpu_time"]:.2f} s)' if isinstance(r.get('cpu_time'), float)
               else '')
        log.info(f'in-plant recording: closed {r["closed"]}: {r["messages"]} messages '
                 f'({counts}); every message of the run is in the bag{cpu}')
        return code

    def reap(self, timeout: float = 10.0) -> None:
        """Wait for the writer process to end after it closed the bag (it exits without the
        interpreter's teardown, but freeing a process with numba and LLVM loaded still takes
        15-20 ms here: the plant lingers meanwhile); killed after ``timeout`` s."""
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()

    def _wait_closed(self) -> dict | None:
        """The writer's closing reply: waited for while the ring still drains."""
        last_used = self.ring.used
        since = time.monotonic()
        while True:
            reply = self._reply(0.2)
            if reply is not None and 'ready' in reply:
                continue                 # a run that never started, or a late 'ready'
            if reply is not None and _failure(reply):
                self._writer_failed(reply=reply)
                return None
            if reply is not None:     # the bag is closed (the process ends on its own: reap)
                return reply
            if self.proc.poll() is not None:
                self._writer_failed()
                return None
            used = self.ring.used
            if used != last_used:
                last_used, since = used, time.monotonic()
            elif time.monotonic() - since > _CLOSE_STALL:
                self.proc.kill()
                self._writer_failed(f'made no progress for {_CLOSE_STALL:g} s')
                return None

    def _unrecorded(self) -> int:
        """With the writer dead: the records put into the ring that its bag lacks, exactly
        (:func:`~fohssv_sim.bag.inplant.unrecorded`), counted once."""
        if self._unrecorded_n is None:
            try:              # its last bytes are written before it can be reaped
                self.proc.wait(timeout=_CLOSE_STALL)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self._unrecorded_n = unrecorded(self.ring, self.path / f'{self.path.name}.mcap')
        return self._unrecorded_n

    def summary(self) -> dict[str, Any]:
        """The recording's figures for the plant's summary; with the writer dead, its lost
        records include those it was handed that its bag lacks."""
        if self._unrecorded_n is None and not self.failed and self.proc.poll() is not None:
            self._writer_failed()
        lacked = self._unrecorded() if self.failed else 0
        return {'record': str(self.path), 'record_lost': self.lost + lacked,
                'record_waits': self.waits, 'record_wait_time': self.wait_seconds}


def _failure(reply: dict) -> bool:
    """Whether a writer's reply is its last line before it gave up (a full disk)."""
    return 'error' in reply and 'ready' not in reply


def start(node: Any) -> InPlantRecording | None:
    """The plant's hook: an :class:`InPlantRecording` of ``node`` when ``record`` is set, else
    None. What the plant publishes is recorded as it is published: the serialized
    ``state``, ``planing_force``, ``/clock`` (and a hosted law's ``command``) messages by the
    plant's publish calls (``_send_state`` & co.), the views by their publishers'
    ``publish``; the commands the plant takes by :meth:`InPlantRecording.command`.

    Raises:
        ParameterError: a bad ``record``, or a bag the writer cannot create (exit 2).
    """
    path = check_record(node.options)
    if path is None:
        return None
    command = command_topic(node)
    made = [(node.state_pub.topic_name, contract.STATE, '_send_state', ''),
            (node.force_pub.topic_name, contract.PLANING_FORCE, '_send_force', ''),
            (command, contract.COMMAND,
             '_send_command' if hasattr(node, '_send_command') else None, '_command_wanted'),
            (node.clock_pub.topic_name, contract.CLOCK, '_send_clock', '_clock_wanted')]
    views = getattr(node, 'views', None)
    published = [] if views is None else list(zip(views.publishers, contract.VIEW_TOPICS,
                                                   strict=True))
    rec = InPlantRecording(node, path, [(name, topic) for name, topic, _, _ in made]
                           + [(pub.topic_name, topic) for pub, topic in published])
    for name, _, attr, wanted in made:
        if attr is not None:
            rec.tap_send(node, attr, name, wanted)
    for pub, _ in published:
        rec.tap(pub)
    rec.command_index = rec.index(command)
    params = {}
    names = node.list_parameters([], 0).names          # every declared parameter
    for name, param in zip(names, node.get_parameters(names)):
        value = param.value
        params[name] = list(value) if isinstance(value, (tuple, list)) or hasattr(
            value, 'tolist') else value
    rec.metadata({'fohssv.plant_parameters': params})
    node.get_logger().info(f'in-plant recording to {path} (writer process {rec.pid}, ring of '
                           f'{rec.ring.capacity} bytes)')
    return rec
