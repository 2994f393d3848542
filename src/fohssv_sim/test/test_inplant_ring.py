"""In-plant recording without ROS (fohssv_sim.bag.inplant): the shared-memory ring, the
log-time rule of every recorded bag (bag.writer.LogTimes), and the writer process end to
end (a real process, a real bag).

Messages are serialized by rosbags' typestore (not by the code under test); the expected
log times follow the rule docs/recording.md states, computed from the decoded messages."""

from __future__ import annotations

import math
import random
import subprocess
import sys
import time

import numpy as np
import pytest
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from fohssv_sim import contract
from fohssv_sim.bag import load_run, scan
from fohssv_sim.bag.check import check
from fohssv_sim.bag.inplant import (
    TopicSpec,
    WriterConfig,
    kind_of,
    read_reply,
    send,
)
from fohssv_sim.bag.ring import HEADER_BYTES, Ring, place
from fohssv_sim.bag.writer import LogTimes, typestore

TS = typestore()
INF = QosTime(9223372036, 854775807)
QOS = Qos(history=QosHistory.KEEP_LAST, depth=10, reliability=QosReliability.RELIABLE,
          durability=QosDurability.VOLATILE, deadline=INF, lifespan=INF,
          liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=INF,
          avoid_ros_namespace_conventions=False)


def _array(values, label='t_z_w_theta_q') -> bytes:
    m = TS.types['std_msgs/msg/Float64MultiArray']
    dim = TS.types['std_msgs/msg/MultiArrayDimension'](label=label, size=len(values),
                                                         stride=len(values))
    layout = TS.types['std_msgs/msg/MultiArrayLayout'](dim=[dim], data_offset=0)
    msg = m(layout=layout, data=np.array(values, dtype=np.float64))
    return bytes(TS.serialize_cdr(msg, 'std_msgs/msg/Float64MultiArray'))


