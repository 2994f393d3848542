"""Issue 12, defects 10 and 11: a bag's files stay inside its folder; a wrong-shaped
metadata.yaml is one BagError line everywhere; repair is all or nothing. Pure: no rclpy."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fohssv_sim.bag import BagError, load_run
from fohssv_sim.bag.check import check
from fohssv_sim.bag.repair import repair
from fohssv_sim.bag.synthetic import edit_metadata, write_bag


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob('*'))
            if p.is_file()}


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-m', 'fohssv_sim.bag', *args],
                          capture_output=True, text=True, timeout=60)


def test_repair_never_follows_file_paths_outside_the_bag(tmp_path):
    """``relative_file_paths: [../victim/victim.mcap]``: repair used to rewrite the victim."""
    write_bag(tmp_path / 'victim', 40, close=False)          # a cut bag: repair would act
    write_bag(tmp_path / 'bag', 40)
    edit_metadata(tmp_path / 'bag', relative_file_paths=['../victim/victim.mcap'])
    (tmp_path / 'bag' / 'bag.mcap').unlink()
    before = _snapshot(tmp_path)
    for call in (lambda p: repair(p, force=True), load_run, check):
        with pytest.raises(BagError, match=r'outside the bag folder'):
            call(tmp_path / 'bag')
    proc = _cli('repair', '--force', str(tmp_path / 'bag'))
    assert proc.returncode == 1 and 'Traceback' not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert _snapshot(tmp_path) == before


def test_a_symbolic_link_out_of_the_bag_is_refused(tmp_path):
    write_bag(tmp_path / 'victim', 40, close=False)
    (tmp_path / 'bag').mkdir()
    (tmp_path / 'bag' / 'bag.mcap').symlink_to(tmp_path / 'victim' / 'victim.mcap')
    before = (tmp_path / 'victim' / 'victim.mcap').read_bytes()
    with pytest.raises(BagError, match=r'outside the bag folder'):
        repair(tmp_path / 'bag')
    assert (tmp_path / 'victim' / 'victim.mcap').read_bytes() == before
    assert sorted(p.name for p in (tmp_path / 'victim').iterdir()) == ['victim.mcap']


@pytest.mark.parametrize('fields, words', [
    ({'custom_data': [1, 2]}, 'custom_data is [1, 2], it must be a mapping'),
    ({'relative_file_paths': 5}, 'relative_file_paths is 5, it must be a list of file names'),
    ({'relative_file_paths': [1]}, 'relative_file_paths is [1]'),
    ({'files': 'x'}, "files is 'x', it must be a list of mappings"),
    ({'topics_with_message_count': [3]}, 'topics_with_message_count is [3]'),
])
def test_wrong_shaped_metadata_yaml_is_one_bag_error_everywhere(tmp_path, fields, words,
                                                                 capfd):
    """... and from the command line (in-process through ``fohssv_sim.bag.__main__.main``,
    what ``python -m fohssv_sim.bag`` calls; the other tests here run that as a process)."""
    from fohssv_sim.bag.__main__ import main

    bag = tmp_path / 'bag'
    write_bag(bag, 30)
    edit_metadata(bag, **fields)
    before = _snapshot(tmp_path)
    for call in (load_run, check, lambda p: repair(p, force=True)):
        with pytest.raises(BagError, match='malformed metadata.yaml') as info:
            call(bag)
        assert words in str(info.value)
    if 'custom_data' in fields or 'relative_file_paths' in fields:   # the cases
        for command in ('info', 'check', 'repair'):
            capfd.readouterr()
            code = main([command, str(bag)])
            out = capfd.readouterr()
            assert code == 1, (command, out.out, out.err)
            lines = out.err.strip().splitlines()
            assert len(lines) == 1 and words in lines[0] and 'Traceback' not in out.err
    assert _snapshot(tmp_path) == before


def test_repair_with_metadata_yaml_a_directory_changes_nothing(tmp_path):
    """A metadata.yaml that is a directory used to leave repair half applied (the MCAP
    replaced and moved to .orig, then the YAML step failing)."""
    bag = tmp_path / 'bag'
    write_bag(bag, 40, close=False)
    (bag / 'metadata.yaml').mkdir()
    before = _snapshot(tmp_path)
    with pytest.raises(BagError, match=r'metadata.yaml: not a file'):
        repair(bag)
    proc = _cli('repair', str(bag))
    assert proc.returncode == 1 and len(proc.stderr.strip().splitlines()) == 1
    assert _snapshot(tmp_path) == before
    assert sorted(p.name for p in bag.iterdir()) == ['bag.mcap', 'metadata.yaml']
