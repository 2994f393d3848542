"""The recorder and the player refuse a bad ``-p`` value before anything of ROS starts: no
context, no DDS participant, so a refused start has nothing to tear down (a recorder refusing
``flush_period:=abc`` died of SIGSEGV once, one of ten refused at once in a test run; 200
such starts, ten at a time under load, did not reproduce it, and a start that creates no DDS
entity cannot crash in one). Shown with ROS_DOMAIN_ID=233, a domain no Fast DDS participant can
be created in ("Calculated port number is too high"): the start is refused by its parameter
alone, one line and exit 2, with no word from DDS. The plant, which checks its parameters
after its node exists, meets DDS's error first (exit 1): the difference the test sees."""

from __future__ import annotations

import subprocess

import pytest

import rosproc

pytestmark = pytest.mark.graph


def _run(name: str, args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([str(rosproc.executable('fohssv_sim', name)), '--ros-args', *args],
                          capture_output=True, text=True, timeout=120,
                          env=rosproc.ros_env(233))


@pytest.mark.parametrize(('name', 'args', 'words'), [
    ('recorder', ['-p', 'flush_period:=abc'],
     "flush_period='abc' is a string, not a number; allowed: (0, 60] s"),
    ('recorder', ['-p', 'chunk_size:=1.5'], 'chunk_size=1.5 is not a whole number'),
    ('player', ['-p', 'rate:=fast'], "rate='fast' is a string, not a number; allowed: [0, inf)"),
])
def test_a_bad_value_is_refused_before_any_dds_entity(tmp_path, name, args, words):
    done = _run(name, [*args, '-p', f'bag_path:={tmp_path / "bag"}'])
    out = done.stdout + done.stderr
    lines = [ln for ln in out.splitlines() if ln.strip()]
    assert done.returncode == 2, out
    assert len(lines) == 1 and words in lines[0] and f'[{name}]' in lines[0], out
    assert 'RTPS' not in out and 'port number' not in out, out
    assert not (tmp_path / 'bag').exists()


def test_without_the_early_check_dds_fails_first_in_that_domain():
    """The control: the plant's bad speed is checked after its node (and participant) is
    made, and in domain 233 that fails first."""
    done = _run('plant', ['-p', 'speed:=abc'])
    out = done.stdout + done.stderr
    assert done.returncode != 2 and 'port number is too high' in out, out
