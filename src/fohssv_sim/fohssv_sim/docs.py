"""The text writers of the generated docs: Markdown tables (the topic table among them) and
parameter YAML files.

:mod:`fohssv_sim.ros.docs` generates the tables of docs/parameters.md and the nodes' YAML files
with them (a test keeps those equal to them); ``fohssv fit`` and ``fohssv tune`` write their
report tables and parameter files with them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence

from .contract import TOPICS, Topic
from .params import ParameterSpec


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


def yaml_value(value: object) -> str:
    """A YAML scalar/list that both rcl's parser and PyYAML read back with the same type."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        s = repr(value)
        if 'e' in s and '.' not in s:
            s = s.replace('e', '.0e')
        return s
    if isinstance(value, (tuple, list)):
        return '[' + ', '.join(yaml_value(v) for v in value) + ']'
    return f"'{value}'"


def parameters_yaml(header: str, specs: Iterable[ParameterSpec]) -> str:
    """A ``--params-file`` for any node (``/**``) with every row at its default."""
    lines = [f'# {line}' if line else '#' for line in header.splitlines()]
    lines += ['/**:', '  ros__parameters:']
    for s in specs:
        unit = f' [{s.unit}]' if s.unit and s.unit != '-' else ''
        ro = '; read-only while running' if s.needs_reset else ''
        lines.append(f'    # {s.description}{unit}; allowed: {s.range_text()}{ro}')
        lines.append(f'    {s.name}: {yaml_value(s.default)}')
    return '\n'.join(lines) + '\n'
