"""The one Markdown table writer of the generated docs, and the topic table it writes.

:mod:`fohssv_sim.ros.docs` generates the tables of docs/parameters.md with it (a test keeps
that page equal to them); ``fohssv fit`` writes its report tables with it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

from .contract import TOPICS, Topic


def markdown_table(columns: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A Markdown table (no trailing newline)."""
    lines = ['| ' + ' | '.join(columns) + ' |', '|' + '---|' * len(columns)]
    lines += ['| ' + ' | '.join(row) + ' |' for row in rows]
    return '\n'.join(lines)


def topic_table(topics: Sequence[Topic] = TOPICS, qos: Callable[[Topic], str] | None = None,
                last: str = 'meaning') -> str:
    """The topic contract (contract.TOPICS) as Markdown; ``qos(topic)`` writes the QoS cell
    (default: the profile's name), ``last`` names the description column."""
    return markdown_table(
        ('topic', 'type', 'data', 'units', 'QoS', last),
        ((f'`{t.name}`', f'`{t.type}`', f'[{", ".join(t.fields)}]', ', '.join(t.units),
          qos(t) if qos else t.qos, t.description) for t in topics))
