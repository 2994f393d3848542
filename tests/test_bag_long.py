"""Long bags: ``info`` from the MCAP summary section, ``load_run`` with a time window and
decimation into arrays, a refusal naming the size when a load cannot fit, bounded chunk
indexes while writing; and the bag and output-folder inputs that used to go wrong (a YAML
alias bomb, ``--out ''``, ``repair --no-backup``).

The asserted values come from the synthetic trajectory (:func:`fohssv_sim.bag.synthetic.
trajectory`, computed here independently of any bag) and from the MCAP file's own bytes.
"""

from __future__ import annotations

import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from fohssv_sim.bag import BagError, load_run
from fohssv_sim.bag.__main__ import info
from fohssv_sim.bag.__main__ import main as bag_main
from fohssv_sim.bag.check import check
from fohssv_sim.bag.run import TooLarge, state_count
from fohssv_sim.bag.stream import fits
from fohssv_sim.bag.synthetic import trajectory, write_bag
from fohssv_sim.bag.writer import RunWriter
from fohssv_sim.cli import main as cli_main

N = 3000        # steps of 1 ms: t = 0 .. 2.999 s


@pytest.fixture(scope='module')
def bag(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp('long') / 'run'
    write_bag(path, N, flush_every=100)
    return path


def test_a_window_and_decimation_give_exactly_those_samples(bag):
    t, x = trajectory(N)
    run = load_run(bag, start=0.5, end=1.5, every=7)
    keep = np.flatnonzero((np.round(t * 1e9) >= 0.5e9) & (np.round(t * 1e9) <= 1.5e9))[::7]
    assert np.array_equal(run.t, t[keep]) and np.array_equal(run.state, x[keep])
    assert np.array_equal(run.planing_force, x[keep, 0])
    assert np.array_equal(run.delta_f, -x[keep, 2]) and np.array_equal(run.delta_c, x[keep, 3])
    assert np.array_equal(run.log_time['state'], np.round(t[keep] * 1e9).astype(np.int64))
    assert not run.truncated
    whole = load_run(bag)
    assert np.array_equal(whole.t, t) and np.array_equal(whole.state, x)
    assert whole.topics == {'/clock': N, '/state': N, '/planing_force': N, '/command': N}
    assert np.allclose(whole.clock_t, t, rtol=0, atol=1e-9)


@pytest.mark.parametrize('kwargs,words', [
    ({'every': 0}, 'every=0'), ({'start': 2.0, 'end': 1.0}, 'lies before'),
    ({'start': float('nan')}, 'start=nan')])
def test_a_bad_request_is_one_line(bag, kwargs, words):
    with pytest.raises(ValueError, match=words):
        load_run(bag, **kwargs)


def test_a_cut_bag_still_loads_what_it_holds(tmp_path):
    t, x, _ = write_bag(tmp_path / 'cut', 1000, flush_every=100, close=False)
    run = load_run(tmp_path / 'cut', start=0.2, every=3)
    assert run.truncated and 'recovered 4000 messages (267 states' in run.recovery
    keep = np.flatnonzero(np.round(t * 1e9) >= 0.2e9)[::3]
    assert np.array_equal(run.t, t[keep]) and np.array_equal(run.state, x[keep])


def test_info_comes_from_the_summary_without_reading_the_messages(bag, tmp_path):
    """Every message record overwritten with garbage (the summary and the first and last
    chunk kept): info still gives the counts, the state's span and the metadata, which it
    could not if it read the messages."""
    mcap = next(bag.glob('*.mcap'))
    broken = tmp_path / 'broken.mcap'
    data = bytearray(mcap.read_bytes())
    middle = slice(len(data) // 3, len(data) // 2)        # inside the data section
    data[middle] = b'\xff' * (middle.stop - middle.start)
    broken.write_bytes(bytes(data))
    lines = info(str(broken))
    assert f'state:    {N} samples, t = 0 ... 2.999 s' in lines
    assert f'topic:    /state: {N} messages' in lines
    assert any(x.startswith('metadata: fohssv.version = 0.1.0') for x in lines)
    assert state_count(broken) == N
    # reading the messages does find the damage
    assert load_run(broken).truncated


def test_info_of_a_cut_bag_reads_it_through(tmp_path):
    write_bag(tmp_path / 'cut', 500, flush_every=100, close=False)
    lines = info(str(tmp_path / 'cut'))
    assert 'state:    500 samples, t = 0 ... 0.499 s' in lines
    assert any(x.startswith('WARNING: truncated bag') for x in lines)


def test_a_load_that_cannot_fit_is_refused_naming_its_size():
    with pytest.raises(MemoryError, match=r'1000000 rows need about 0.08 GB and 0.01 GB of '
                       r'memory is available; load less'):
        fits('bag', 1_000_000, 40, 'load less', available=10_000_000)
    fits('bag', 1000, 40, 'load less', available=10_000_000)
    assert issubclass(TooLarge, BagError)


def test_the_chunk_indexes_of_a_long_recording_stay_out_of_memory(tmp_path):
    """One chunk per flush, 8000 flushes (a 13-minute recording at the recorder's 0.1 s):
    the Python heap grows by less than 1 MB from the 1000th to the last (the chunk index
    objects alone took 9 MB over 20 000 chunks, 450 bytes each: 3 MB here), and the bag is
    sound with every chunk indexed. Memory is traced from the 1000th flush on (tracing slows
    every allocation): what it counts, the blocks allocated since and still alive, is at
    least the growth (observed: 0.5 kB)."""
    w = RunWriter(tmp_path / 'idx', chunk_size=1 << 20).open()
    w.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
    from fohssv_sim.bag.synthetic import clock

    for i in range(8000):
        w.write('/clock', i * 1000, clock(i * 1000))
        w.flush()
        if i == 1000:
            tracemalloc.start()
    grown = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    w.close()
    assert grown < 1e6, grown
    assert check(tmp_path / 'idx').ok
    from mcap.reader import make_reader

    with open(next((tmp_path / 'idx').glob('*.mcap')), 'rb') as f:
        summary = make_reader(f).get_summary()
    assert len(summary.chunk_indexes) == 8000
    assert [c.message_start_time for c in summary.chunk_indexes[:3]] == [0, 1000, 2000]


def test_an_alias_bomb_in_metadata_yaml_is_refused_at_once(bag, tmp_path):
    import shutil

    copy = tmp_path / 'bomb'
    shutil.copytree(bag, copy)
    meta = copy / 'metadata.yaml'
    bomb = ('a: &a ["x","x","x","x","x","x","x","x","x"]\n'
            + ''.join(f'{c}: &{c} [*{p},*{p},*{p},*{p},*{p},*{p},*{p},*{p},*{p}]\n'
                      for p, c in zip('abcdefgh', 'bcdefghi')))
    # nine to the ninth strings once expanded, in custom_data where info prints each value
    text = meta.read_text().replace('  custom_data:', '  bomb_data:\n' + ''.join(
        '    ' + line + '\n' for line in bomb.splitlines()) + '  custom_data:\n    boom: *i',
        1)
    meta.write_text(text)
    started = time.monotonic()
    with pytest.raises(BagError, match='YAML aliases'):
        load_run(copy)
    assert bag_main(['info', str(copy)]) == 1
    assert time.monotonic() - started < 5


def test_out_empty_is_refused_and_writes_nothing(bag, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        cli_main(['plot', str(bag), '--out', ''])
    assert e.value.code == 2
    assert "'' is no folder" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_plot_decimates_a_long_bag_and_says_so(bag, tmp_path, capsys):
    out = tmp_path / 'fig'
    assert cli_main(['plot', str(bag), '--out', str(out), '--every', '10', '--start', '1',
                     '--end', '2']) == 0
    said = capsys.readouterr().out
    assert 'every 10th sample plotted' in said
    assert (out / 'run_time.png').exists()


def test_repair_no_backup_from_the_fohssv_command(tmp_path):
    write_bag(tmp_path / 'cut', 300, flush_every=100, close=False)
    out = subprocess.run([sys.executable, '-m', 'fohssv_sim.cli', 'repair', '--no-backup',
                          str(tmp_path / 'cut')], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert check(tmp_path / 'cut').ok
    assert not list((tmp_path / 'cut').glob('*.orig*'))



@pytest.mark.parametrize('argv', [['fit', 'BAG', '--out', ' '], ['tune', '--out', '']])
def test_out_empty_is_refused_by_fit_and_tune_too(argv, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        cli_main(argv)
    assert e.value.code == 2 and 'is no folder' in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
