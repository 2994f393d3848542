"""Issue 51.4: ``fohssv repair`` and the player stream the bag: their memory does not grow
with the bag's size (both read the whole MCAP file into memory, and a Python object per
message beside it, so a long run's bag could not be repaired or replayed on the machine that
recorded it).

One real bag of about 48 MB, cut after a known chunk (its footer, summary and the chunks after
it gone, as a killed recorder leaves it), repaired under ``tracemalloc``: the peak of the
Python heap stays a small share of the bag's size, and the repaired bag holds exactly the
messages of the complete chunks, byte for byte (the chunk boundaries read from the complete
file's summary with the ``mcap`` library's reader, not with the code under test). The
player's reading (:func:`fohssv_sim.bag.loader.stream` and the replay
:func:`~fohssv_sim.bag.replay.timeline` over it) of the same bag whole, likewise.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
from mcap.reader import make_reader

from fohssv_sim import contract
from fohssv_sim.bag import load_run
from fohssv_sim.bag.loader import scan, stream
from fohssv_sim.bag.repair import repair
from fohssv_sim.bag.replay import timeline
from fohssv_sim.bag.synthetic import float64_array
from fohssv_sim.bag.writer import RunWriter

#: Doubles per message (32 KiB messages: the message count, and so the test, stays small).
WIDTH = 4096
MESSAGES = 1500


def _message(i: int, block: np.ndarray) -> bytes:
    values = block[i % len(block)].copy()
    values[0] = i * 1e-4
    return float64_array(contract.STATE, values)


def _long_bag(path) -> np.ndarray:
    """A bag of :data:`MESSAGES` 32 KiB states at log times i * 0.1 ms; the rows it draws
    from (incompressible)."""
    block = np.random.default_rng(2).standard_normal((16, WIDTH))
    w = RunWriter(path, chunk_size=1 << 20).open()
    w.add_topic('/state', contract.STATE.type)
    for i in range(MESSAGES):
        w.write('/state', i * 100_000, _message(i, block))
    w.close()
    return block


def test_the_player_reads_a_long_bag_a_chunk_at_a_time(tmp_path):
    """What the player plays, read as it plays it: every message in order, each due at its
    log time over the rate (i * 0.1 ms / 2 at rate 2), with a Python heap peak a small share
    of the bag."""
    _long_bag(tmp_path / 'long')
    size = (tmp_path / 'long' / 'long.mcap').stat().st_size
    tracemalloc.start()
    try:
        _, messages = stream(tmp_path / 'long')
        played = [(item[1], due) for item, due, _ in timeline(
            ((cid, log) for cid, log, _ in messages), 2.0)]
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert [log for log, _ in played] == [i * 100_000 for i in range(MESSAGES)]
    assert np.allclose([due for _, due in played], np.arange(MESSAGES) * 1e-4 / 2.0,
                       rtol=0, atol=1e-12)
    assert peak < size / 8, (peak, size)


def test_repair_of_a_cut_bag_needs_a_small_share_of_its_size(tmp_path):
    bag = tmp_path / 'long'
    block = _long_bag(bag)
    mcap = bag / 'long.mcap'
    size = mcap.stat().st_size
    assert size > 45e6
    with mcap.open('rb') as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes,
                        key=lambda c: c.chunk_start_offset)
    keep = chunks[len(chunks) * 3 // 4]          # the bag is cut after this chunk's indexes
    cut = keep.chunk_start_offset + keep.chunk_length + keep.message_index_length
    held = keep.message_end_time // 100_000 + 1  # log time i * 1e5 ns: messages 0 .. i
    with mcap.open('r+b') as f:
        f.truncate(cut + 1000)                   # and a part of the next chunk
    (bag / 'metadata.yaml').unlink()

    tracemalloc.start()
    try:
        report = repair(bag)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert report.repaired and report.messages == held
    assert peak < size / 8, (peak, size)         # reading it whole: more than its size
    sc = scan(bag, on_message=lambda cid, t, data: None)
    assert sc.complete and sc.message_count == held
    seen = []
    scan(bag, on_message=lambda cid, t, data: seen.append(
        (t, data == _message(t // 100_000, block))))
    assert [t for t, _ in seen] == [i * 100_000 for i in range(held)]
    assert all(same for _, same in seen)
    assert load_run(bag).topics['/state'] == held
