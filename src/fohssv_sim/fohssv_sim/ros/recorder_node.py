"""Recorder: write the run's topics to a rosbag2 bag (version 9, MCAP) as they arrive.

``ros2 run fohssv_sim recorder --ros-args -p bag_path:=runs/x``

* Messages are subscribed with ``raw=True`` and written as received (CDR bytes untouched).
* Each topic carries the profile the plant offers on it (:func:`.qos.offered_qos`) as
  ``offered_qos_profiles``, in metadata.yaml and in the MCAP channel, as rosbag2 writes it:
  ``ros2 bag play`` then offers the plant's reliability and durability.
* Topics (``topics``): by default the contract (``state``, ``planing_force``, ``command``,
  ``/clock``) and the plant's typed views (``pose``, ``twist``, ``planing_wrench``,
  ``vehicle_marker``: see :mod:`.views`).
* Log time = simulation time in ns: ``round(data[0] * 1e9)`` for the contract's
  Float64MultiArray topics (``data[0]`` is the exact t the plant computed), the stamp itself
  for ``/clock`` and the typed views (``header.stamp``). The exact doubles stay in the
  messages; the log time is for ordering and for tools (``ros2 bag info``, Foxglove).
* Run metadata, written at once as an MCAP metadata record ``fohssv`` and at close into
  ``metadata.yaml`` custom_data: package version, ``git describe`` and revision of
  ``$FOHSSV_ROOT``, recorder settings, and (when the plant answers its parameter services)
  every parameter of the node named by ``plant_node``: the model parameters, model options,
  solver, mode; and the node publishing ``command`` with its ``controller`` parameter (the
  law it hosts: ``fohssv.controller_node``, ``fohssv.controller``).
* Durability: the chunk in progress is flushed to the OS every ``flush_period`` seconds of
  wall time (and whenever it exceeds ``chunk_size`` bytes). SIGKILL loses at most the
  messages received in the last ``flush_period`` (plus one callback); SIGINT/SIGTERM close the
  bag completely (summary, index, metadata.yaml) after draining what the readers already
  hold (until the bag holds what a received ``run_end`` lists, else until nothing arrived
  for 0.5 s and for at most ``drain_timeout`` s, 10 by default: a lockstep plant paced by the
  recorder runs on while the recorder reads, so without a run_end messages may never stop
  arriving; a drain cut there says so in one line; it gives up once nothing arrived for
  ``end_timeout`` s, or at a second signal). ``python -m fohssv_sim.bag repair`` rebuilds a
  killed recorder's bag.
* End of run (``stop_at_run_end``, default true): the plant (and the player after a replay)
  publishes ``run_end`` once, with the number of messages it sent on each topic. The recorder
  stores it in the run metadata (``fohssv.run_end``), waits until its bag holds that many
  messages on every recorded topic listed (while messages keep arriving; what is missing
  once nothing arrived for ``end_timeout`` s is lost), closes the bag and
  exits: 0 when nothing is missing, 6 naming each topic's shortfall otherwise. After
  SIGINT/SIGTERM the same comparison is made once the delivered messages are drained.
* A bag closed without any message (the recorder stopped before the run started, e.g. because
  another node of the loop failed at start) is marked ``fohssv.empty`` in its run metadata,
  and the closing line says it is empty.
  (The plant lists the commands it received; ``/clock`` is keep-last 1 and not listed.)
* A second publisher of ``state`` (two plants on one domain and namespace) is reported once as
  a warning naming the nodes (the plants themselves refuse to run beside each other).
* Namespaces: topics given in other namespaces (``/a/state``) are written under their own
  names; ``run_end`` is heard in every namespace recorded (one recorder, two vehicles).
  Completeness is claimed only when checked: every publisher seen on a recorded sample topic
  owes a run_end (two players of one topic: the sum of both is compared); when one never comes
  within ``end_timeout`` of silence, or the publishers are gone without any run_end (the
  plant died), the bag is closed with exit 7.
* A full disk (an OS error while writing): one line naming it and ``fohssv repair``, exit 1.

Exit codes: 0 bag closed (end of run with nothing lost, or SIGINT/SIGTERM, also when
``drain_timeout`` cut the drain of a run that announced no end), 1 the bag cannot
be created or written (an OS error: a full disk), 2 invalid arguments or parameters (one
line: a wrong type, a value
out of range, an unknown parameter name, ``bag_path`` that exists already, also when another
recorder started on the same path created it first; see
:mod:`.startup`), 6 messages lost: the bag misses messages the run's ``run_end`` says were
published (the bag is closed and readable; the line names the topics and counts),
7 completeness not checked: a publisher of the recorded topics left without its ``run_end``
(also found at the end of the drain after a signal: a recorder far behind a fast run missed
the run_end of a plant that has left).
"""

