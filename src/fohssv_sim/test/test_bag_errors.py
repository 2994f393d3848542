"""Missing, empty, truncated and non-bag paths: a clear BagError naming the path, and from the
command line a one-line error with a non-zero exit, never a traceback. Pure: no rclpy."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fohssv_sim.bag import BagError, load_run
from fohssv_sim.bag.synthetic import write_bag


def _bad_paths(root: Path) -> dict[str, tuple[Path, str]]:
    """name -> (path, words the error must contain)."""
    (root / 'empty_dir').mkdir()
    (root / 'empty.mcap').write_bytes(b'')
    (root / 'text.mcap').write_text('hello, not a bag\n')
    (root / 'other_dir').mkdir()
    (root / 'other_dir' / 'notes.txt').write_text('x')
    (root / 'bad_yaml').mkdir()
    (root / 'bad_yaml' / 'metadata.yaml').write_text('rosbag2_bagfile_information: [\n')
    (root / 'sqlite').mkdir()
    (root / 'sqlite' / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n')
    write_bag(root / 'good', 50)
    data = (root / 'good' / 'good.mcap').read_bytes()
    (root / 'magic_only').mkdir()
    (root / 'magic_only' / 'magic_only.mcap').write_bytes(data[:8])
    (root / 'header_cut').mkdir()
    (root / 'header_cut' / 'header_cut.mcap').write_bytes(data[:5])
    (root / 'first_chunk_cut').mkdir()
    (root / 'first_chunk_cut' / 'first_chunk_cut.mcap').write_bytes(data[:300])
    return {
        'missing': (root / 'nope', 'no such file'),
        'empty_dir': (root / 'empty_dir', 'empty directory'),
        'empty_file': (root / 'empty.mcap', 'empty file'),
        'text_file': (root / 'text.mcap', 'not an MCAP file'),
        'dir_without_bag': (root / 'other_dir', 'not a bag'),
        'bad_metadata_yaml': (root / 'bad_yaml', 'not valid YAML'),
        'sqlite_storage': (root / 'sqlite', "storage 'sqlite3'"),
        'magic_only': (root / 'magic_only', 'nothing to recover'),
        'header_cut': (root / 'header_cut', 'truncated'),
        'first_chunk_cut': (root / 'first_chunk_cut', 'nothing to recover'),
    }


@pytest.fixture(scope='module')
def bad(tmp_path_factory):
    return _bad_paths(tmp_path_factory.mktemp('bad'))


@pytest.mark.parametrize('case', ['missing', 'empty_dir', 'empty_file', 'text_file',
                                  'dir_without_bag', 'bad_metadata_yaml', 'sqlite_storage',
                                  'magic_only', 'header_cut', 'first_chunk_cut'])
def test_load_run_raises_a_clear_bag_error(bad, case):
    path, words = bad[case]
    with pytest.raises(BagError) as info:
        load_run(path)
    assert words in str(info.value) and path.name in str(info.value)


def test_cli_exits_non_zero_with_one_line_and_no_traceback(bad):
    for command in ('info', 'check', 'repair'):
        for case, (path, words) in bad.items():
            proc = subprocess.run([sys.executable, '-m', 'fohssv_sim.bag', command, str(path)],
                                  capture_output=True, text=True, timeout=60)
            assert proc.returncode == 1, (command, case, proc.stdout, proc.stderr)
            assert 'Traceback' not in proc.stderr + proc.stdout
            lines = proc.stderr.strip().splitlines()
            if command == 'check' and not lines:
                # a readable file with problems: they are listed, the verdict is last
                assert 'problem: ' in proc.stdout and 'problem(s)' in proc.stdout, (
                    case, proc.stdout)
                continue
            assert len(lines) == 1 and lines[0].startswith('error: ') and words in lines[0], (
                command, case, proc.stderr)


def test_cli_on_a_good_bag(bad):
    good = bad['missing'][0].parent / 'good'
    for command in ('info', 'check'):
        proc = subprocess.run([sys.executable, '-m', 'fohssv_sim.bag', command, str(good)],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
    assert 'OK' in proc.stdout
    proc = subprocess.run([sys.executable, '-m', 'fohssv_sim.bag'], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and 'usage' in proc.stderr
