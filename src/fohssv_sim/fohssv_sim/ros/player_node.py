"""Player: replay a recorded run. ``ros2 run fohssv_sim player --ros-args -p bag_path:=runs/x``

Two modes (parameter ``mode``):

* ``republish`` (default): publish the bag's contract topics on their recorded names, the
  serialized CDR bytes exactly as recorded, in recorded order, paced by the high-water mark
  of the log times (the simulation time) at ``rate`` x real time, with ``/clock`` whenever
  that mark moves (never back, but at a reset recorded in the run:
  :func:`~fohssv_sim.bag.replay.replay_timeline`).
  ``rate = 0`` plays as fast as the subscribers allow: it waits for them, publishes with
  reliable keep-all, transient-local history (a publish blocks while a keep-all subscriber's
  queue is full and is retried, never dropped; a transient-local subscriber gets every
  message even when its side of the match completes late) and waits for the last messages
  to be acknowledged. After the last message the player publishes ``run_end`` (see
  :mod:`fohssv_sim.contract`) with the messages it sent on each topic, so a recorder can check
  its bag; a subscriber that has not acknowledged every message within ``end_timeout`` is
  named in a warning (DDS acknowledgements can lag under load: the recorder's comparison with
  ``run_end`` is what decides a loss).
* ``commands`` (open loop): act as the controller of a fresh plant. For each ``state`` at time
  t it publishes the recorded ``command`` whose ``data[0]`` is exactly t (the same double, as
  recorded bytes). A lockstep plant with the recorded parameters then reproduces the recorded
  trajectory bit for bit. A state with no recorded command is an error naming t. Before the
  first command the player reads the plant's model parameters, ``control_period`` and
  ``initial_state`` through its parameter services (node ``plant_node``) and compares them
  with the bag's ``fohssv.plant_parameters``: a mismatch is refused (exit 1, naming each
  difference) unless ``force`` is true (a warning). A bag without recorded parameters is
  replayed with a warning.

Bags are read with the pure loader (:func:`fohssv_sim.bag.scan`), a chunk at a time: once to
learn the channels and counts, then as they are played (republish; the commands mode keeps
the recorded commands only), so a bag of any length is played in bounded memory. A cut bag
(killed recorder) plays everything recoverable, with a warning.

Exit codes: 0 played to the end (republish), or the plant's run ended / the bag's commands
were used up (commands); 1 bad bag (missing, empty, truncated before any message, not a bag:
one ``player: error: ...`` line, no traceback), a state without a recorded command, or a
plant that does not match the recording (commands, without ``force``);
2 invalid parameters; 4 no subscriber (rate 0) or no plant (commands) within
``start_timeout``. SIGINT/SIGTERM stop cleanly with the code so far (0): the process runs
under :func:`.nodekit.run_node` like every node, so a signal only sets ``spin.STOP`` and the
replay stops between callbacks (a final ``interrupted after ...`` line; no ``run_end``).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterator
from typing import Any

import rclpy
from rcl_interfaces.srv import GetParameters
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray, String

from .. import contract
from ..bag import BagError, scan
from ..bag.loader import stream
from ..bag.replay import (
    COMPARED,
    PlayerError,
    Track,
    choose_tracks,
    command_table,
    compare_plant,
    select_tracks,
    timeline,
)
from .bag_options import PLAYER_MODES, PLAYER_PARAMETERS, PlayerOptions
from .nodekit import (
    NODE_OPTIONS,
    STOP,
    HoldReporter,
    SubscriptionGate,
    declare,
    destroy_on_error,
    error_line,
    final_log,
    make_executor,
    message_class,
    profile,
    refuse_unknown,
    run_node,
    spin_until,
)
from .ros_params import refuse_early

__all__ = ['Player', 'PlayerError', 'Track', 'select_tracks', 'command_table', 'main',
           'compare_plant', 'COMPARED',
           'EXIT_OK', 'EXIT_ERROR', 'EXIT_BAD_PARAMETERS', 'EXIT_NO_PEERS']

EXIT_OK, EXIT_ERROR, EXIT_BAD_PARAMETERS, EXIT_NO_PEERS = 0, 1, 2, 4
MODES = PLAYER_MODES
#: Most messages published in one go before the executor runs again (rate 0: all are due).
_BATCH = 256


def _paced_qos(topic: contract.Topic) -> QoSProfile:
    # the contract's profile, offered transient-local so that transient-local subscribers
    # match too (volatile ones ignore the history)
    base = profile(topic)
    return QoSProfile(history=base.history, depth=base.depth, reliability=base.reliability,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _deep_qos() -> QoSProfile:
    # transient-local: a subscriber asking for it gets everything even if its side of the
    # match completes after the first publish; volatile subscribers stay compatible
    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Player(Node):
    """See the module docstring. Raises ValueError (bad parameters) or PlayerError/BagError
    (bad bag) from the constructor."""

    @destroy_on_error
    def __init__(self, **kwargs: Any) -> None:
        super().__init__('player', **NODE_OPTIONS, **kwargs)
        self.options = PlayerOptions(**declare(self, PLAYER_PARAMETERS))
        refuse_unknown(self)
        # BagError: one line from main. Republish reads the messages again as it plays them;
        # the commands mode keeps the recorded commands (its table)
        self.scan = scan(self.options.bag_path, keep=lambda ch: (
            self.options.mode != 'republish'
            and contract.find_topic(ch.topic) is contract.COMMAND))
        if not self.scan.complete:
            self.get_logger().warning(
                f'bag is truncated; playing the {self.scan.message_count} messages that could '
                f'be recovered ({self.scan.problem}); python -m fohssv_sim.bag repair '
                f'{self.options.bag_path} rebuilds it')
        self.finished = Future()
        self.exit_code = EXIT_OK
        self.published = 0
        if self.options.mode == 'republish':
            self._setup_republish()
        else:
            self._setup_commands()

    # -- republish -------------------------------------------------------------------------
    def _setup_republish(self) -> None:
        wanted = self.options.topics
        tracks = choose_tracks(self.scan, wanted)
        if self.options.clock and not any(w.lstrip('/') == 'clock' for w in wanted):
            # /clock is generated from the log times (every step, never keep-last-dropped)
            tracks = [t for t in tracks if t.name != contract.CLOCK.name]
        sc = self.scan
        self._names = {c.id: c.topic for c in sc.channels.values()
                       if c.topic in {t.name for t in tracks} and c.id in sc.channel_counts}
        counts = dict.fromkeys((t.name for t in tracks), 0)
        for cid, name in self._names.items():
            counts[name] += sc.channel_counts[cid]
        self.total = sum(counts.values())
        if not self.total:
            raise PlayerError(f'{self.scan.files.directory}: no message to play on '
                              f'{[t.name for t in tracks] or "any contract topic"}')
        self.pubs = {}
        for tr in tracks:
            qos = _deep_qos() if self.options.rate == 0 else _paced_qos(tr.topic)
            self.pubs[tr.name] = self.create_publisher(message_class(tr.topic), tr.name,
                                                       qos)
        self.clock_pub = None
        if self.options.clock and contract.CLOCK.name not in self.pubs:
            self.clock_pub = self.create_publisher(
                Clock, contract.CLOCK.name, _deep_qos() if self.options.rate == 0 else
                _paced_qos(contract.CLOCK))
        self.sent = dict.fromkeys(self.pubs, 0)
        self.end_pub = self.create_publisher(String, contract.RUN_END.name,
                                             profile(contract.RUN_END))
        times = [sc.channel_times[cid] for cid in self._names]
        span = (max(last for _, last in times) - min(first for first, _ in times)) * 1e-9
        rate = self.options.rate
        self.get_logger().info(
            f'republishing {self.options.bag_path}: {counts}, {span:.6g} s simulated, rate '
            f'{rate:g}' + (' (as fast as the subscribers allow)' if rate == 0 else '')
            + ('; /clock at every log time' if self.clock_pub else ''))
        self._start_republish()

    # Republishing runs from the executor: a timer waits for the subscribers, then
    # spin_until paces the messages (Paced: pacing_wait / publish_due, as for the real-time
    # plant), spinning in between; the node's future completes after the last message.
    def _start_republish(self) -> None:
        # /clock: the high-water mark of the log times (monotonic; back only at a recorded
        # reset), published before the message that moves it (bag/replay.py)
        self._queue = timeline(self._playlist(), self.options.rate)
        self._head = next(self._queue, None)   # ((name, log, raw), due, clock) played next
        self._first_log: int | None = None   # log times of the first and last played
        self._last_log = 0
        self._wall0: float | None = None     # wall time the first message was due
        self.wall = 0.0                      # wall seconds from the first to the last message
        self.clock_sent = 0
        self._clock_due: int | None = None   # the last /clock published (ns)
        self._wait_start = time.monotonic()
        self._minimums_since: float | None = None
        self._settled_since: float | None = None
        self._wait_timer = self.create_timer(0.01, self._check_subscribers)

    def _check_subscribers(self) -> None:
        """Start once every topic has ``min_subscribers`` (or at the start timeout: rate 0
        fails then, a paced replay starts anyway)."""
        if self._wall0 is not None or self.finished.done():
            return
        missing = [n for n, p in self.pubs.items()
                   if p.get_subscription_count() < self.options.min_subscribers]
        if not missing and not self._listed_matched():
            return
        if missing:
            waited = time.monotonic() - self._wait_start
            if waited < self.options.start_timeout:
                return
            what = (f'{", ".join(missing)} without {self.options.min_subscribers} subscriber(s) '
                    f'after {waited:.1f} s')
            if self.options.rate == 0:
                self._fail(EXIT_NO_PEERS, f'start timeout: {what}; nothing would receive '
                           'the messages (same ROS_DOMAIN_ID and namespace?)')
                return
            self.get_logger().warning(f'starting without all subscribers: {what}')
        self.destroy_timer(self._wait_timer)
        self._wall0 = time.monotonic()

    def _listed_matched(self) -> bool:
        """Every subscription the graph lists on the played topics and on ``run_end`` has
        matched this player's writers: a recorder started together with the player is heard
        in full, and its run_end reader is matched before the end is announced (it used to
        miss the run_end and never stop). Best effort: 2 s after the minimums were met the
        replay starts anyway (a listed reader may never match, e.g. incompatible QoS)."""
        now = time.monotonic()
        if self._minimums_since is None:
            self._minimums_since = now
        if now - self._minimums_since > 2.0:
            return True
        pubs = [*self.pubs.values(), self.end_pub] + (
            [self.clock_pub] if self.clock_pub is not None else [])
        if not all(p.get_subscription_count() >= self.count_subscribers(p.topic_name)
                   for p in pubs):
            self._settled_since = None
            return False
        # settled for 0.3 s: a recorder creating its readers one after the other is seen
        # whole, not between two of them (its volatile /clock reader would miss the start)
        if self._settled_since is None:
            self._settled_since = now
        return now - self._settled_since >= 0.3

    def pacing_wait(self) -> float | None:
        """Seconds until the next message is due; None before the start and after the end."""
        if self._wall0 is None or self.finished.done():
            return None
        return self._wall0 + self._head[1] - time.monotonic()

    def _playlist(self) -> Iterator[tuple[str, int, bytes]]:
        """(track name, log ns, CDR) of the played tracks in recorded order, read from the
        bag as the replay goes (a chunk at a time)."""
        names = self._names
        _, messages = stream(self.options.bag_path)
        for cid, log, raw in messages:
            name = names.get(cid)
            if name is not None:
                yield name, log, raw

    def publish_due(self) -> None:
        """Publish the messages due by now (at most :data:`_BATCH`, then back to the
        executor); after the last one the run is complete."""
        now = time.monotonic() - self._wall0
        for _ in range(_BATCH):
            head = self._head
            if head is None or head[1] > now or not rclpy.ok() or STOP.received is not None:
                break
            (name, log, raw), _, clock = head
            if self.clock_pub is not None and clock is not None and self._clock_due != clock:
                if not self._publish_blocking(self.clock_pub, Clock(
                        clock=Time(nanoseconds=clock).to_msg())):
                    break
                self.clock_sent += 1
                self._clock_due = clock     # published: not again if the message is retried
            if not self._publish_blocking(self.pubs[name], raw):
                break
            self._head = next(self._queue, None)
            if self._first_log is None:
                self._first_log = log
            self._last_log = log
            self.published += 1
            self.sent[name] += 1
        if self._head is None:
            self.wall = time.monotonic() - self._wall0
            self._end(EXIT_OK)

    def _publish_blocking(self, pub: Any, data: Any) -> bool:
        """Publish; at rate 0 a keep-all subscriber's full queue makes DDS time out: retry
        until it is accepted (True), or a signal stops the player (False: not sent)."""
        while True:
            try:
                pub.publish(data)
                return True
            except Exception:  # noqa: BLE001 - rclpy raises RCLError on a publish timeout
                if self.options.rate != 0 or not rclpy.ok():
                    raise
                if STOP.received is not None:
                    return False
                time.sleep(0.001)

    def end_republish(self, executor: Any) -> int:
        """After the last message: announce ``run_end``, wait for the acknowledgements and
        linger (spinning ``executor``); the exit code."""
        self._announce_end()
        pubs = list(self.pubs.values()) + [p for p in (self.clock_pub,) if p] + [self.end_pub]
        unacked = self._flush_all(pubs, executor)
        span = (self._last_log - (self._first_log or 0)) * 1e-9
        wall = self.wall
        self.get_logger().info(
            f'played {self.published} messages, {span:.6g} s simulated in {wall:.3f} s wall '
            f'(x{span / wall if wall > 0 else math.inf:.3g})')
        if unacked:
            # not proof of a loss: under load Fast DDS acknowledged 500 messages a keep-all
            # subscriber had all taken more than 5 s late. The subscriber that must keep
            # everything (a recorder) checks its bag against run_end and exits 6 on a loss.
            self.get_logger().warning(
                f"{', '.join(unacked)}: not acknowledged by every subscriber within "
                f'end_timeout = {self.options.end_timeout:g} s; a subscriber may have lost '
                "messages (a recorder checks its bag against this replay's run_end)")
        return self.exit_code

    def _announce_end(self) -> None:
        """``run_end``: the messages sent on each topic whose delivery is complete (reliable,
        deeper than 1: /clock only at rate 0, where it is keep-all)."""
        published = {self.pubs[n].topic_name: k for n, k in self.sent.items()
                     if self.pubs[n].qos_profile.history == HistoryPolicy.KEEP_ALL
                     or self.pubs[n].qos_profile.depth > 1}
        if self.clock_pub is not None and self.options.rate == 0:
            published[self.clock_pub.topic_name] = self.clock_sent
        self.end_pub.publish(String(data=contract.run_end_text(
            'player', f'played {self.published} of {self.total} messages', EXIT_OK,
            self._last_log * 1e-9, published)))

    def _flush_all(self, pubs: list, executor: Any) -> list[str]:
        """Wait for the acknowledgements of the last messages, then keep the publishers for
        ``end_linger`` s while anything subscribes (a subscriber acknowledges on receipt but
        loses what it has not taken yet when the writer goes away). Returns the reliable
        topics whose subscribers did not acknowledge everything in ``end_timeout``."""
        unacked = []
        for pub in pubs:
            if pub.get_subscription_count() > 0 and rclpy.ok():
                if not pub.wait_for_all_acked(Duration(seconds=self.options.end_timeout)):
                    unacked.append(pub.topic_name)
        deadline = time.monotonic() + self.options.end_linger
        while (rclpy.ok() and STOP.received is None and time.monotonic() < deadline
               and any(pub.get_subscription_count() > 0 for pub in pubs)):
            executor.spin_once(timeout_sec=0.05)
        # run_end too: a recorder that has not taken it yet would lose it with this writer;
        # a recorder leaves once it has it (bounded by end_timeout). A reader the graph lists
        # but that has not matched yet (a recorder started together with the player) is
        # waited for as well: it gets the transient-local run_end once it matches.
        end = getattr(self, 'end_pub', None)
        if end is not None and end in pubs:
            deadline = time.monotonic() + self.options.end_timeout
            while (rclpy.ok() and STOP.received is None and time.monotonic() < deadline
                   and (end.get_subscription_count() > 0
                        or self.count_subscribers(end.topic_name) > 0)):
                executor.spin_once(timeout_sec=0.05)
        return unacked

    # -- commands --------------------------------------------------------------------------
    def _setup_commands(self) -> None:
        name, self.table, bad = command_table(self.scan, self.options.topics)
        self.remaining = sum(len(q) for q in self.table.values())
        self.t_first, self.t_last = min(self.table), max(self.table)
        if bad:
            self.get_logger().warning(f'{bad} recorded command(s) do not fit the contract and '
                                      'are skipped')
        self._pending: list[bytes] = []
        self.states = 0
        self._last_t: float | None = None
        self._used: dict[float, int] = {}
        self._plant_seen = False
        self._wall0 = time.monotonic()
        self.command_pub = self.create_publisher(Float64MultiArray, contract.COMMAND.name,
                                                 profile(contract.COMMAND))
        self.state_sub = self.create_subscription(Float64MultiArray, contract.STATE.name,
                                                  self._on_state, profile(contract.STATE))
        self._matched = SubscriptionGate(self, self.command_pub,
                                         minimum=self.options.min_command_subscribers)
        self._held = HoldReporter(self, self._matched)
        self._setup_verification()
        self._timer = self.create_timer(0.005, self._tick)
        self.get_logger().info(
            f'replaying {self.remaining} commands of {self.options.bag_path} ({name}, t in '
            f'[{self.t_first!r}, {self.t_last!r}] s) in answer to {self.state_sub.topic_name}')

    # -- commands: is the plant the recorded one? ---------------------------------------------
    def _setup_verification(self) -> None:
        """Nothing is sent until the plant's model, parameters, control period and initial
        state are known to equal the bag's (``fohssv.plant_parameters``); a bag without them
        is replayed with a warning."""
        recorded = self.scan.run_metadata().get('fohssv.plant_parameters')
        self._recorded = recorded if isinstance(recorded, dict) else None
        self._verified = self._recorded is None
        self._asked = False
        if self._recorded is None:
            self.get_logger().warning(
                'the bag holds no plant parameters: the plant cannot be checked against the '
                'recording (replaying anyway)')
            return
        self._get_params = self.create_client(GetParameters,
                                              f'/{self.options.plant_node}/get_parameters')

    def _verify(self) -> None:
        if self._asked:
            return
        if not self._get_params.service_is_ready():
            o = self.options
            if time.monotonic() - self._wall0 > o.start_timeout:
                self._fail(EXIT_NO_PEERS, f'start timeout: no parameter services of the '
                           f'plant node /{o.plant_node} after {o.start_timeout:g} s, so it '
                           'cannot be checked against the recording; name it with '
                           '-p plant_node:=NAME (or skip the check with -p force:=true)')
            return
        self._asked = True
        names = list(COMPARED)
        self._get_params.call_async(GetParameters.Request(names=names)).add_done_callback(
            lambda f: self._on_plant_parameters(names, f))

    def _on_plant_parameters(self, names: list[str], future: Any) -> None:
        if self.finished.done():
            return
        result = future.result()
        if result is None or len(result.values) != len(names):
            self._fail(EXIT_ERROR, f'could not read the parameters of /{self.options.plant_node}')
            return
        live = {n: parameter_value_to_python(v) for n, v in zip(names, result.values,
                                                                 strict=True)}
        diffs = compare_plant(self._recorded, live)
        if diffs:
            text = (f'the plant /{self.options.plant_node} does not match the recording: '
                    + '; '.join(diffs))
            if not self.options.force:
                self._fail(EXIT_ERROR, f'{text}; start the plant with the recorded values '
                           '(or replay anyway with -p force:=true)')
                return
            self.get_logger().warning(f'{text}; replaying anyway (force)')
        else:
            self.get_logger().info(f'the plant /{self.options.plant_node} matches the recording '
                                   '(model, parameters, control_period, initial_state)')
        self._verified = True

    def _send(self, raw: bytes) -> None:
        if self._pending or not self._verified or not self._matched():
            self._pending.append(raw)      # published by _tick once verified and matched
            return
        self.command_pub.publish(raw)
        self.published += 1

    def _on_state(self, msg: Float64MultiArray) -> None:
        if self.finished.done():
            return
        try:
            t = contract.decode(contract.STATE, msg.data)[0]
        except contract.ContractError as exc:
            self.get_logger().error(f'ignored a state message: {exc}')
            return
        self.states += 1
        self._last_t = t
        queue = self.table.get(t)
        if not queue:
            if t > self.t_last:
                self._finish(f"the bag's commands end at t={self.t_last!r} s; the plant is at "
                             f't={t!r} s ({self.remaining} recorded command(s) unused)')
                return
            self._fail(EXIT_ERROR,
                       f'no recorded command for the state at t={t!r} s (the bag answers '
                       f'{len(self.table)} distinct times in [{self.t_first!r}, '
                       f'{self.t_last!r}] s); is the plant running with the recorded '
                       'control_period and parameters?')
            return
        # the k-th state at t gets the k-th command recorded for t (a run with a reset has
        # several); a state repeated more often than recorded gets the last one again
        k = self._used.get(t, 0)
        self._used[t] = k + 1
        if k < len(queue):
            self.remaining -= 1
        self._send(queue[min(k, len(queue) - 1)])
        if self.remaining == 0:
            self._finish('every recorded command was replayed')

    def _tick(self) -> None:
        if self.finished.done():
            return
        if not self._verified:
            self._verify()
        if self._pending and self._verified:
            if self._matched():
                pending, self._pending = self._pending, []
                for raw in pending:
                    self.command_pub.publish(raw)
                    self.published += 1
            else:
                self._held.report(len(self._pending))
        plants = self.state_sub.get_publisher_count()
        if plants > 0:
            self._plant_seen = True
        elif self._plant_seen:
            last = 'no state' if self._last_t is None else f'the last state at t={self._last_t!r} s'
            self._finish(f'the plant left ({last})')
        elif time.monotonic() - self._wall0 > self.options.start_timeout:
            self._fail(EXIT_NO_PEERS, f'start timeout: no publisher of '
                       f'{self.state_sub.topic_name} after {self.options.start_timeout:g} s; '
                       'is the plant running in the same ROS_DOMAIN_ID and namespace?')

    # -- end -------------------------------------------------------------------------------
    def _end(self, code: int) -> None:
        if self.finished.done():
            return
        self.exit_code = code
        if self.options.mode == 'commands':
            self.destroy_timer(self._timer)
        self.finished.set_result(code)

    def _finish(self, why: str) -> None:
        self.get_logger().info(f'done: {why}; {self.published} command(s) published for '
                               f'{self.states} state(s)')
        self._end(EXIT_OK)

    def _fail(self, code: int, message: str) -> None:
        self.get_logger().error(message)
        self._end(code)


def _run(node: Player) -> int:
    """Play until the end (republish: then announce run_end, wait for the acknowledgements and
    linger; commands: flush the last commands) or a signal (a final line, no run_end); the
    exit code."""
    executor = make_executor()
    executor.add_node(node)
    republish = node.options.mode == 'republish'
    spin_until(executor, node.finished, paced=node if republish else None)
    if not node.finished.done():          # a signal (STOP) or an external shutdown
        return _on_interrupt(node)
    if not republish:
        node._flush_all([node.command_pub], executor)
    elif node.exit_code == EXIT_OK:
        return node.end_republish(executor)
    return node.exit_code


def _on_interrupt(node: Player) -> int:
    sent = (f'{node.published} of {len(node.order)} messages'
            if node.options.mode == 'republish' else f'{node.published} message(s)')
    final_log('player', f'interrupted after {sent}')
    return node.exit_code


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run fohssv_sim player``; returns the exit code. SIGINT and SIGTERM
    only set STOP (spin.StopSignal): the replay stops between callbacks with a final line and
    the code so far (0); no run_end is announced for an interrupted replay."""
    refuse_early('player', args, PLAYER_PARAMETERS)        # exit 2 before any DDS entity
    return run_node('player', args, Player, _run, specs=PLAYER_PARAMETERS,
                    on_interrupt=_on_interrupt,
                    on_error=error_line('player', (BagError, PlayerError, OSError)))


if __name__ == '__main__':
    sys.exit(main())
