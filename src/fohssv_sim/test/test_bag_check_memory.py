"""Issue 21 class 4: ``fohssv check`` streams the bag, so its memory does not grow with the
bag's size (it needed about 6 times the bag's size: a one-hour 10 kHz bag must be checkable
on a 24 GB machine).

Two real bags, one 10 times the other (about 8 and 80 MB of MCAP), each checked by ``fohssv
check`` in its own process; the peak resident set of each (``resource.getrusage`` of the
child) is compared. Reading the large bag into memory once would add its whole size; the
streamed check adds a small share. The messages are large byte arrays (UInt8MultiArray):
few of them, and each decodes (check decodes every message) as one slice, where a
Float64MultiArray decodes double by double in Python (80 MB of doubles cost 4 s of CPU,
the bytes a tenth of that: the check's memory does not depend on the type).
"""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import numpy as np

from fohssv_sim.bag.writer import RunWriter, typestore

#: Bytes per message: 64 KiB messages, 125 per 8 MB.
WIDTH = 65536
BYTES = 'std_msgs/msg/UInt8MultiArray'


def write_blob_bag(path: Path, n_messages: int) -> int:
    """A bag of ``n_messages`` random (incompressible) 64 KiB byte arrays; its MCAP size."""
    rng = np.random.default_rng(1)
    ts = typestore()
    layout = ts.types['std_msgs/msg/MultiArrayLayout'](dim=[], data_offset=0)
    w = RunWriter(path).open()
    w.add_topic('/blob', BYTES)
    block = rng.integers(0, 256, (16, WIDTH), dtype=np.uint8)
    for i in range(n_messages):
        values = block[i % 16].copy()
        values[:8] = np.frombuffer(np.int64(i).tobytes(), dtype=np.uint8)   # each one unique
        msg = ts.types[BYTES](layout=layout, data=values)
        w.write('/blob', i * 100_000, bytes(ts.serialize_cdr(msg, BYTES)))
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
