"""The local Dask cluster of a command that was given no scheduler (``fohssv fit``, ``tune``,
``sweep``, ``report``), made one way; :func:`dask_client` gives the client of either.

Without a dashboard unless asked: the scheduler's HTTP server (health and metrics only) takes
a free port, so a port 8787 already taken on a shared host (another user's cluster or
dashboard) costs nothing and prints no warning. ``dashboard=True`` serves Dask's dashboard on
port 8787 (or the next free one, as Dask says).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

__all__ = ['local_cluster', 'dask_client']


def local_cluster(n_workers: int | None, *, processes: bool = True,
                  dashboard: bool = False) -> Any:
    """A ``dask.distributed.LocalCluster`` of ``n_workers`` single-threaded workers
    (``processes``: worker processes, else threads of this process)."""
    from dask.distributed import LocalCluster

    if dashboard:
        return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=processes)
    return LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=processes,
                        dashboard_address=':0', scheduler_kwargs={'dashboard': False})


@contextlib.contextmanager
def dask_client(scheduler: str | None, n_workers: int | None) -> Iterator[Any]:
    """A ``dask.distributed.Client`` of the scheduler at ``scheduler`` or, without one, of a
    :func:`local_cluster` of ``n_workers`` worker processes; closed on exit (and that
    cluster with it)."""
    from dask.distributed import Client

    if scheduler:
        with Client(scheduler, timeout='20s') as client:
            yield client
        return
    with local_cluster(n_workers) as cluster, Client(cluster) as client:
        yield client
