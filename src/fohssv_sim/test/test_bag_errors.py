"""Missing, empty, truncated and non-bag paths: a clear BagError naming the path, and from the
command line a one-line error with a non-zero exit, never a traceback. Pure: no rclpy.

The command line's cases run in-process through ``fohssv_sim.bag.__main__.main`` (what
``python -m fohssv_sim.bag`` calls); one bad bag and the usage error also run as
``python -m fohssv_sim.bag``, as a user runs it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fohssv_sim.bag import BagError, load_run
from fohssv_sim.bag.__main__ import main as bag_main
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


def _bag_cli(argv: list[str], capfd) -> tuple[int, str, str]:
    """``python -m fohssv_sim.bag ARGV`` in this process: (exit code, stdout, stderr)."""
    capfd.readouterr()
    code = bag_main([str(a) for a in argv])
    out = capfd.readouterr()
    return code, out.out, out.err


def test_cli_exits_non_zero_with_one_line_and_no_traceback(bad, capfd):
    path, words = bad['header_cut']
    proc = subprocess.run([sys.executable, '-m', 'fohssv_sim.bag', 'info', str(path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and 'Traceback' not in proc.stderr + proc.stdout
    assert proc.stderr.startswith('error: ') and words in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    for command in ('info', 'check', 'repair'):
        for case, (path, words) in bad.items():
            code, stdout, stderr = _bag_cli([command, path], capfd)
            assert code == 1, (command, case, stdout, stderr)
            assert 'Traceback' not in stderr + stdout
            lines = stderr.strip().splitlines()
            if command == 'check' and not lines:
                # a readable file with problems: they are listed, the verdict is last
                assert 'problem: ' in stdout and 'problem(s)' in stdout, (case, stdout)
                continue
            assert len(lines) == 1 and lines[0].startswith('error: ') and words in lines[0], (
                command, case, stderr)


def test_cli_on_a_good_bag(bad, capfd):
    good = bad['missing'][0].parent / 'good'
    for command in ('info', 'check'):
        code, stdout, stderr = _bag_cli([command, good], capfd)
        assert code == 0, stderr
    assert 'OK' in stdout
    proc = subprocess.run([sys.executable, '-m', 'fohssv_sim.bag'], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and 'usage' in proc.stderr
