"""Options of the recorder and the player: one table and one validated options class each.

Pure (no rclpy). :data:`RECORDER_PARAMETERS` and :data:`PLAYER_PARAMETERS` are declared as ROS
parameters by :func:`fohssv_sim.ros.ros_params.declare` (descriptor: description with unit,
``allowed: ...``, ranges, read-only; an override of the wrong type or out of range is refused
in the table's words before rclpy declares it) and documented in ``docs/ros.md`` from the same
rows. :class:`RecorderOptions` and :class:`PlayerOptions` validate the values by the rows and
add the rules a range cannot say, in the same words (``name=value ...; allowed: range unit
(description)``). Every row is read-only: a running recorder or player does not change.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

from .. import contract
from ..bag.writer import DEFAULT_CHUNK_SIZE
from ..closed_loop import default_bag
from ..params import ParameterError, ParameterSpec
from .options import FlagSpec, NamesSpec, TableOptions, TextSpec

__all__ = ['RECORDED', 'PLAYER_MODES', 'RECORDER_PARAMETERS', 'PLAYER_PARAMETERS',
           'RecorderOptions', 'PlayerOptions', 'default_bag_path', 'new_bag_path', 'bag_exists']

#: What the recorder records by default: the contract and the typed views.
RECORDED: tuple[contract.Topic, ...] = contract.TOPICS + contract.VIEW_TOPICS
#: The player's two modes.
PLAYER_MODES = ('republish', 'commands')

_P = ParameterSpec

#: The recorder's parameters.
RECORDER_PARAMETERS: tuple[ParameterSpec, ...] = (
    TextSpec('bag_path', '-', '', '-', "bag directory to create; '' = runs/<UTC timestamp> "
             'under $FOHSSV_ROOT (or the current directory)',
             allowed='a path that does not exist'),
    NamesSpec('topics', '-', tuple(t.name for t in RECORDED), '-', 'topics to record '
              "(relative names resolved in the recorder's namespace)",
              allowed=', '.join(t.name for t in RECORDED) + ' (in any namespace)'),
    TextSpec('plant_node', '-', 'plant', '-', "node whose parameters are stored with the run; "
             "'' or 'none' = no node", allowed='a node name'),
    _P('plant_timeout', '-', 10.0, 's', 'wall time to wait for the plant parameter services',
       low=0.0, low_open=False),
    _P('flush_period', '-', 0.1, 's', 'wall time between flushes: the most a SIGKILL can '
       'lose', low=0.0, high=60.0, high_open=False),
    _P('command_publishers', '-', 0, 'publishers', 'subscribe to state only once the command '
       'subscription has matched this many publishers (a plant waiting for its state '
       'subscribers then cannot start before the recorder hears the controller); 0 = at once',
       low=0.0, low_open=False),
    _P('chunk_size', '-', DEFAULT_CHUNK_SIZE, 'bytes', 'size after which a chunk is written '
       'even between flushes', low=1024.0, low_open=False),
    FlagSpec('stop_at_run_end', '-', True, '-', 'close the bag and exit once the run_end of '
             'the run (plant or player) arrived and every message it lists is in the bag '
             '(exit 6 naming what is missing after end_timeout; exit 7 when a publisher of '
             'the recorded topics left or stayed silent without its run_end)'),
    _P('end_timeout', '-', 10.0, 's', 'wall time without a new message after which the '
       'messages a run_end lists that are not in the bag count as lost, and a drain after a '
       'signal ends (a backlog still being written is waited for)', low=0.0, high=3600.0,
       high_open=False),
    _P('drain_timeout', '-', 10.0, 's', 'wall time a drain after SIGINT/SIGTERM lasts at most '
       'while no run_end was heard: then the bag is closed even while messages still arrive '
       '(a plant paced by this recorder runs on while it is read), with one line saying so; '
       "after a run_end the drain writes the ended run's backlog", low=0.0, high=3600.0,
       high_open=False),
)

#: The player's parameters.
PLAYER_PARAMETERS: tuple[ParameterSpec, ...] = (
    TextSpec('bag_path', '-', '', '-', 'bag to play', required=True,
             allowed='a bag directory (e.g. runs/<run>), its metadata.yaml or its .mcap file'),
    _P('mode', '-', 'republish', '-', "'republish': the bag's topics with /clock at rate; "
       "'commands': answer a fresh plant's states with the recorded commands (open loop)",
       choices=PLAYER_MODES, numeric=False),
    _P('rate', '-', 1.0, '-', 'republish: simulated seconds per wall second (1 = real time); '
       '0 = as fast as the subscribers allow', low=0.0, low_open=False),
    NamesSpec('topics', '-', ('',), '-', "topics to play: recorded names ('/state') or "
              "contract names ('state', any namespace); [''] = every contract topic in the "
              'bag (commands mode: the command topic)', allowed='topic names in the bag'),
    FlagSpec('clock', '-', True, '-', 'republish: publish /clock at every new log time (the '
             'recorded /clock is then not replayed)'),
    _P('min_subscribers', '-', 1, 'subscribers', 'republish: matched subscribers per topic to '
       'wait for before playing', low=0.0, low_open=False),
    _P('min_command_subscribers', '-', 1, 'subscriptions', 'commands: matched subscriptions '
       'of command (the plant, recorders) to wait for before the first command; 2 with a '
       'recorder, so it hears every command', low=1.0, low_open=False),
    _P('start_timeout', '-', 30.0, 's', 'wall time to wait for subscribers (republish; rate 0 '
       'fails without them, rate > 0 starts anyway) or for the plant (commands)', low=0.0,
       low_open=False),
    _P('end_timeout', '-', 5.0, 's', 'wall time to wait for subscribers to acknowledge the '
       'last messages, and for the readers of run_end to leave (a recorder leaves once it '
       'has it)', low=0.0, low_open=False),
    _P('end_linger', '-', 1.0, 's', 'wall time the player keeps its publishers after the '
       'last message while anything subscribes: a reader drops what it has not taken yet '
       'when the writer goes away', low=0.0, low_open=False),
    TextSpec('plant_node', '-', 'plant', '-', 'commands: the plant node whose model, '
             "parameters, control_period and initial_state are compared with the bag's "
             '(through its parameter services) before the first command',
             allowed='a node name'),
    FlagSpec('force', '-', False, '-', 'commands: replay even when the plant does not match '
             'the recording (a warning instead of exit 1)'),
)


class RecorderOptions(TableOptions):
    """The recorder's validated options (:data:`RECORDER_PARAMETERS`).

    Raises:
        ParameterError: a value out of range or of the wrong kind; no topic; a topic that is
            not a contract topic; ``command_publishers`` > 0 with state but not command.
    """

    TABLE = RECORDER_PARAMETERS

    def check(self) -> None:
        topics = self.spec('topics')
        if not self.topics:
            raise topics.refuse(list(self.topics), 'is empty: give at least one topic')
        for name in self.topics:
            if contract.find_topic(name, RECORDED) is None:
                raise topics.refuse(list(self.topics),
                                    f'is not valid: {name!r} is not a contract topic')
        recorded = {topic for _, topic in self.recorded()}
        if (self.command_publishers > 0 and contract.STATE in recorded
                and contract.COMMAND not in recorded):
            raise self.spec('command_publishers').refuse(
                self.command_publishers, 'needs the command topic recorded (it defers state '
                f'until command has that many publishers), and topics={list(self.topics)!r} '
                'has none')

    def recorded(self) -> list[tuple[str, contract.Topic]]:
        """Each topic as given with its contract topic."""
        return [(name, contract.find_topic(name, RECORDED)) for name in self.topics]


class PlayerOptions(TableOptions):
    """The player's validated options (:data:`PLAYER_PARAMETERS`): ``topics`` without empty
    names (none = every contract topic in the bag), ``plant_node`` without slashes.

    Raises:
        ParameterError: a value out of range or of the wrong kind, no ``bag_path``.
    """

    TABLE = PLAYER_PARAMETERS

    def check(self) -> None:
        self._set('topics', tuple(t for t in self.topics if t))
        self._set('plant_node', self.plant_node.strip('/'))


def default_bag_path(now: datetime | None = None) -> Path:
    """``runs/<UTC timestamp>`` under ``$FOHSSV_ROOT`` (or the current directory):
    :func:`fohssv_sim.closed_loop.default_bag`."""
    return default_bag(now)


def new_bag_path(options: RecorderOptions) -> Path:
    """The bag directory the recorder creates: ``bag_path``, or :func:`default_bag_path`.

    Raises:
        ParameterError: it exists already (the recorder never overwrites a bag).
    """
    path = Path(options.bag_path) if options.bag_path else default_bag_path()
    if path.exists():
        raise bag_exists(options, path)
    return path


def bag_exists(options: RecorderOptions, path: Path) -> ParameterError:
    """The refusal of a ``bag_path`` that exists (exit 2 from the node)."""
    return options.spec('bag_path').refuse(
        str(path), 'exists already: the recorder never overwrites a bag')
