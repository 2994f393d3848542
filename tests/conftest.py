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


def pytest_sessionfinish(session, exitstatus):
    """Once per run (the xdist controller, or a run without workers): the shared-memory files
    of the nodes the tests killed (:func:`rosproc.clean_shared_memory`)."""
    if hasattr(session.config, 'workerinput'):
        return
    printed = rosproc.clean_shared_memory()
    if printed:
        lines = [ln.strip() for ln in printed.splitlines() if ln.strip()]
        print('\nFast DDS shared memory after the run: ' + '; '.join(lines[1:]))
