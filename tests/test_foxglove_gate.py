"""The viewer's front door alone (no ROS): the Foxglove server as the viewer starts it, and
WebSocket clients written here from the protocol (the ``websockets`` package, no part of the
SDK): a client offering only the protocol's published name ``foxglove.websocket.v1`` is
served the same data; browser origins other than the Foxglove and Lichtblick apps and this
machine's pages are refused, as are connections past ``max_clients``; every refusal is one
line naming its reason.
"""

from __future__ import annotations

import contextlib
import json
import socket
import struct
import time

import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from fohssv_sim.params import ParameterError
from fohssv_sim.ros.foxglove_gate import origin_allowed
from fohssv_sim.ros.foxglove_live import TOPICS, LiveServer, Marker, ViewAssembler
from fohssv_sim.ros.viewer_options import ViewerOptions

OLD_NAME = 'foxglove.websocket.v1'


@pytest.fixture
def server():
    refused: list[str] = []
    live = LiveServer('127.0.0.1', 0, max_clients=2,
                      allowed_origins=('https://viz.example.org',), on_refused=refused.append)
    live.refused_lines = refused
    try:
        yield live
    finally:
        live.stop()


def _open(server, subprotocols=(OLD_NAME,), origin=None):
    headers = {} if origin is None else {'Origin': origin}
    return connect(f'ws://127.0.0.1:{server.port}', subprotocols=list(subprotocols),
                   additional_headers=headers, open_timeout=10, compression=None)


def _json(ws, op: str) -> dict:
    while True:
        frame = ws.recv(timeout=10)
        if isinstance(frame, str) and json.loads(frame).get('op') == op:
            return json.loads(frame)


def _view(stamp: int, world: str = 'w', body: str = 'b'):
    a = ViewAssembler()
    a.add_pose(stamp, world, (0.0, 0.0, -0.25), (0.0, 0.0, 0.0, 1.0))
    a.add_twist(stamp, body, (75.0, 0.0, -1.5), (0.0, 0.125, 0.0))
    a.add_wrench(stamp, body, (0.0, 0.0, -3.0), (0.0, 0.0, 0.0))
    for i in (0, 1):
        a.add_marker(stamp, Marker(i, world, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                                   (1.0, 1.0, 1.0), (1.0, 1.0, 1.0, 1.0)))
    return a.take()


@contextlib.contextmanager
def _behind(server):
    """A client subscribed to every channel that reads nothing (a websockets client stops
    reading its socket at 16 unread frames; its receive buffer is 4 kB), sent 6 MB of views
    (frame ids of 10 kB): more than the sockets between the SDK, the gate and the client
    hold, so the gate is left holding frames on both of its sides. Gives the client's
    socket."""
    sock = socket.create_connection(('127.0.0.1', server.port), timeout=10)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    with connect(f'ws://127.0.0.1:{server.port}', sock=sock, subprotocols=[OLD_NAME],
                 open_timeout=10, compression=None) as ws:
        channels = _json(ws, 'advertise')['channels']
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': i, 'channelId': c['id']} for i, c in enumerate(channels, 1)]}))
        deadline = time.monotonic() + 10
        while server.subscriptions < len(TOPICS) and time.monotonic() < deadline:
            time.sleep(0.01)
        view = _view(1_000_000_000, 'w' * 10_000, 'b' * 10_000)
        for _ in range(100):
            server.send(view)
        yield sock
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack('ii', 1, 0))
        sock.close()                  # a reset: no close frame (a killed app, a lost network)


def test_a_client_offering_only_foxglove_websocket_v1_gets_the_run(server):
    with _open(server) as ws:
        assert ws.subprotocol == OLD_NAME
        assert _json(ws, 'serverInfo')['name'] == 'fohssv'
        channels = {c['topic']: c for c in _json(ws, 'advertise')['channels']}
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': 7, 'channelId': channels['/state']['id']}]}))
        view = _view(1_250_000_000)
        for _ in range(200):                  # until the server has taken the subscription
            server.send(view)
            frame = ws.recv(timeout=10)
            if isinstance(frame, bytes) and frame[0] == 1:
                break
        sub, log_time = struct.unpack_from('<IQ', frame, 1)
        state = json.loads(frame[13:])
        # z = -pose.z, w = -twist.linear.z, q = -twist.angular.y (docs/ros.md)
        assert (sub, log_time) == (7, 1_250_000_000)
        assert (state['t'], state['z'], state['w'], state['q']) == (1.25, 0.25, 1.5, -0.125)
    with _open(server, ('foxglove.sdk.v1',)) as ws:
        assert ws.subprotocol == 'foxglove.sdk.v1'
    assert server.refused_lines == []


