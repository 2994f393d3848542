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


# The files whose longest test is among the suite's slowest (`--durations=0` of a full run on
# four workers: each of them about 5 s or more), longest first. The workers of `make test` (--dist
# worksteal) take the tests in collection order and steal from each other's end: a long test
# collected last leaves the other workers idle while one runs it. Whole files move (in their
# own order), so a module fixture is built once per worker, as before.
SLOW_FILES_FIRST = (
    'src/fohssv_sim/test/test_fit_filter.py',
    'tests/test_graph_env_ros.py',
    'tests/test_launch.py',
    'tests/test_graph_tune.py',
    'tests/test_graph_run_end.py',
    'tests/test_player.py',
    'tests/test_record_process.py',
    'tests/test_graph_bad_input.py',
    'tests/test_graph_publish_failure.py',
    'tests/test_graph_controller_package.py',
    'tests/test_graph_viewer.py',
    'tests/test_recorder_drain.py',
    'tests/test_readme.py',
    'tests/test_fit.py',
    'tests/test_graph_startup.py',
    'tests/test_graph_inplant_record.py',
    'tests/test_record_plot.py',
    'tests/test_graph_realtime.py',
    'tests/test_graph_hosted.py',
    'tests/test_graph_command_stall.py',
    'tests/node/test_plant_start.py',
    'tests/test_graph_full_disk.py',
    'src/fohssv_sim/test/test_continuation_cli.py',
    'tests/test_graph_recorder_sources.py',
    'tests/test_graph_plugin_faults.py',
    'src/fohssv_sim/test/test_chunks_workers_lost.py',
    'tests/node/test_plant_realtime.py',
    'src/fohssv_sim/test/test_inplant_ring.py',
    'src/fohssv_sim/test/test_gainmap.py',
    'tests/test_example_fft.py',
)


def pytest_collection_modifyitems(config, items):
    """The files of :data:`SLOW_FILES_FIRST` first, in that order; the rest as collected."""
    rank = {path: i for i, path in enumerate(SLOW_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split('::')[0], len(rank)))


def pytest_sessionstart(session):
    _clean_shared_memory(session, 'before')


def pytest_sessionfinish(session, exitstatus):
    _clean_shared_memory(session, 'after')
