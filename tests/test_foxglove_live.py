"""The viewer's Foxglove side alone (no ROS): the SDK's real WebSocket server on a free port
of the loopback, a real client speaking the protocol (tests/foxglove_client.py), and views
made from a known sample with the formulas of docs/ros.md (not with the viewer's code). What
the client decodes must be those numbers; the options refuse bad values in the table's words.
"""

from __future__ import annotations

import json
import math
import socket
import time

import pytest
from foxglove_client import SUBPROTOCOL, FoxgloveClient

from fohssv_sim import contract
from fohssv_sim.params import ParameterError
from fohssv_sim.ros.foxglove_live import ENTITY_IDS, TOPICS, LiveServer, Marker, ViewAssembler
from fohssv_sim.ros.viewer_options import ViewerOptions, is_loopback

#: A sample [t, z, w, theta, q] and Fp (the plant's model signs), V = 75 m/s.
T, Z, W, THETA, Q, FP, V = 0.37, 0.0452, 1.67, 0.02227, -0.31, 12.75, 75.0
L, R, CAV_L, CAV_R = 1.8, 0.0508, 2.3302, 0.1013
STAMP = round(T * 1e9)

SCHEMAS = {'/vehicle_marker': ('foxglove.SceneUpdate', 'protobuf'),
           '/tf': ('foxglove.FrameTransform', 'protobuf'),
           '/pose': ('foxglove.PoseInFrame', 'protobuf'),
           '/twist': ('fohssv.TwistStamped', 'json'),
           '/planing_wrench': ('fohssv.WrenchStamped', 'json'),
           '/state': ('fohssv.State', 'json'),
           '/planing_force': ('fohssv.PlaningForce', 'json')}


def _feed(assembler: ViewAssembler, stamp: int = STAMP, theta: float = THETA) -> None:
    """The five messages of one view, as docs/ros.md defines them, in a shuffled order."""
    qy, qw = -math.sin(theta / 2), math.cos(theta / 2)
    world, body = contract.VIEW_WORLD_FRAME, contract.VIEW_BODY_FRAME
    assembler.add_marker(stamp, Marker(1, world, (-CAV_L / 2, 0.0, -Z), (0.0, 0.0, 0.0, 1.0),
                                       (CAV_L, 2 * CAV_R, 2 * CAV_R), (0.3, 0.65, 1.0, 0.25)))
    assembler.add_wrench(stamp, body, (0.0, 0.0, -FP), (0.0, 0.0, 0.0))
    assembler.add_pose(stamp, world, (0.0, 0.0, -Z), (0.0, qy, 0.0, qw))
    assembler.add_marker(stamp, Marker(7, world, (9.0, 9.0, 9.0), (0.0, 0.0, 0.0, 1.0),
                                       (1.0, 1.0, 1.0), (1.0, 0.0, 0.0, 1.0)))   # not ours
    assembler.add_twist(stamp, body, (V, 0.0, -W), (0.0, -Q, 0.0))
    body_x, body_z = -L / 2 * math.cos(theta), -Z - L / 2 * math.sin(theta)
    assembler.add_marker(stamp, Marker(0, world, (body_x, 0.0, body_z), (0.0, qy, 0.0, qw),
                                       (L, 2 * R, 2 * R), (0.55, 0.57, 0.6, 1.0)))


