"""The test helpers' own rules (no processes): the ROS domains a run may use."""

from __future__ import annotations

import pytest

import rosproc


@pytest.mark.parametrize(('text', 'expected'), [
    ('1-200', (1, 200)), ('101-150', (101, 150)), (' 7 - 7 ', (7, 7)), ('0-232', (0, 232))])
def test_a_domain_range_is_read_inclusive(text, expected):
    assert rosproc.domain_range(text) == expected


@pytest.mark.parametrize('text', ['150-101', '1-233', '-1-5', 'a-b', '5', '1-2-3', ''])
def test_a_bad_domain_range_is_named_with_what_is_allowed(text):
    with pytest.raises(ValueError) as exc:
        rosproc.domain_range(text)
    assert str(exc.value) == (f'FOHSSV_TEST_DOMAINS={text!r} is not a range LO-HI of ROS '
                              'domain ids with 0 <= LO <= HI <= 232 (e.g. 1-200)')


@pytest.mark.parametrize(('lo', 'hi', 'workers'), [(1, 200, 2), (101, 110, 3), (40, 41, 2)])
def test_workers_of_one_run_take_disjoint_domains_inside_the_range(monkeypatch, lo, hi, workers):
    """Each worker of an xdist run cycles through its own residue class of the range: no
    domain is given to two workers, every one is inside [lo, hi], and consecutive tests of a
    worker get different domains while the range holds more than one per worker."""
    monkeypatch.setenv(rosproc.DOMAINS_VAR, f'{lo}-{hi}')
    monkeypatch.setenv('PYTEST_XDIST_TESTRUNUID', 'one-run')
    monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', str(workers))
    taken = []
    for k in range(workers):
        monkeypatch.setenv('PYTEST_XDIST_WORKER', f'gw{k}')
        taken.append([rosproc.unique_domain_id() for _ in range(3)])
    flat = {d for ids in taken for d in ids}
    assert all(lo <= d <= hi for d in flat)
    assert all(not set(a) & set(b) for i, a in enumerate(taken) for b in taken[i + 1:])
    per_worker = (hi - lo + 1) // workers
    assert all(len(set(ids)) == min(3, per_worker) for ids in taken)


def test_a_range_narrower_than_the_workers_is_refused(monkeypatch):
    monkeypatch.setenv(rosproc.DOMAINS_VAR, '5-6')
    monkeypatch.setenv('PYTEST_XDIST_WORKER', 'gw0')
    monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', '3')
    with pytest.raises(ValueError, match=r'FOHSSV_TEST_DOMAINS=5-6 holds 2 domain\(s\), fewer '
                       r'than the 3 pytest-xdist workers'):
        rosproc.unique_domain_id()
