"""The ROS interface's generated files and docs stay in sync with the code (no processes)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fohssv_sim.ros import docs

ROOT = Path(__file__).resolve().parents[1]


def test_plant_yaml_is_generated_from_the_tables():
    assert (ROOT / 'src/fohssv_sim/config/plant.yaml').read_text() == docs.plant_yaml()


@pytest.mark.parametrize('name', ['state_feedback', 'lqr', 'fractional_pid', 'scheduled'])
def test_controller_yaml_is_generated_from_the_tables(name):
    path = ROOT / f'src/fohssv_controller/config/{name}.yaml'
    assert path.read_text() == docs.controller_yaml(name)


def test_docs_tables_are_generated_from_the_tables():
    text = (ROOT / 'docs/parameters.md').read_text()
    block = re.search(r'<!-- begin generated tables[^\n]*-->\n(.*)<!-- end generated tables -->',
                      text, re.S)
    assert block is not None
    assert block.group(1) == docs.tables()
