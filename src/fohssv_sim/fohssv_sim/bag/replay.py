"""What the player replays, decided from a scanned bag: pure (no rclpy).

* :func:`select_tracks`: the contract topics to republish and their messages in recorded
  order;
* :func:`pacing_schedule`: when each of them is due at a replay rate;
* :func:`replay_timeline`: the same for messages of several topics in recorded order, with
  the monotonic ``/clock`` to publish before each;
* :func:`command_table`: the recorded commands by the state time they answer (open-loop
  replay);
* :func:`compare_plant`: the differences between the plant parameters a bag recorded and a
  live plant's.

The ROS side (publishers, the plant's parameter services, timers) is
:mod:`fohssv_sim.ros.player_node`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from .. import contract
from ..params import PARAMETERS, ModelParameters, ParameterError
from .writer import typestore

__all__ = ['PlayerError', 'Track', 'select_tracks', 'choose_tracks', 'pacing_schedule',
           'replay_timeline', 'timeline',
           'command_table',
           'compare_plant', 'COMPARED']


class PlayerError(Exception):
    """A bag that cannot be played as asked (the message says why); exit code 1."""


@dataclass
class Track:
    """One recorded topic to play: its name, contract topic and (log ns, CDR) messages."""

    name: str
    topic: contract.Topic
    messages: list[tuple[int, bytes]] = field(default_factory=list)


def _basename(name: str) -> str:
    return name.rstrip('/').rsplit('/', 1)[-1]


def select_tracks(sc: Any, wanted: list[str]) -> tuple[list[Track], list[tuple[str, int, bytes]]]:
    """The bag's channels to play (:func:`choose_tracks`) and its messages kept by ``sc`` in
    recorded order.

    Returns:
        (tracks, [(track name, log ns, cdr)] in file order).

    Raises:
        PlayerError: a wanted topic is not in the bag or not a contract topic.
    """
    by_name = {tr.name: tr for tr in choose_tracks(sc, wanted)}
    names = {c.id: c.topic for c in sc.channels.values() if c.topic in by_name}
    order: list[tuple[str, int, bytes]] = []
    for cid, log, raw in sc.messages:
        name = names.get(cid)
        if name is not None:
            by_name[name].messages.append((log, raw))
            order.append((name, log, raw))
    return list(by_name.values()), order


def choose_tracks(sc: Any, wanted: list[str]) -> list[Track]:
    """The bag's channels to play (no messages: those are the player's to read).

    ``wanted``: recorded names (``/state``) or contract names (``state``, matching the topic
    in any namespace); empty = every contract topic in the bag.

    Raises:
        PlayerError: a wanted topic is not in the bag or not a contract topic.
    """
    by_name: dict[str, Track] = {}
    for chan in sc.channels.values():
        topic = contract.find_topic(chan.topic)
        if topic is None or chan.msgtype != topic.type:
            continue
        by_name.setdefault(chan.topic, Track(chan.topic, topic))
    if wanted:
        chosen: dict[str, Track] = {}
        for w in wanted:
            hits = [n for n in by_name if n == w or (not w.startswith('/')
                                                     and _basename(n) == w)]
            if not hits:
                have = ', '.join(sorted(by_name)) or 'none'
                raise PlayerError(f'{sc.files.directory}: topic {w!r} is not in the bag '
                                  f'(contract topics recorded: {have})')
            for n in hits:
                chosen[n] = by_name[n]
        by_name = chosen
    return list(by_name.values())


def command_table(sc: Any, wanted: list[str]) -> tuple[str, dict[float, list[bytes]], int]:
    """The recorded commands by their ``data[0]`` (the exact double of the state they answer).

    Returns:
        (recorded topic name, {t: CDR bytes in recorded order}, messages rejected).

    Raises:
        PlayerError: no command topic, several, or no valid command in it.
    """
    tracks, _ = select_tracks(sc, wanted or [contract.COMMAND.name])
    tracks = [tr for tr in tracks if tr.topic is contract.COMMAND]
    where = sc.files.directory
    if not tracks:
        raise PlayerError(f'{where}: no command topic in the bag; nothing to replay')
    if len(tracks) > 1:
        raise PlayerError(f'{where}: several command topics {[t.name for t in tracks]}; '
                          'name one in the topics parameter')
    ts = typestore()
    table: dict[float, list[bytes]] = {}
    bad = 0
    for _, raw in tracks[0].messages:
        try:
            t = contract.decode(contract.COMMAND, ts.deserialize_cdr(raw, contract.FLOAT64_ARRAY)
                                .data)[0]
        except (contract.ContractError, ValueError, IndexError, TypeError):
            bad += 1
            continue
        table.setdefault(t, []).append(raw)
    if not table:
        raise PlayerError(f'{where}: {tracks[0].name} holds no valid command '
                          f'({len(tracks[0].messages)} messages, {bad} rejected)')
    return tracks[0].name, table, bad


#: Plant parameters the commands mode compares with the bag's: the model table, the control
#: period and the initial state (what decides the trajectory the recorded commands answer).
COMPARED = (*(p.name for p in PARAMETERS), 'control_period', 'initial_state')


def compare_plant(recorded: dict[str, Any], live: dict[str, Any]) -> list[str]:
    """Differences between the plant parameters recorded in a bag and a live plant's, as
    ``'name: recorded X, plant Y'``. Model parameters are compared after resolution (``step:
    auto`` equals the model's default step); names the bag lacks are not compared."""
    names = [p.name for p in PARAMETERS if p.name in recorded]
    try:
        a = ModelParameters.from_dict({n: recorded[n] for n in names}).to_dict()
        b = ModelParameters.from_dict({n: live[n] for n in names if n in live}).to_dict()
        names = [n for n in a if n in recorded]
    except (ParameterError, TypeError, ValueError):
        a, b = recorded, live
    diffs = [f'{n}: recorded {a.get(n)!r}, plant {b.get(n)!r}' for n in names
             if a.get(n) != b.get(n)]
    for n in ('control_period', 'initial_state'):
        if n not in recorded:
            continue
        r, v = recorded[n], live.get(n)
        if isinstance(r, (list, tuple)) or hasattr(r, 'tolist'):
            r = [float(x) for x in r]
        if isinstance(v, (list, tuple)) or hasattr(v, 'tolist'):
            v = [float(x) for x in v]
        if r != v:
            diffs.append(f'{n}: recorded {r!r}, plant {v!r}')
    return diffs


def pacing_schedule(logs: list[int], rate: float) -> list[float]:
    """Wall seconds after the start at which each message (log times ``logs``, ns, in
    recorded order) is due at ``rate`` simulated seconds per wall second: the log time's
    forward steps, scaled (a reset in the run, a step back, is played at once). ``rate`` 0:
    everything due at once (as fast as the subscribers allow)."""
    due = 0.0
    out = []
    last: int | None = None
    for log in logs:
        if last is not None and log > last and rate > 0:
            due += (log - last) * 1e-9 / rate
        out.append(due)
        last = log
    return out


def replay_timeline(order: list[tuple[str, int, bytes]] | list[tuple[str, int]], rate: float
                    ) -> tuple[list[float], list[int | None]]:
    """:func:`timeline` of a list, as two lists (dues, clocks)."""
    dues: list[float] = []
    clocks: list[int | None] = []
    for _, due, clock in timeline(order, rate):
        dues.append(due)
        clocks.append(clock)
    return dues, clocks


def timeline(order: Iterable[tuple], rate: float) -> Iterator[tuple[tuple, float, int | None]]:
    """For each message of ``order`` ((topic, log ns, ...) in recorded order, read as it
    comes: a bag of any length): the message, when it is due at ``rate`` (wall seconds after
    the first), and the ``/clock`` (ns) to publish before it (None: no new clock).

    A recorder writes in arrival order: the command answering t_n often arrives after the
    state t_(n+1), so the log times of the whole file step back thousands of times a second
    although each topic's own times only go forward. Time here is the high-water mark of the
    log times: ``/clock`` never steps back, and the pacing counts each simulated interval
    once (with :func:`pacing_schedule` on the interleaved times, the steps back and forth are
    counted again and again, and a replay at rate 1 ran at a fraction of real time). Only a
    topic whose own time goes back (the run was reset: the live plant's ``/clock`` went back
    too) starts a new epoch: the mark restarts from that time, and messages of the old epoch
    still in flight neither move the clock nor the pacing.
    """
    last: dict[str, int] = {}      # per topic: log time of its previous message
    epoch: dict[str, int] = {}     # per topic: resets it has seen
    current = 0                    # the newest epoch
    mark: int | None = None        # high-water mark of the log times in the newest epoch
    due = 0.0
    for item in order:
        name, log = item[0], item[1]
        prev = last.get(name)
        e = epoch.get(name, 0)
        if prev is not None and log < prev:
            e += 1                 # this topic went back in time: a reset
            epoch[name] = e
        last[name] = log
        clock = None
        if e > current:
            current = e
            mark = log
            clock = log
        elif e == current and (mark is None or log > mark):
            if mark is not None and rate > 0:
                due += (log - mark) * 1e-9 / rate
            mark = log
            clock = log
        yield item, due, clock
