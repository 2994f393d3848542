"""The in-process node layer (marker ``node``): the plant and controller nodes built in the
test process, each test with a :class:`inprocess.Graph` (rclpy's context on its own domain,
one executor), closed after it. The layers: ``pytest -m "not graph and not node"`` runs the
pure tests, ``-m node`` these, ``-m graph`` the real processes; ``-m "not graph"`` is the
fast inner loop."""

import pytest
from inprocess import Graph


@pytest.fixture
def graph():
    g = Graph()
    try:
        yield g
    finally:
        g.close()
