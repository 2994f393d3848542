"""A bag cut anywhere (as a SIGKILLed recorder leaves it) loads with every flushed message,
and repair rebuilds a complete, checked bag from it. Pure: no rclpy."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from fohssv_sim.bag import BagError, load_run
from fohssv_sim.bag.check import check
from fohssv_sim.bag.repair import main_repair, repair
from fohssv_sim.bag.synthetic import METADATA, write_bag

N, FLUSH = 300, 20


def test_unclosed_bag_holds_every_flushed_step(tmp_path):
    """The writer is left open (no close, as after SIGKILL): no metadata.yaml, no summary,
    and the loader reads every step up to the last flush."""
    path = tmp_path / 'killed'
    t, x, w = write_bag(path, N + 7, flush_every=FLUSH, close=False)
    w._storage()._file.flush()   # what the OS holds when the process dies
    assert not (path / 'metadata.yaml').exists()
    run = load_run(path)
    flushed = (N + 7) // FLUSH * FLUSH
    assert run.truncated and len(run.t) == flushed
    assert np.array_equal(run.state, x[:flushed]) and np.array_equal(run.t, t[:flushed])
    assert run.metadata['fohssv.plant_parameters'] == METADATA['fohssv.plant_parameters']
    assert f'{flushed} states' in run.recovery


@pytest.fixture(scope='module')
def whole(tmp_path_factory):
    path = tmp_path_factory.mktemp('whole') / 'run'
    t, x, _ = write_bag(path, N, flush_every=FLUSH)
    return path, (path / 'run.mcap').read_bytes(), t, x


def test_cut_anywhere_recovers_a_prefix_losing_at_most_one_flush(whole, tmp_path):
    path, data, t, x = whole
    first_chunk_end = None
    for k, cut in enumerate(np.linspace(0, len(data), 41).astype(int)[1:-1]):
        bag = tmp_path / f'cut{k}'
        bag.mkdir()
        (bag / f'cut{k}.mcap').write_bytes(data[:cut])
        try:
            run = load_run(bag)
        except BagError as exc:
            # only before the first chunk is complete: nothing to recover, said clearly
            assert 'nothing to recover' in str(exc) and str(bag) in str(exc)
            assert first_chunk_end is None
            continue
        first_chunk_end = first_chunk_end or cut
        n = len(run.t)
        assert run.truncated
        assert np.array_equal(run.state, x[:n]) and np.array_equal(run.t, t[:n])
        # every step whose 4 messages lie wholly before the cut, minus one flush, is there
        assert n % FLUSH == 0
        assert n >= min(N, int(cut / len(data) * N)) - 2 * FLUSH


def test_repair_rebuilds_a_complete_checked_bag(whole, tmp_path):
    path, data, t, x = whole
    bag = tmp_path / 'cut'
    bag.mkdir()
    (bag / 'cut.mcap').write_bytes(data[:int(len(data) * 0.6)])
    before = load_run(bag)
    report = repair(bag)
    assert report.repaired and report.backup == bag / 'cut.mcap.orig'
    assert check(bag).ok, check(bag).problems
    after = load_run(bag)
    assert not after.truncated
    assert np.array_equal(after.state, before.state)
    assert np.array_equal(after.log_time['state'], before.log_time['state'])
    assert after.metadata['fohssv.plant_parameters'] == METADATA['fohssv.plant_parameters']
    assert 'recovered' in after.metadata['fohssv.repaired']
    with Reader(bag) as reader:
        assert reader.message_count == sum(after.topics.values())
    assert not repair(bag).repaired      # complete now: nothing to do


def test_repair_recreates_a_missing_metadata_yaml(whole, tmp_path):
    path = tmp_path / 'nometa'
    shutil.copytree(whole[0], path)
    (path / 'metadata.yaml').unlink()
    assert main_repair([str(path), '--no-backup']) == 0
    assert check(path).ok
    assert not (path / 'run.mcap.orig').exists()
    assert len(load_run(path).t) == N
