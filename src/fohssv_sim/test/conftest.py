"""Shared fixtures of the package tests."""

import pytest


@pytest.fixture(scope='session')
def dask_cluster():
    """One Dask cluster of threads in the test process for every test whose subject is not
    the process cluster (the CLIs' own ``--workers N`` clusters are run by their tests):
    no worker process to start, reachable over TCP so that a CLI run as a subprocess can be
    pointed at it with ``--scheduler``."""
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
