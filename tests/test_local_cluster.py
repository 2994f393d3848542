"""The local Dask cluster that fit, tune, sweep and report start when given no scheduler:
beside a taken port 8787 (a shared host) it says nothing and serves no dashboard."""

from __future__ import annotations

import pytest


def test_a_local_cluster_beside_a_taken_port_8787_says_nothing(recwarn):
    """What fit, tune, sweep and report start when given no scheduler: with port 8787 taken
    (here by this test), no warning, and no dashboard."""
    import socket
    import urllib.error
    import urllib.request
    import warnings

    from dask.distributed import Client

    from fohssv_sim.analysis.cluster import local_cluster

    taken = socket.socket()
    try:
        try:
            taken.bind(('0.0.0.0', 8787))
            taken.listen()
        except OSError:
            pass                    # taken already: the case itself
        with warnings.catch_warnings():
            warnings.simplefilter('error')
            cluster = local_cluster(1, processes=False)
        with cluster, Client(cluster) as client:
            assert client.submit(sum, [1, 2]).result() == 3
            port = cluster.scheduler.http_server.port
            assert port != 8787
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(f'http://127.0.0.1:{port}/status', timeout=10)
            assert e.value.code == 404                  # no dashboard
    finally:
        taken.close()
