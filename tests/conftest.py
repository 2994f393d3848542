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


def _clean_shared_memory(session, when: str) -> None:
    """Once per run (the xdist controller, or a run without workers): the shared-memory files
    of nodes killed before (a run that was itself killed never reached its end) and of those
    the tests killed (:func:`rosproc.clean_shared_memory`)."""
    if hasattr(session.config, 'workerinput'):
        return
    try:
        printed = rosproc.clean_shared_memory()
    except Exception as exc:  # noqa: BLE001 - e.g. another user's files: say so, run the tests
        print(f'\nFast DDS shared memory {when} the run: not cleaned ({exc!r})')
        return
    if printed:
        lines = [ln.strip() for ln in printed.splitlines() if ln.strip()]
        print(f'\nFast DDS shared memory {when} the run: ' + '; '.join(lines[1:]))


def pytest_configure(config):
    """A bad ``FOHSSV_TEST_DOMAINS`` stops the run at once, in one line, not in every test."""
    try:
        rosproc.domain_range()
    except ValueError as exc:
        raise pytest.UsageError(str(exc)) from None


def pytest_sessionstart(session):
    _clean_shared_memory(session, 'before')


def pytest_sessionfinish(session, exitstatus):
    _clean_shared_memory(session, 'after')
