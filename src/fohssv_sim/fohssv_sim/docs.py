"""Markdown tables generated from the parameter and topic tables (README and docs/).

``python -m fohssv_sim.docs`` prints them; a test checks that README.md holds them verbatim,
so the README cannot drift from the code.
"""

from __future__ import annotations

from .contract import TOPICS, VIEW_TOPICS
from .params import PARAMETERS, ParameterSpec


def _row(spec: ParameterSpec) -> str:
    default = spec.default if isinstance(spec.default, str) else f'{spec.default:g}'
    ref = f' ({spec.reference})' if spec.reference else ''
    return (f'| `{spec.name}` | {spec.symbol} | `{default}` | {spec.unit} | '
            f"{spec.range_text().replace(' | ', ' / ')} | {spec.description}{ref} |")


def parameter_table() -> str:
    """The model parameter table (params.PARAMETERS) as Markdown."""
    head = ('| parameter | symbol | default | unit | allowed | meaning |\n'
            '|---|---|---|---|---|---|')
    return head + '\n' + '\n'.join(_row(s) for s in PARAMETERS)


def topic_table(topics=TOPICS) -> str:
    """The topic contract (contract.TOPICS) as Markdown."""
    head = '| topic | type | data | units | QoS | meaning |\n|---|---|---|---|---|---|'
    rows = [f'| `{t.name}` | `{t.type}` | [{", ".join(t.fields)}] | {", ".join(t.units)} | '
            f'{t.qos} | {t.description} |' for t in topics]
    return head + '\n' + '\n'.join(rows)


def view_table() -> str:
    """The typed views (contract.VIEW_TOPICS) as Markdown."""
    return topic_table(VIEW_TOPICS)


if __name__ == '__main__':
    print(parameter_table())
    print()
    print(topic_table())
    print()
    print(view_table())
