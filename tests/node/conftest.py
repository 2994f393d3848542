"""The in-process node layer: each test gets a :class:`inprocess.Graph` (its own context,
domain and executor), closed after it."""

import pytest
from inprocess import Graph


@pytest.fixture
def graph():
    g = Graph()
    try:
        yield g
    finally:
        g.close()
