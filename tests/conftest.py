import sys
from pathlib import Path

# tests/ helpers (rosproc) importable from every test module
sys.path.insert(0, str(Path(__file__).parent))


import pytest  # noqa: E402

import rosproc  # noqa: E402


@pytest.fixture(autouse=True)
def _kill_leftover_processes():
    yield
    rosproc.kill_leftovers()