from __future__ import annotations

import sys
import time
from datetime import datetime, timezone
from typing import Any

import rclpy
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import HistoryPolicy, QoSProfile
from rclpy.task import Future
from rosbags.rosbag2 import WriterError
from std_msgs.msg import String

from .. import contract
from ..bag.writer import LogTimes, RunWriter, source_info
from . import controller_name
from .bag_options import (
    RECORDED,
    RECORDER_PARAMETERS,
    RecorderOptions,
    bag_exists,
    default_bag_path,
    new_bag_path,
)
from .nodekit import (
    NODE_OPTIONS,
    STOP,
    SecondPublisherWarning,
    declare,
    destroy_on_error,
    error_line,
    final_log,
    message_class,
    offered_qos,
    profile,
    refuse_unknown,
    run_node,
    spin_until,
)
from .ros_params import refuse_early

__all__ = ['Recorder', 'main', 'default_bag_path', 'source_info', 'EXIT_LOST', 'EMPTY_KEY',
           'RECORDED']

#: Run-metadata key (metadata.yaml custom_data) of a bag closed without any message.
EMPTY_KEY = 'fohssv.empty'
#: Exit code when the bag misses messages that the run's ``run_end`` says were published.
EXIT_LOST = 6
#: Exit code when the bag's completeness could not be checked: a publisher of the recorded
#: topics left (or stayed silent for ``end_timeout``) without its ``run_end``.
EXIT_UNCHECKED = 7
#: Exit code of an OS error: the bag could not be created or written (a full disk).
EXIT_OS_ERROR = 1
#: After a signal: stop draining once nothing arrived for this long (s) and no publisher of
#: a recorded topic is left.
_DRAIN_QUIET = 0.5
#: ... and while one is left, once nothing arrived for this long (s): a reliable writer sends
#: again what a reader lost (the full shared-memory port of a recorder that fell behind drops
#: what comes in) only after its next periodic heartbeat, every 3 s in Fast DDS, so a shorter
#: silence is not the end of what was published (seen: a recorder stopped for 0.4 s during an
#: unpaced run, signalled at its end, closed a bag without 1259 states and without run_end).
_REPAIR_QUIET = 5.0
#: A complete bag is closed at once unless the plant's parameters are on their way (asked,
#: or its parameter services ready to be asked): then it waits for them this long at most (s).
_PARAMS_WAIT = 5.0



def _namespace(name: str) -> str:
    """The namespace of a resolved topic name (``/a/state`` -> ``/a``, ``/state`` -> ``/``)."""
    return name.rsplit('/', 1)[0] or '/'


def _namespaces(topics: list[str], own: str) -> list[str]:
    """The namespaces whose ``run_end`` the recorder hears: those of the recorded topics
    (``/clock`` is global and says nothing), else the recorder's own."""
    found = sorted({_namespace(n) for n in topics if n != contract.CLOCK.name})
    return found or [own]


class _Source:
    """What publishes the recorded topics of one namespace (a plant, a player, two of them):
    its ``run_end`` subscription, the run_ends heard, and the most publishers seen at once on
    its run_end and sample topics (every one of them must announce its end before the bag is
    called complete). Commands are left out: controllers publish no run_end."""

    def __init__(self, node: Recorder, namespace: str, topics: list[str]) -> None:
        self.node = node
        self.namespace = namespace
        self.topic = f"{namespace.rstrip('/')}/{contract.RUN_END.name}"
        self.ends: list[dict] = []
        self.samples = [t for t in topics if contract.find_topic(t, RECORDED)
                        not in (contract.COMMAND, contract.CLOCK)]
        self.most = 0          # the most publishers seen at once
        self.now = 0           # publishers at the last look
        self.seen = False      # a publisher was there once
        self.sub = node.create_subscription(String, self.topic,
                                            lambda msg: node._on_run_end(self, msg),
                                            profile(contract.RUN_END))

    def look(self) -> None:
        """Count the publishers now (graph queries: every 0.1 s, off the message path)."""
        count = self.node.count_publishers
        self.now = max([count(self.topic)] + [count(t) for t in self.samples])
        self.most = max(self.most, self.now)
        self.seen = self.seen or self.now > 0

    def expected(self) -> int:
        """How many run_ends this namespace owes: one per publisher seen (at least those
        heard)."""
        return max(self.most, len(self.ends))

    def left_without_end(self) -> bool:
        """Its publishers were there and are gone, and not every one announced its end."""
        return self.seen and self.now == 0 and len(self.ends) < self.expected()


