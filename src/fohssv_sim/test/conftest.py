"""Shared fixtures of the package tests."""

import pytest


@pytest.fixture(scope='module')
def dask_cluster():
    """One Dask cluster of threads in the test process for the tests of a module whose
    subject is not the process cluster (the CLIs' own ``--workers N`` clusters are run by
    their tests): no worker process to start, reachable over TCP so that a CLI run as a
    subprocess can be pointed at it with ``--scheduler``. Per module, not per session: idle,
    its scheduler's and worker's periodic callbacks take about 4 % of a core, which a session
    cluster kept taking in every test worker that had once run one of these modules until the
    end of the run; starting one costs 0.04 CPU s."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      protocol='tcp://', host='127.0.0.1', dashboard_address=':0',
                      scheduler_kwargs={'dashboard': False}) as cluster:
        yield cluster


@pytest.fixture
def dask_client(dask_cluster):
    """A client of :func:`dask_cluster` for one test."""
    from dask.distributed import Client

    with Client(dask_cluster) as client:
        yield client
