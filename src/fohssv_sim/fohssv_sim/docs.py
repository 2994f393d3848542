"""Markdown tables generated from the parameter and topic tables (README and docs/).

``python -m fohssv_sim.docs`` prints them; a test checks that README.md holds them verbatim,
so the README cannot drift from the code.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

from .contract import TOPICS, VIEW_TOPICS, Topic
from .params import PARAMETERS, ParameterSpec


def markdown_table(columns: Sequence[str], rows: Iterable[Sequence[str]]) -> str:
    """A Markdown table (no trailing newline): the one table writer of the generated docs
    (README here, docs/ros.md in :mod:`fohssv_sim.ros.docs`)."""
    lines = ['| ' + ' | '.join(columns) + ' |', '|' + '---|' * len(columns)]
    lines += ['| ' + ' | '.join(row) + ' |' for row in rows]
    return '\n'.join(lines)


def _row(spec: ParameterSpec) -> tuple[str, ...]:
    default = spec.default if isinstance(spec.default, str) else f'{spec.default:g}'
    ref = f' ({spec.reference})' if spec.reference else ''
    return (f'`{spec.name}`', spec.symbol, f'`{default}`', spec.unit,
            spec.range_text().replace(' | ', ' / '), f'{spec.description}{ref}')


def parameter_table() -> str:
    """The model parameter table (params.PARAMETERS) as Markdown."""
    return markdown_table(('parameter', 'symbol', 'default', 'unit', 'allowed', 'meaning'),
                          (_row(s) for s in PARAMETERS))


def topic_table(topics: Sequence[Topic] = TOPICS, qos: Callable[[Topic], str] | None = None,
                last: str = 'meaning') -> str:
    """The topic contract (contract.TOPICS) as Markdown; ``qos(topic)`` writes the QoS cell
    (default: the profile's name), ``last`` names the description column."""
    return markdown_table(
        ('topic', 'type', 'data', 'units', 'QoS', last),
        ((f'`{t.name}`', f'`{t.type}`', f'[{", ".join(t.fields)}]', ', '.join(t.units),
          qos(t) if qos else t.qos, t.description) for t in topics))


def view_table() -> str:
    """The typed views (contract.VIEW_TOPICS) as Markdown."""
    return topic_table(VIEW_TOPICS)


if __name__ == '__main__':
    print(parameter_table())
    print()
    print(topic_table())
    print()
    print(view_table())
