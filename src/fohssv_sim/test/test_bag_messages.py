"""The bag writer's message path (fohssv_sim.bag.writer._Messages) writes what the ``mcap``
library's own ``Writer.add_message`` writes: the same file, byte for byte, for the same
messages (channels interleaved, payloads of every length mod 8 and empty, log times out of
order, chunks ending on size and on flush, single messages and batches mixed). The reference
is the library's public path, not this code."""

from __future__ import annotations

import io
import random

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as McapFileWriter

from fohssv_sim.bag.writer import _Messages


def _writer(stream: io.BytesIO, chunk_size: int) -> McapFileWriter:
    w = McapFileWriter(stream, chunk_size=chunk_size, compression=CompressionType.NONE,
                       enable_crcs=True, enable_data_crcs=True,
                       index_types=IndexType.ALL & ~IndexType.ATTACHMENT)
    w.start(profile='ros2', library='test')
    for k in range(3):
        sid = w.register_schema(f'pkg/msg/T{k}', 'ros2msg', b'float64 x')
        w.register_channel(f'/topic{k}', 'cdr', sid, {'offered_qos_profiles': '- {}'})
    return w


def _messages(seed: int, n: int) -> list[tuple[int, int, bytes]]:
    rng = random.Random(seed)
    out, t = [], 10**9
    for _ in range(n):
        t += rng.randint(-2000, 100_000)          # mostly forward, sometimes back in time
        out.append((rng.randint(1, 3), max(t, 0), rng.randbytes(rng.choice(
            (0, 1, 3, 4, 12, 40, 84, rng.randint(0, 900))))))
    return out


@pytest.mark.parametrize('chunk_size', [1, 700, 64 * 1024])
@pytest.mark.parametrize('seed', [1, 2])
def test_the_same_file_as_the_library_add_message(chunk_size, seed):
    msgs = _messages(seed, 3000)
    flush_at = set(random.Random(seed).sample(range(len(msgs)), 12))
    ref_stream, ours_stream = io.BytesIO(), io.BytesIO()
    ref, ours = _writer(ref_stream, chunk_size), _writer(ours_stream, chunk_size)
    sequence: dict[int, int] = {}
    for i, (ch, t, data) in enumerate(msgs):
        sequence[ch] = sequence.get(ch, 0) + 1
        ref.add_message(ch, log_time=t, data=data, publish_time=t, sequence=sequence[ch])
        if i in flush_at:
            ref.flush()
    sink = _Messages(ours, chunk_size)
    rng = random.Random(seed + 100)
    i = 0
    while i < len(msgs):                             # batches of 1..300, cut at the flushes
        j = min(len(msgs), i + rng.randint(1, 300))
        cut = min((k for k in flush_at if i <= k < j), default=None)
        if cut is not None:
            j = cut + 1
        if j - i == 1 and rng.random() < 0.5:
            sink.add(*msgs[i])
        else:
            sink.add_many(iter(msgs[i:j]))
        if cut is not None:
            ours.flush()
        i = j
    ref.finish()
    ours.finish()
    assert sink.count == len(msgs)
    assert ours_stream.getvalue() == ref_stream.getvalue()
    # and a reader sees the messages in order with their sequence numbers
    got = [(m.channel_id, m.log_time, m.data, m.sequence) for _, _, m in
           make_reader(io.BytesIO(ours_stream.getvalue())).iter_messages(log_time_order=False)]
    assert [g[:3] for g in got] == msgs
    counts: dict[int, int] = {}
    for ch, *_, seq in got:
        counts[ch] = counts.get(ch, 0) + 1
        assert seq == counts[ch]