@pytest.mark.parametrize('origin', [None, 'https://app.foxglove.dev', 'http://localhost:5173',
                                    'http://127.0.0.1:8080', 'https://viz.example.org'])
def test_the_apps_this_machine_and_the_added_origins_are_served(server, origin):
    with _open(server, origin=origin) as ws:
        assert _json(ws, 'serverInfo')['op'] == 'serverInfo'


@pytest.mark.parametrize('kwargs,status,words', [
    ({'origin': 'https://evil.example'}, 403, "Origin 'https://evil.example' is not allowed"),
    ({'origin': 'http://localhost.evil.example'}, 403, 'is not allowed'),
    ({'subprotocols': ('chat',)}, 400, "subprotocols ['chat'] offer neither of "
                                       'foxglove.sdk.v1, foxglove.websocket.v1'),
])
def test_a_refused_handshake_says_why(server, kwargs, status, words):
    with pytest.raises(InvalidStatus) as e:
        _open(server, **kwargs)
    assert e.value.response.status_code == status
    assert words in e.value.response.body.decode()
    (line,) = server.refused_lines
    assert line.startswith('refused a Foxglove client from 127.0.0.1: ') and words in line


def test_connections_past_max_clients_are_refused_until_one_leaves(server):
    with _open(server) as first, _open(server) as second:
        with pytest.raises(InvalidStatus) as e:
            _open(server)
        assert e.value.response.status_code == 503
        assert 'max_clients' in server.refused_lines[0]
        first.close()
        for _ in range(100):                       # the gate notices the close
            try:
                with _open(server) as third:
                    assert _json(third, 'serverInfo')['name'] == 'fohssv'
                break
            except InvalidStatus:
                time.sleep(0.05)
        else:
            pytest.fail('no client was accepted after one left')
        assert _json(second, 'serverInfo')['name'] == 'fohssv'


def test_a_client_gone_while_behind_the_views_frees_its_place_at_once(server):
    """Gone without a close (a killed app, a lost network) while the gate held its frames:
    its place (one of max_clients=2) is free at once. Before, the gate stopped reading the
    SDK's side when the client went, websockets' flow control then never read the close
    frame that ends it, and the place was held for its close_timeout, 10 s."""
    with _behind(server):
        pass
    with _open(server) as first:
        deadline = time.monotonic() + 5
        while True:
            try:
                with _open(server) as second:
                    assert _json(second, 'serverInfo')['name'] == 'fohssv'
                break
            except InvalidStatus as e:
                assert e.response.status_code == 503
                assert time.monotonic() < deadline, 'the gone client still holds its place'
                time.sleep(0.05)
        assert _json(first, 'serverInfo')['name'] == 'fohssv'


def test_the_viewer_stops_at_once_beside_a_client_that_stopped_reading():
    """The viewer's stop closes every connection; a client that stopped reading never
    answers the close (it waits for buffer space the client never frees), so the gate cuts
    it after its grace, 1 s. Before, the stop raised TimeoutError after 10 s."""
    live = LiveServer('127.0.0.1', 0)
    with _behind(live):
        start = time.monotonic()
        live.stop()
        assert time.monotonic() - start < 5


def test_origin_rules():
    assert origin_allowed(None) and origin_allowed('https://APP.foxglove.dev/')
    assert origin_allowed('http://[::1]:3000') and not origin_allowed('null')
    assert not origin_allowed('https://app.foxglove.dev.evil.example')
    assert origin_allowed('https://a.example', ('*',))


def test_the_viewer_options_of_the_gate():
    o = ViewerOptions(allowed_origins=' https://a.example, http://b.example:81 ',
                      max_clients=3)
    assert o.allowed_origins == ('https://a.example', 'http://b.example:81')
    assert o.max_clients == 3 and ViewerOptions().max_clients == 16
    with pytest.raises(ParameterError, match=r"allowed_origins='a.example' .*holds "
                                             r"'a.example', which is no origin"):
        ViewerOptions(allowed_origins='a.example')
    with pytest.raises(ParameterError, match=r'max_clients=0 is outside the allowed range'):
        ViewerOptions(max_clients=0)


def test_a_flood_of_made_up_origins_logs_a_bounded_number_of_lines(server):
    for i in range(130):
        with pytest.raises(InvalidStatus):
            _open(server, origin=f'https://x{i}.example')
    assert len(server.refused_lines) == 100
    assert server.refused_lines[-1].endswith('(HTTP 403; 100 refused so far)')