def test_assembler_gives_the_newest_complete_view_once():
    a = ViewAssembler(keep=3)
    assert a.take() is None
    a.add_pose(1, 'w', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))    # never completed
    _feed(a)
    view = a.take()
    assert view is not None and view.stamp == STAMP and a.take() is None
    assert [m.ident for m in view.markers] == [0, 1]              # the foreign id 7 ignored
    t, z, w, theta, q = view.state()
    assert (t, z, w, q) == (STAMP / 1e9, Z, W, Q)                 # exact negations
    assert theta == pytest.approx(THETA, rel=1e-14, abs=1e-16)
    assert view.planing_force() == (STAMP / 1e9, FP)
    # two views before a take: the newer one only (the decimation)
    _feed(a, STAMP + 10_000_000)
    _feed(a, STAMP + 20_000_000)
    assert a.take().stamp == STAMP + 20_000_000 and a.take() is None
    assert (a.complete, a.taken) == (3, 2)
    # incomplete views are bounded: the oldest partial is dropped
    for s in range(10):
        a.add_twist(100 + s, 'b', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert len(a._partial) == 3


def test_assembler_completes_a_backlog_taken_topic_by_topic():
    """A viewer behind the run takes each topic's queued messages together: 31 views' poses,
    then their twists, wrenches and markers. Holding as many incomplete views as that backlog
    assembles all 31; holding 8 (the viewer's old setting) assembles none: each topic's turn
    evicts the partial views the previous topics left."""
    def backlog(a):
        stamps = [STAMP + k * 10_000_000 for k in range(31)]
        for s in stamps:
            a.add_pose(s, 'w', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
        for s in stamps:
            a.add_twist(s, 'b', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        for s in stamps:
            a.add_wrench(s, 'b', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        for ident in ENTITY_IDS:
            for s in stamps:
                a.add_marker(s, Marker(ident, 'w', (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                                       (1.0, 1.0, 1.0), (1.0, 1.0, 1.0, 1.0)))
        return a

    deep = backlog(ViewAssembler(keep=100))
    assert deep.complete == 31 and deep.take().stamp == STAMP + 300_000_000
    assert backlog(ViewAssembler(keep=8)).complete == 0


@pytest.fixture
def served():
    server = LiveServer('127.0.0.1', 0)
    client = FoxgloveClient(f'ws://127.0.0.1:{server.port}')
    try:
        yield server, client
    finally:
        client.close()
        server.stop()


def test_the_client_gets_every_channel_with_its_schema_and_the_view_values(served):
    server, client = served
    assert client.subprotocol == SUBPROTOCOL
    client.wait(lambda: len(client.channels) == len(TOPICS), 10, 'the advertised channels')
    info = client.texts[0]
    assert info['op'] == 'serverInfo' and info['name'] == 'fohssv'
    assert 'time' in info['capabilities']
    chans = client.by_topic()
    assert {t: (c['schemaName'], c['encoding']) for t, c in chans.items()} == SCHEMAS
    for c in chans.values():
        assert c['schemaEncoding'] == ('jsonschema' if c['encoding'] == 'json' else 'protobuf')
    client.subscribe(chans)
    client.wait(lambda: server.subscriptions == len(TOPICS), 10, 'the server to count them')
    a = ViewAssembler()
    _feed(a)
    server.send(a.take())     # once: the SDK tells the server of a subscription it has taken
    # the time goes on the SDK's control queue, the messages on its data queue: it may come
    # after them
    topics = set(TOPICS.values())
    client.wait(lambda: {r.topic for r in client.received} == topics and client.times,
                10, 'the view on every topic and its time')
    assert [r.log_time for r in client.received] == [STAMP] * len(TOPICS)
    assert client.times == [STAMP]
    got = {r.topic: r for r in client.received}

    (body, cavity) = got['/vehicle_marker'].message.entities
    assert (body.id, cavity.id) == ('body', 'cavity')
    assert body.frame_id == cavity.frame_id == contract.VIEW_WORLD_FRAME
    assert (body.timestamp.seconds, body.timestamp.nanos) == divmod(STAMP, 1_000_000_000)
    (sphere,) = body.spheres
    assert (sphere.size.x, sphere.size.y, sphere.size.z) == (L, 2 * R, 2 * R)
    o = sphere.pose.orientation
    assert (o.x, o.y, o.z, o.w) == (0.0, -math.sin(THETA / 2), 0.0, math.cos(THETA / 2))
    p = sphere.pose.position
    assert (p.x, p.z) == (-L / 2 * math.cos(THETA), -Z - L / 2 * math.sin(THETA))
    (csphere,) = cavity.spheres
    assert (csphere.size.x, csphere.size.y) == (CAV_L, 2 * CAV_R)
    assert (csphere.pose.position.x, csphere.pose.position.z) == (-CAV_L / 2, -Z)
    assert csphere.color.a == 0.25

    tf = got['/tf'].message
    assert (tf.parent_frame_id, tf.child_frame_id) == (contract.VIEW_WORLD_FRAME,
                                                       contract.VIEW_BODY_FRAME)
    assert (tf.translation.x, tf.translation.y, tf.translation.z) == (0.0, 0.0, -Z)
    assert (tf.rotation.y, tf.rotation.w) == (-math.sin(THETA / 2), math.cos(THETA / 2))
    pose = got['/pose'].message
    assert pose.frame_id == contract.VIEW_WORLD_FRAME and pose.pose.position.z == -Z

    state = got['/state'].message
    assert (state['t'], state['z'], state['w'], state['q']) == (STAMP / 1e9, Z, W, Q)
    assert state['theta'] == pytest.approx(THETA, rel=1e-14)
    assert state['data'] == [state[k] for k in ('t', 'z', 'w', 'theta', 'q')]
    force = got['/planing_force'].message
    assert force == {'t': STAMP / 1e9, 'Fp': FP, 'data': [STAMP / 1e9, FP]}
    twist = got['/twist'].message
    assert twist['twist'] == {'linear': {'x': V, 'y': 0.0, 'z': -W},
                              'angular': {'x': 0.0, 'y': -Q, 'z': 0.0}}
    assert twist['header'] == {'stamp': dict(zip(('sec', 'nanosec'),
                                                 divmod(STAMP, 1_000_000_000))),
                               'frame_id': contract.VIEW_BODY_FRAME}
    assert got['/planing_wrench'].message['wrench']['force'] == {'x': 0.0, 'y': 0.0, 'z': -FP}
    # the JSON Schemas name every field the JSON messages carry
    for topic in ('/state', '/planing_force', '/twist', '/planing_wrench'):
        schema = json.loads(chans[topic]['schema'])
        assert set(schema['properties']) == set(got[topic].message), topic


def test_a_reset_starts_a_new_session(served):
    server, client = served
    client.wait(lambda: len(client.channels) == len(TOPICS), 10, 'the advertised channels')
    client.subscribe(['/state'])
    client.wait(lambda: server.subscriptions == 1, 10, 'the server to count it')
    a = ViewAssembler()
    _feed(a)
    server.send(a.take())
    client.wait(lambda: client.received, 10, 'a view')
    _feed(a, stamp=0)
    server.send(a.take())                          # back to t = 0: the plant was reset
    infos = lambda: [m for m in client.texts if m['op'] == 'serverInfo']   # noqa: E731
    client.wait(lambda: len(infos()) == 2, 10, 'a second serverInfo')
    assert infos()[0]['sessionId'] != infos()[1]['sessionId'] and server.sessions == 2
    client.close()                                 # a client that leaves is not counted
    deadline = time.monotonic() + 10
    while server.subscriptions and time.monotonic() < deadline:
        time.sleep(0.02)
    assert server.subscriptions == 0


def _outward_address() -> str | None:
    """An address of this machine that is not loopback (None if it has none)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(('192.0.2.1', 9))              # TEST-NET-1: nothing is sent
            addr = s.getsockname()[0]
        except OSError:
            return None
    return None if is_loopback(addr) else addr


def test_the_default_host_serves_the_loopback_only():
    options = ViewerOptions()
    assert options.host == '127.0.0.1' and options.loopback and options.port == 8765
    outward = _outward_address()
    if outward is None:
        pytest.skip('this machine has no non-loopback address')
    server = LiveServer(options.host, 0)
    try:
        with pytest.raises(OSError):
            socket.create_connection((outward, server.port), timeout=2).close()
        socket.create_connection(('127.0.0.1', server.port), timeout=2).close()
    finally:
        server.stop()


def test_a_port_in_use_is_an_os_error_naming_it():
    first = LiveServer('127.0.0.1', 0)
    try:
        with pytest.raises(OSError, match=rf'cannot serve Foxglove on 127.0.0.1:{first.port}: '
                           '.*in use'):
            LiveServer('127.0.0.1', first.port)
    finally:
        first.stop()


@pytest.mark.parametrize(('values', 'words'), [
    ({'port': 70000}, r'port=70000 is outside the allowed range \[0, 65535\] \(TCP port'),
    ({'port': -1}, r'port=-1 is outside the allowed range \[0, 65535\]'),
    ({'rate': 0.0}, r'rate=0.0 is outside the allowed range \(0, 1000\] Hz \(most views'),
    ({'rate': 'fast'}, r"rate='fast' is not valid; allowed: \(0, 1000\] Hz"),
    ({'host': 'my host'}, r"host='my host' is not an IP address or host name; allowed: an IP"),
    ({'host': ''}, r"host='' is not an IP address or host name"),
])
def test_bad_options_are_refused_in_the_tables_words(values, words):
    with pytest.raises(ParameterError, match=words):
        ViewerOptions(**values)


@pytest.mark.parametrize(('host', 'loopback'), [
    ('127.0.0.1', True), ('localhost', True), ('::1', True), ('127.0.1.1', True),
    ('0.0.0.0', False), ('192.168.1.5', False), ('example.org', False)])
def test_which_hosts_are_loopback(host, loopback):
    assert ViewerOptions(host=host).loopback is loopback
