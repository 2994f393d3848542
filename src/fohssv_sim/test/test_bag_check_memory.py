"""Issue 21 class 4: ``fohssv check`` streams the bag, so its memory does not grow with the
bag's size (it needed about 6 times the bag's size: a one-hour 10 kHz bag must be checkable
on a 24 GB machine).

Two real bags, one 10 times the other (about 8 and 80 MB of MCAP; large messages keep the
message count and so the test short), each checked by ``fohssv check`` in its own process;
the peak resident set of each (``resource.getrusage`` of the child) is compared. Reading the
large bag into memory once would add its whole size; the streamed check adds a small share.
"""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import numpy as np

from fohssv_sim import contract
from fohssv_sim.bag.synthetic import float64_array
from fohssv_sim.bag.writer import RunWriter

#: Doubles per message: 64 KiB messages, 125 per 8 MB.
WIDTH = 8192


def write_blob_bag(path: Path, n_messages: int) -> int:
    """A bag of ``n_messages`` random (incompressible) 64 KiB arrays; its MCAP size."""
    rng = np.random.default_rng(1)
    w = RunWriter(path).open()
    w.add_topic('/state', contract.STATE.type)
    block = rng.standard_normal((16, WIDTH))
    for i in range(n_messages):
        values = block[i % 16].copy()
        values[0] = i * 1e-4
        w.write('/state', i * 100_000, float64_array(contract.STATE, values))
    w.close()
    return sum(f.stat().st_size for f in path.glob('*.mcap'))


CHILD = '''
import resource, sys
from fohssv_sim.cli import main
code = main(['check', sys.argv[1]])
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, code)
'''


def peak_rss_of_check(bag: Path) -> int:
    out = subprocess.run([sys.executable, '-c', CHILD, str(bag)], capture_output=True,
                         text=True, timeout=300)
    rss, code = out.stdout.strip().splitlines()[-1].split()
    assert code == '0', out.stdout + out.stderr
    return int(rss)


def test_check_memory_does_not_grow_with_the_bag(tmp_path):
    small_size = write_blob_bag(tmp_path / 'small', 125)
    large_size = write_blob_bag(tmp_path / 'large', 1250)
    assert large_size > 9 * small_size > 60e6
    small = peak_rss_of_check(tmp_path / 'small')
    large = peak_rss_of_check(tmp_path / 'large')
    growth = large - small
    # held in memory, the extra 72 MB would show in full (6 times over before the fix)
    assert growth < 0.2 * (large_size - small_size), (small, large, small_size, large_size)
    assert large < 3 * small, (small, large)
    assert resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss > 0