class Recorder(Node):
    """Subscribes to the run's topics and writes them to a bag; see the module docstring."""

    @destroy_on_error
    def __init__(self, **kwargs: Any) -> None:
        super().__init__('recorder', **NODE_OPTIONS, **kwargs)
        self.options = RecorderOptions(**declare(self, RECORDER_PARAMETERS))
        refuse_unknown(self)
        self.end_timeout = self.options.end_timeout
        self.bag_path = new_bag_path(self.options)

        self._times = LogTimes()
        self.closed = False
        self.done = Future()          # set when the run ended and the bag holds it (or not)
        self.exit_code = 0
        self._expected: dict[str, int] | None = None   # from run_end: topic -> messages
        self._runs_ended = 0          # run_end messages heard
        self.unchecked = ''           # why the bag's completeness could not be checked
        self._end_timer = None
        self._progress = (0, time.monotonic())   # (messages written, when reached)
        self.write_error: Exception | None = None   # the bag could not be written (full disk)
        self.writer = self._create_bag()
        print(f'recording to {self.bag_path}', flush=True)
        try:
            self._start()
        except BaseException:
            self.close()     # interrupted while starting: still a complete (empty) bag
            raise

    def _create_bag(self) -> RunWriter:
        """The bag, created. A bag_path that appeared since :func:`new_bag_path` looked (a
        second recorder started on the same path) is refused as one that existed: exit 2."""
        try:
            return RunWriter(self.bag_path, chunk_size=self.options.chunk_size).open()
        except (FileExistsError, WriterError):
            if not self.bag_path.exists():
                raise
            raise bag_exists(self.options, self.bag_path) from None

    def _start(self) -> None:
        o = self.options
        topics = o.recorded()
        # run_end first: a player (or plant) that sees this recorder's data readers then sees
        # its run_end reader too and keeps its run_end until it is taken (issue 22.6)
        names = [self.resolve_topic_name(n) for n, _ in topics]
        self._sources = {ns: _Source(self, ns, [n for n in names if _namespace(n) == ns])
                         for ns in _namespaces(names, self.get_namespace())}
        self._last_log = 0
        self.subscriptions_ = []
        self._deferred = None
        wait_commands = o.command_publishers
        for name, topic in topics:
            base = profile(topic)
            # same reliability/durability as the plant's; keep-all: when the recorder falls
            # behind, its reader stops acknowledging instead of overwriting what it has not
            # written yet, and a lockstep plant waits for it (nothing lost)
            qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=base.depth,
                             reliability=base.reliability, durability=base.durability)
            if topic is contract.STATE and wait_commands > 0:
                # deferred until the command subscription hears enough publishers
                self._deferred = (name, topic, qos)
                self.writer.add_topic(self.resolve_topic_name(name), topic.type,
                                      qos=[offered_qos(topic)])
                continue
            resolved = self.resolve_topic_name(name)
            sub = self.create_subscription(message_class(topic), name,
                                           self._callback(topic, resolved), qos, raw=True)
            self.writer.add_topic(resolved, topic.type, qos=[offered_qos(topic)])
            self.subscriptions_.append(sub)
        self.topic_names = [self.resolve_topic_name(n) for n, _ in topics]
        if self._deferred is not None:
            # there is one: RecorderOptions refuses command_publishers > 0 without it
            command = next(s for s in self.subscriptions_
                           if contract.find_topic(s.topic_name) is contract.COMMAND)
            self._wait_commands = (command, wait_commands)
            self._defer_timer = self.create_timer(0.005, self._maybe_subscribe_state)
        self.writer.add_metadata({
            **source_info(),
            'fohssv.recorder_started_utc': datetime.now(timezone.utc).isoformat(),
            'fohssv.topics': self.topic_names,
            'fohssv.log_time': 'simulation time in ns: round(data[0] * 1e9) for '
                               'Float64MultiArray topics, the stamp for /clock',
            'fohssv.flush_period_s': repr(o.flush_period),
            'fohssv.chunk_size_bytes': str(o.chunk_size),
            'fohssv.plant_node': o.plant_node,
        })
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._flush_timer = self.create_timer(o.flush_period, self._flush, clock=steady)
        # always heard (a drain after a signal waits for what it lists); it ends the recording
        # only with stop_at_run_end
        self._stop_at_end = o.stop_at_run_end
        self._watch_timer = self.create_timer(0.1, self._watch_sources, clock=steady)
        state = self.resolve_topic_name(contract.STATE.name)
        self._rivals = (SecondPublisherWarning(self, state) if state in self.topic_names
                        else None)
        self._plant = '' if o.plant_node.lower() == 'none' else o.plant_node
        self._plant_deadline = time.monotonic() + o.plant_timeout
        self._plant_timer = None
        self._asking = False              # list/get_parameters asked, no answer yet
        self._complete_at: float | None = None   # when _check_end found the bag complete
        if self._plant:
            self._list = self.create_client(ListParameters, f'/{self._plant}/list_parameters')
            self._get = self.create_client(GetParameters, f'/{self._plant}/get_parameters')
            self._plant_timer = self.create_timer(0.05, self._poll_plant, clock=steady)
        # the law answering the plant: the 'controller' parameter of the command's publisher
        # (stored as fohssv.controller, e.g. for plot titles)
        command = self.resolve_topic_name(contract.COMMAND.name)
        if command in self.topic_names:
            controller_name.ask(self, command, self._on_controller,
                                timeout=o.plant_timeout + 60.0)

    def _on_controller(self, values: dict[str, Any]) -> None:
        if values and not self.closed:
            self.writer.add_metadata(values)

    def _maybe_subscribe_state(self) -> None:
        command, wanted = self._wait_commands
        if self._deferred is None or command.get_publisher_count() < wanted:
            return
        name, topic, qos = self._deferred
        self._deferred = None
        self.destroy_timer(self._defer_timer)
        self.subscriptions_.append(self.create_subscription(
            message_class(topic), name, self._callback(topic, self.resolve_topic_name(name)),
            qos, raw=True))
        print(f'command matched {command.get_publisher_count()} publisher(s); subscribed to '
              f'{self.resolve_topic_name(name)}', flush=True)

    # -- messages ---------------------------------------------------------------------------
    def _callback(self, topic: contract.Topic, name: str):
        """The writer of ``topic``'s raw messages under ``name`` (the resolved name the
        recorder subscribed to, in whatever namespace it was given); log times by the one rule
        (:class:`~fohssv_sim.bag.writer.LogTimes`, shared with in-plant recording)."""
        write = self.writer.write
        times = self._times
        if topic.type == contract.CLOCK.type:
            def on_clock(raw: bytes) -> None:
                write(name, times.clock(raw), raw)
            return on_clock
        if topic.type != contract.FLOAT64_ARRAY:
            # the typed views start with a std_msgs/Header: the stamp is the log time
            def on_stamped(raw: bytes, _type: str = topic.type) -> None:
                write(name, times.stamped(raw, _type), raw)
            return on_stamped

        def on_array(raw: bytes) -> None:
            write(name, times.array(raw), raw)
        return on_array

    # -- end of run -------------------------------------------------------------------------
    def _on_run_end(self, source: _Source, msg: String) -> None:
        try:
            info = contract.parse_run_end(msg.data)
        except contract.ContractError as exc:
            self.get_logger().warning(f'dropped a bad run_end message: {exc}')
            return
        if self.closed:
            return
        source.ends.append(info)
        self._runs_ended += 1
        # what every run_end heard so far lists, summed: two players of one topic each list
        # what they sent (the bag holds both); topics the recorder does not record are left out
        expected: dict[str, int] = dict(self._expected or {})
        for k, v in info['published'].items():
            if k in self.writer.counts:
                expected[k] = expected.get(k, 0) + v
        self._expected = expected
        self._progress = (sum(self.writer.counts.values()), time.monotonic())
        key = 'fohssv.run_end' if self._runs_ended == 1 else f'fohssv.run_end.{self._runs_ended}'
        self.writer.add_metadata({key: info})
        waiting = self._unended()
        more = (f'; still waiting for the run_end of {waiting}' if waiting else '')
        self.get_logger().info(
            f"run_end from the {info.get('source', '?')} on {source.topic} "
            f"({info.get('reason', '')}): waiting for {sum(expected.values())} messages on "
            f'{len(expected)} topics{more}')
        if self._stop_at_end and self._end_timer is None:
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            self._end_timer = self.create_timer(0.01, self._check_end, clock=steady)

    def _unended(self) -> str:
        """The sources (publishers of the recorded topics) whose run_end has not arrived, in
        words; '' when every one seen has announced its end."""
        parts = [f'{src.expected() - len(src.ends)} of {src.expected()} publisher(s) in '
                 f'{src.namespace}' for src in self._sources.values()
                 if len(src.ends) < src.expected()]
        return ', '.join(parts)

    def _watch_sources(self) -> None:
        """Every 0.1 s: how many publishers each namespace's topics have (so that two
        players of one topic need two run_ends), and whether a plant left without run_end."""
        if self.done.done() or self.closed:
            return
        for src in self._sources.values():
            src.look()
        if not self._stop_at_end or self._end_timer is not None:
            return
        gone = [src for src in self._sources.values() if src.left_without_end()]
        if gone and self._stalled():
            names = ', '.join(src.namespace for src in gone)
            self.get_logger().error(
                f'the publishers of the recorded topics in {names} are gone without a run_end '
                f'and nothing arrived for end_timeout={self.end_timeout:g} s (the plant '
                f'died?): closing the bag; its completeness cannot be checked '
                f'(exit {EXIT_UNCHECKED})')
            self.unchecked = 'no run_end from ' + names
            self.exit_code = EXIT_UNCHECKED
            self.done.set_result(self.exit_code)

    def missing(self) -> dict[str, tuple[int, int]]:
        """Topics whose recorded count is below the run_end's: topic -> (recorded, published)."""
        counts = self.writer.counts
        return {k: (counts.get(k, 0), v) for k, v in (self._expected or {}).items()
                if counts.get(k, 0) < v}

    def _stalled(self) -> bool:
        """True once no message was written for ``end_timeout`` s: a backlog that is still
        being written (a loaded machine, a fast replay) is waited for, a loss is not."""
        total, since = self._progress
        now = time.monotonic()
        n = sum(self.writer.counts.values())
        if n != total:
            self._progress = (n, now)
            return False
        return now - since >= self.end_timeout

    def _check_end(self) -> None:
        if self.done.done():
            return
        missing = self.missing()
        waiting = self._unended()
        if (missing or waiting) and not self._stalled():
            return
        if not (missing or waiting) and self._parameters_coming():
            return
        self._end_timer.cancel()
        if missing:
            self.exit_code = EXIT_LOST
        elif waiting:
            # never claim a completeness that was not checked: a publisher seen on the
            # recorded topics never announced what it sent
            self.unchecked = f'no run_end from {waiting}'
            self.exit_code = EXIT_UNCHECKED
            self.get_logger().error(
                f'no run_end from {waiting} within end_timeout={self.end_timeout:g} s of '
                'silence: the bag holds what every run_end heard lists, but its completeness '
                f'cannot be checked; closing (exit {EXIT_UNCHECKED})')
        else:
            self.exit_code = 0
            self.get_logger().info('every message of the run is in the bag; closing')
        self.done.set_result(self.exit_code)

    def _parameters_coming(self) -> bool:
        """Whether a complete bag waits for the plant's parameters: asked and not answered,
        or its services ready and about to be asked, for at most :data:`_PARAMS_WAIT` s from
        the bag's completeness (a short run can end before the answer: the bag then lacked
        them without a word, seen under load); past that, the bag records why not."""
        polling = self._plant_timer is not None and not self._plant_timer.is_canceled()
        if not (self._asking or (polling and self._list.service_is_ready()
                                 and self._get.service_is_ready())):
            return False
        now = time.monotonic()
        if self._complete_at is None:
            self._complete_at = now
        if now - self._complete_at < _PARAMS_WAIT:
            return True
        if polling:
            self._plant_timer.cancel()
        self._record_plant_error(f'no answer from the parameter services of /{self._plant} '
                                 f'within {_PARAMS_WAIT:g} s of the run_end')
        return False

    def drain(self, executor: Any) -> None:
        """After a signal: take what the readers already hold. Once a run_end arrived, until
        the bag holds what it lists (the run ended: its backlog is finite and is written while
        it keeps arriving); before, until nothing arrived for 0.5 s with no publisher of a
        recorded topic left, or for 5 s with one left (a reliable writer sends again what was
        lost on the way at its next heartbeat, every 3 s), and for at most
        ``drain_timeout`` s: a plant paced by this recorder (lockstep,
        ``pace_to_subscribers``) runs on while the recorder reads, so without a run_end
        messages may never stop arriving. Either way it ends when nothing arrived for
        ``end_timeout`` s, or at a further signal. Cut by ``drain_timeout``, one line says so
        and where the bag ends (exit 0: the run went on past the stop asked for)."""
        signals = STOP.count
        start = time.monotonic()
        written = sum(self.writer.counts.values())
        self._progress = (written, start)
        cut = told = False
        while rclpy.ok() and STOP.count == signals:
            if self._expected is not None and not self.missing():
                break
            if (self._expected is None
                    and time.monotonic() - start >= self.options.drain_timeout):
                cut = True
                break
            executor.spin_once(timeout_sec=0.02)
            if self._stalled():
                break
            quiet = time.monotonic() - self._progress[1]
            if self._expected is None and quiet >= _DRAIN_QUIET:
                if quiet >= _REPAIR_QUIET or not self._publishers_left():
                    break
                if not told:
                    told = True
                    self.get_logger().info(
                        f'draining: nothing arrived for {_DRAIN_QUIET:g} s, but the recorded '
                        'topics still have publishers: waiting until nothing arrived for '
                        f'{_REPAIR_QUIET:g} s (a reliable writer sends again what was lost on '
                        'the way at its next heartbeat; a second signal stops now)')
        if self.missing():
            self.exit_code = EXIT_LOST
        elif self._stop_at_end and self.exit_code == 0:
            self._gone_without_end()
        if cut:
            self._report_cut(time.monotonic() - start, sum(self.writer.counts.values()) - written)

    def _publishers_left(self) -> bool:
        """Whether any recorded topic still has a publisher (a graph query; the drain asks
        only once it has been quiet for _DRAIN_QUIET)."""
        return any(self.count_publishers(t) for t in self.topic_names)

    def _gone_without_end(self) -> None:
        """After the drain: publishers of the recorded topics that were there and are gone
        without their run_end make the bag's completeness unchecked (exit 7), as when they
        leave during the run. A recorder far behind a fast run misses the run_end this way:
        the plant left, and a reader drops what it has not taken from a writer that goes away
        (seen with ``make demo`` on a loaded machine: a signal 30 s after the run, 11865 of
        20001 states in the bag, and exit 0)."""
        for src in self._sources.values():
            src.look()
        gone = [src.namespace for src in self._sources.values() if src.left_without_end()]
        if gone:
            names = ', '.join(gone)
            self.unchecked = 'no run_end from ' + names
            self.exit_code = EXIT_UNCHECKED
            print(f'recorder: error: the publishers of the recorded topics in {names} are '
                  'gone without a run_end (not heard before the signal): the bag holds what '
                  'was delivered, its completeness cannot be checked (exit '
                  f'{EXIT_UNCHECKED})', file=sys.stderr, flush=True)

    def _report_cut(self, waited: float, taken: int) -> None:
        """The one line of a drain cut by ``drain_timeout`` (no run_end was heard)."""
        newest = self.writer.newest
        end = 'holds no message' if newest is None else f'ends at t={newest * 1e-9:.6g} s'
        print(f'recorder: warning: drain_timeout={self.options.drain_timeout:g} s reached after '
              f'the signal with messages still arriving ({taken} written in {waited:.1f} s) and '
              f'no run_end heard: the run went on, and the bag {end} (what was published after '
              f'that is not in it); closing {self.bag_path} (exit 0)', file=sys.stderr,
              flush=True)

    def report_loss(self) -> None:
        """One line naming each topic the run_end lists with fewer messages in the bag."""
        missing = self.missing()
        if missing:
            lost = sum(p - r for r, p in missing.values())
            detail = ', '.join(f'{k} {r} of {p}' for k, (r, p) in missing.items())
            print(f'recorder: error: {lost} message(s) lost: the bag holds {detail} published '
                  f'(run_end); {self.bag_path} is closed and readable', file=sys.stderr,
                  flush=True)

    def _flush(self) -> None:
        self.writer.flush()

    # -- plant parameters -------------------------------------------------------------------
    def _poll_plant(self) -> None:
        if self._list.service_is_ready() and self._get.service_is_ready():
            self._plant_timer.cancel()
            self._asking = True
            req = ListParameters.Request()
            self._list.call_async(req).add_done_callback(self._on_list)
        elif time.monotonic() > self._plant_deadline:
            self._plant_timer.cancel()
            self._record_plant_error(f'no parameter services of node /{self._plant} within '
                                     'plant_timeout')

    def _on_list(self, future) -> None:
        result = future.result()
        if result is None:
            self._record_plant_error('list_parameters failed')
            return
        names = sorted(result.result.names)
        req = GetParameters.Request(names=names)
        self._get.call_async(req).add_done_callback(
            lambda f: self._on_get(names, f))

    def _on_get(self, names: list[str], future) -> None:
        self._asking = False
        result = future.result()
        if result is None or len(result.values) != len(names):
            self._record_plant_error('get_parameters failed')
            return
        params = {}
        for n, v in zip(names, result.values, strict=True):
            value = parameter_value_to_python(v)
            params[n] = list(value) if isinstance(value, (tuple, list)) or hasattr(
                value, 'tolist') else value
        if self.closed:
            return
        self.writer.add_metadata({'fohssv.plant_parameters': params})
        self.get_logger().info(f'stored {len(params)} parameters of /{self._plant}')

    def _record_plant_error(self, text: str) -> None:
        self._asking = False
        if not self.closed:
            self.writer.add_metadata({'fohssv.plant_parameters_error': text})
        self.get_logger().warning(f'run metadata without plant parameters: {text}')

    # -- end --------------------------------------------------------------------------------
    def close(self) -> None:
        """Close the bag (summary, index, metadata.yaml) and print the counts. When the bag
        cannot be written (a full disk), one line says so and how to rebuild it."""
        if self.closed:
            return
        self.closed = True
        error = self.write_error
        if error is None:
            try:
                if sum(self.writer.counts.values()) == 0:
                    # stopped before any message (e.g. a node of the loop failed at start):
                    # say so in the bag, so that an empty run is not taken for a recorded one
                    self.writer.add_metadata({EMPTY_KEY: 'no message arrived before the '
                                                         'recorder stopped'})
                self.writer.close()
            except Exception as exc:  # noqa: BLE001 - OSError, or the library's after it
                error = exc
        if error is not None:
            self.exit_code = EXIT_OS_ERROR
            why = getattr(error, 'strerror', None) or error
            print(f'recorder: error: writing {self.bag_path}: {why}; the '
                  f'bag is unfinished ({sum(self.writer.counts.values())} messages written): '
                  f'`fohssv repair {self.bag_path}` rebuilds it once there is space',
                  file=sys.stderr, flush=True)
            return
        total = sum(self.writer.counts.values())
        counts = ', '.join(f'{k}: {v}' for k, v in self.writer.counts.items())
        print(f'closed {self.bag_path}: {total} messages ({counts})'
              + (f'; the bag is empty (marked {EMPTY_KEY} in its metadata)' if not total else ''),
              flush=True)


def _run(node: Recorder) -> int:
    # SingleThreadedExecutor: rclpy's EventsExecutor (faster) did not run this node's
    # steady-clock timers and service clients in a first try; see docs/recording.md
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        spin_until(executor, node.done)
        if STOP.received is not None:
            final_log('recorder', 'stopping: draining the delivered messages')
            node.drain(executor)
    except OSError as exc:          # the bag cannot be written (ENOSPC): one line at close
        node.write_error = exc
    node.close()                    # here, so that a failing close gives the exit code
    return node.exit_code


def _close(node: Recorder) -> None:
    node.close()
    if node.write_error is None:
        node.report_loss()


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run fohssv_sim recorder``; returns the exit code. SIGINT and
    SIGTERM only set STOP (spin.StopSignal): the loop ends between callbacks, the readers are
    drained and the bag is closed, in order."""
    refuse_early('recorder', args, RECORDER_PARAMETERS)    # exit 2 before any DDS entity
    return run_node('recorder', args, Recorder, _run, specs=RECORDER_PARAMETERS,
                    on_error=error_line('recorder'), on_exit=_close)


if __name__ == '__main__':
    sys.exit(main())