def _clock(ns: int) -> bytes:
    t = TS.types['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
    return bytes(TS.serialize_cdr(TS.types['rosgraph_msgs/msg/Clock'](clock=t),
                                  'rosgraph_msgs/msg/Clock'))


def _drain(ring: Ring) -> list[tuple[int, bytes]]:
    """Everything in the ring, as the writer takes it: one batch, then room for the plant."""
    got = [(k, bytes(v)) for k, v in ring.take()]
    ring.release()
    return got


def test_ring_gives_back_every_record_in_order_across_wraps():
    rng = random.Random(3)
    ring = Ring.create(4096)
    sent, got = [], []
    for i in range(5000):
        data = bytes([i % 251]) * rng.randint(0, 700)
        while not ring.put(i % 5, data):           # full: the consumer takes what is there
            got.extend(_drain(ring))
        sent.append((i % 5, data))
    got.extend(_drain(ring))
    assert got == sent
    assert ring.used == 0 and ring.lost == 0
    ring.close()


def test_a_full_ring_refuses_a_record_and_writes_nothing():
    ring = Ring.create(4096)
    n = 0
    while ring.put(0, bytes(100)):
        n += 1
    assert n == 4096 // 112                         # 8-byte header + 100 bytes padded to 104
    before = ring.used
    assert not ring.put(0, bytes(100)) and ring.used == before
    assert len(_drain(ring)) == n
    ring.close()


def test_place_writes_the_bytes_ring_put_writes_and_refuses_where_it_refuses():
    """place (the producer's put as array code, which the compiled fast path compiles) on a
    copy of the records' area, step for step beside Ring.put: the same bytes, wrap markers
    included, the same head, and no room at the same records."""
    rng = random.Random(5)
    ring = Ring.create(4096)
    area = np.zeros(ring.capacity, dtype=np.uint8)
    mapped = np.frombuffer(ring._map, dtype=np.uint8)[HEADER_BYTES:]    # noqa: SLF001
    refused = 0
    for i in range(3000):
        data = bytes(rng.randrange(256) for _ in range(rng.randint(0, 300)))
        head, tail = ring._counters[0], ring.consumed                  # noqa: SLF001
        after = place(area, ring.capacity, head, tail, i % 7,
                      np.frombuffer(data, dtype=np.uint8), len(data))
        put = ring.put(i % 7, data)
        assert put == (after >= 0)
        if put:
            assert ring._counters[0] == after                          # noqa: SLF001
            assert np.array_equal(area, mapped)
        else:
            refused += 1
            _drain(ring)
    assert refused > 10                                 # the ring wrapped and filled often
    del mapped
    ring.close()


@pytest.mark.parametrize('values', [[0.25, 1.0, 2.0], [1e-4] * 5, [], [math.nan, 1.0],
                                    [-1.0, 2.0], [float('inf')], [12345.678]])
def test_log_time_of_an_array_is_round_t_ns_else_the_previous(values):
    times = LogTimes()
    times.last = 777
    for label in ('t_delta_f_delta_c', '', 'x' * 13):
        raw = _array(values, label)
        data = TS.deserialize_cdr(raw, 'std_msgs/msg/Float64MultiArray').data
        t = float(data[0]) if len(data) else math.nan
        expected = round(t * 1e9) if math.isfinite(t) and 0 <= t < 9e9 else 777
        assert times.array(raw) == expected
        times.last = 777


def test_log_time_of_clock_is_its_stamp():
    for ns in (0, 1, 10**9 - 1, 123_456_789_012):
        assert LogTimes().clock(_clock(ns)) == ns


def test_writer_process_writes_a_complete_bag_and_checks_run_end(tmp_path):
    ring = Ring.create(64 * 1024)
    topics = (TopicSpec('/state', contract.FLOAT64_ARRAY, (QOS,), kind_of(contract.FLOAT64_ARRAY)),
              TopicSpec('/clock', contract.CLOCK.type, (QOS,), kind_of(contract.CLOCK.type)))
    bag = tmp_path / 'run'
    proc = subprocess.Popen([sys.executable, '-m', 'fohssv_sim.bag.inplant', str(ring.fd),
                             str(ring.size)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            pass_fds=(ring.fd,))
    send(proc.stdin, ('open', WriterConfig(str(bag), topics, {'fohssv.test': 'yes'})))
    assert 'opened' in read_reply(proc.stdout)
    assert read_reply(proc.stdout)['ready']
    states = [_array([k * 1e-4, 0.0, float(k), 0.0, 0.0]) for k in range(3000)]
    for k, raw in enumerate(states):                 # 3000 x 2 records through a 64 KiB ring
        while not ring.put(0, raw):                  # full: the writer's turn (no busy wait:
            time.sleep(0.001)                        # it would share the cores with it)
        while not ring.put(1, _clock(round(k * 1e-4 * 1e9))):
            time.sleep(0.001)
    send(proc.stdin, ('end', contract.run_end_text('plant', 'test', 0, 0.2999,
                                                    {'/state': 3001})))
    reply = read_reply(proc.stdout)
    assert proc.wait(timeout=60) == 6                # one state short of what run_end lists
    assert reply['missing'] == {'/state': [3000, 3001]} and reply['messages'] == 6000
    assert check(bag).ok
    sc = scan(bag)
    assert [bytes(r) for c, _, r in sc.messages if sc.channels[c].topic == '/state'] == states
    run = load_run(bag)
    assert np.array_equal(run.t, np.arange(3000) * 1e-4)
    assert run.metadata['fohssv.test'] == 'yes' and run.metadata['fohssv.run_end']['t'] == 0.2999
    ring.close()


def test_writer_closes_the_bag_when_its_plant_goes_away(tmp_path):
    """End of file on the control pipe without 'end' (the plant died): what the ring holds
    is written and the bag is closed, marked interrupted (exit 7)."""
    ring = Ring.create(8192)
    topics = (TopicSpec('/state', contract.FLOAT64_ARRAY, (QOS,), 'array'),)
    bag = tmp_path / 'cut'
    proc = subprocess.Popen([sys.executable, '-m', 'fohssv_sim.bag.inplant', str(ring.fd),
                             str(ring.size)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            pass_fds=(ring.fd,))
    send(proc.stdin, ('open', WriterConfig(str(bag), topics, {})))
    assert 'opened' in read_reply(proc.stdout)
    assert read_reply(proc.stdout)['ready']
    for k in range(20):
        assert ring.put(0, _array([k * 1e-4, 0.0, 0.0, 0.0, 0.0]))
    proc.stdin.close()
    reply = read_reply(proc.stdout)
    assert proc.wait(timeout=60) == 7 and reply['interrupted']
    assert check(bag).ok and load_run(bag).topics['/state'] == 20
    assert 'fohssv.record_interrupted' in load_run(bag).metadata
    ring.close()


def _stamped(ns: int, frame: str = 'world') -> bytes:
    stamp = TS.types['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)
    header = TS.types['std_msgs/msg/Header'](stamp=stamp, frame_id=frame)
    pose = TS.types['geometry_msgs/msg/Pose'](
        position=TS.types['geometry_msgs/msg/Point'](x=1.0, y=2.0, z=3.0),
        orientation=TS.types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0))
    msg = TS.types['geometry_msgs/msg/PoseStamped'](header=header, pose=pose)
    return bytes(TS.serialize_cdr(msg, 'geometry_msgs/msg/PoseStamped'))


def _records(path):
    """Every MCAP record of a bag but those that hold the session's start time (metadata
    and what indexes or checksums it), as (type, fields)."""
    from mcap.records import DataEnd, Footer, Metadata, MetadataIndex, SummaryOffset
    from mcap.stream_reader import StreamReader

    skip = (Metadata, MetadataIndex, DataEnd, Footer, SummaryOffset)
    with open(next(path.glob('*.mcap')), 'rb') as f:
        reader = StreamReader(f, emit_chunks=True, validate_crcs=True)
        return [(type(r).__name__, vars(r)) for r in reader.records if not isinstance(r, skip)]


def test_compiled_writer_writes_the_bytes_the_interpreted_one_does(tmp_path):
    """The in-plant writer's compiled path (bag.ringpack) against its interpreted one, fed the
    same records through a small ring (wraps) into small chunks (many chunk ends): every MCAP
    record equal, chunks' bytes included. The records mix what :func:`~bag.ringpack.pack`
    packs and what it leaves to the interpreted path: a topic's first array, a layout
    change (another label), arrays whose t is not a time (NaN, negative, empty: the previous
    log time), /clock, stamped views (a negative stamp: the previous log time) and odd
    lengths (padding)."""
    from fohssv_sim.bag.inplant import _Session

    topics = (TopicSpec('/state', contract.FLOAT64_ARRAY, (QOS,), 'array'),
              TopicSpec('/clock', contract.CLOCK.type, (QOS,), 'clock'),
              TopicSpec('/pose', 'geometry_msgs/msg/PoseStamped', (QOS,), 'stamped'),
              TopicSpec('/command', contract.FLOAT64_ARRAY, (QOS,), 'array'))
    rng = random.Random(7)
    records = []
    for k in range(3000):
        t = k * 1e-4
        label = 't_z_w_theta_q' if k < 2500 else 'state'
        values = [t, 0.1, 0.2, 0.3, 0.4] if k % 997 else rng.choice(
            [[math.nan, 1.0], [-1.0], []])
        records.append((0, _array(values, label)))
        records.append((1, _clock(round(t * 1e9))))
        if k % 50 == 0:
            records.append((2, _stamped(round(t * 1e9), 'w' * rng.randint(0, 9))))
        if k % 1500 == 7:
            records.append((2, _stamped(0)[:4] + (-5).to_bytes(4, 'little', signed=True)
                            + _stamped(0)[8:]))
        records.append((3, _array([t, 0.01, -0.02], 't_delta_f_delta_c')))
    bags = {}
    for compiled in (False, True):
        ring = Ring.create(64 * 1024)
        bag = tmp_path / ('compiled' if compiled else 'interpreted') / 'run'   # one name
        session = _Session(WriterConfig(str(bag), topics, {}, chunk_size=4096,
                                        compiled=compiled), ring)
        assert session.use_compiled() is compiled
        for index, raw in records:
            while not ring.put(index, raw):
                session.drain(rng.choice([1, 300, 5000, 1 << 22]))
        while session.drain():
            pass
        result = session.end(None)
        assert result['messages'] == len(records) and result['compiled'] is compiled
        ring.close()
        bags[compiled] = _records(bag)
    kinds = [name for name, _ in bags[True]]
    assert kinds.count('Chunk') > 100 and kinds.count('MessageIndex') > 300
    assert bags[True] == bags[False]


def test_a_writer_whose_compiled_path_cannot_load_writes_interpreted(tmp_path):
    """The compiled path refuses a topic kind it does not know (KeyError building its tables):
    the writer says why (the plant logs it at 'ready') and writes every message interpreted."""
    from fohssv_sim.bag.inplant import _Session

    topics = (TopicSpec('/state', contract.FLOAT64_ARRAY, (QOS,), 'array'),
              TopicSpec('/odd', contract.CLOCK.type, (QOS,), 'unknown kind'))
    ring = Ring.create(64 * 1024)
    session = _Session(WriterConfig(str(tmp_path / 'run'), topics, {}), ring)
    assert session.use_compiled() is False and session.packer is None
    assert session.compile_error.startswith('KeyError') and 'unknown kind' in \
        session.compile_error
    for k in range(100):
        assert ring.put(0, _array([k * 1e-4, 0.0, 0.0, 0.0, 0.0]))
    while session.drain():
        pass
    result = session.end(None)
    assert result['compiled'] is False and result['counts']['/state'] == 100
    ring.close()
    assert np.array_equal(load_run(tmp_path / 'run').t, np.arange(100) * 1e-4)


@pytest.mark.parametrize(('compiled', 'chunk_size', 'limit'), [
    (True, 1 << 20, 1500 * 1024), (True, 16 * 1024, 700 * 1024), (False, 16 * 1024, 300 * 1024),
    (True, 16 * 1024, None)],
    ids=['compiled-1MiB-chunks', 'compiled-16KiB-chunks', 'interpreted-16KiB-chunks',
         'compiled-killed'])
def test_a_writer_stopped_by_a_full_disk_leaves_a_shortfall_the_ring_counts_exactly(
        tmp_path, compiled, chunk_size, limit):
    """Issue 51.5: the writer's bag file may not grow past ``limit`` bytes (RLIMIT_FSIZE, the
    disk full: its write fails with EFBIG, as with ENOSPC, wherever it is: in a chunk's
    bytes, between a chunk and its indexes, at a flush). The writer answers one line and
    exits 1; the records the producer offered that the bag lacks, counted as the plant counts
    them (the puts that failed once the writer was dead, plus :func:`unrecorded` from the
    ring's header and the cut file), equal the offered records less the messages ``fohssv
    repair`` recovers from the bag: exact, not a bound. ``limit`` None: no limit, the writer
    SIGKILLed in the middle of the stream instead (wherever it was), the same count."""
    import resource
    import signal

    from fohssv_sim.bag.inplant import unrecorded
    from fohssv_sim.bag.repair import repair

    def full_disk():
        if limit is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)    # a failed write, not a signal
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    ring = Ring.create(256 * 1024)
    topics = (TopicSpec('/state', contract.FLOAT64_ARRAY, (QOS,), 'array'),
              TopicSpec('/clock', contract.CLOCK.type, (QOS,), 'clock'))
    bag = tmp_path / 'full'
    proc = subprocess.Popen([sys.executable, '-m', 'fohssv_sim.bag.inplant', str(ring.fd),
                             str(ring.size)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            pass_fds=(ring.fd,), preexec_fn=full_disk)
    send(proc.stdin, ('open', WriterConfig(str(bag), topics, {}, flush_period=0.02,
                                           chunk_size=chunk_size, compiled=compiled)))
    assert 'opened' in read_reply(proc.stdout)
    assert read_reply(proc.stdout)['compiled'] is compiled
    offered = failed = 0
    for k in range(40000):                # up to 4 MB of records: the file stops at limit
        if k == 5000 and limit is None:
            proc.kill()
        for index, raw in ((0, _array([k * 1e-4, 0.0, float(k), 0.0, 0.0])),
                           (1, _clock(round(k * 1e-4 * 1e9)))):
            offered += 1
            while not ring.put(index, raw):
                if proc.poll() is not None:    # the writer is gone: counted, as the plant does
                    failed += 1
                    break
                time.sleep(0.001)              # full: the writer's turn
        if failed >= 100:     # the ring full behind a dead writer: more puts fail alike
            break
    reply = read_reply(proc.stdout)
    if limit is None:
        assert proc.wait(timeout=60) == -signal.SIGKILL and reply is None
    else:
        assert proc.wait(timeout=60) == 1
        assert reply['error'] == f'{bag}: File too large', reply
    lacked = failed + unrecorded(ring, bag / 'full.mcap')
    ring.close()
    report = repair(bag)
    held = sum(load_run(bag).topics.values())
    assert report.repaired and 0 < held == report.messages < offered
    assert failed >= 100 and lacked == offered - held, (lacked, offered, held, failed)
