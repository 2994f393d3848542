"""Fill numba's on-disk cache before the tests (``make test`` runs this before pytest).

Hundreds of plant, node and test processes start in the tests; each one that starts before
the cache holds a kernel compiles it again (the in-plant writer and the lockstep plant their
compiled paths, each test worker the drivers, the fit's, the env's and the continuation's).
Compiling everything once costs about 70 CPU s in a clean clone, under 3 s when the cache is
already there.

Numba compiles in the calling process, on one core: so the modules are split into two groups
of about equal compile time, run as two processes side by side (one per core of a 2-core
machine, which halves the wall time):

  kernels  the plants' kernels (models), the recording ring (bag.ringpack), the sweeps'
           and the fits' kernels (analysis.population, analysis.fit.observer), the vector
           env's step (envs.vector)
  drivers  the plant's compiled sample path (ros.plant.fastpath.sample), simulate()'s
           drivers (simulate), the continuation's flow (continuation.flow)

    python scripts/warm_up.py            # both groups, one process each, side by side
    python scripts/warm_up.py kernels    # one group, in this process

Exit 1 if a group failed (its traceback printed), 2 for an unknown group.
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys

#: The modules whose ``warm_up()`` compiles their kernels, by group (one process each).
GROUPS = {
    'kernels': ('fohssv_sim.models', 'fohssv_sim.bag.ringpack',
                'fohssv_sim.analysis.population', 'fohssv_sim.analysis.fit.observer',
                'fohssv_sim.envs.vector'),
    'drivers': ('fohssv_sim.ros.plant.fastpath.sample', 'fohssv_sim.simulate',
                'fohssv_sim.continuation.flow'),
}


def warm(group: str) -> None:
    """Import each module of ``group`` and call its ``warm_up()``, in this process."""
    for name in GROUPS[group]:
        importlib.import_module(name).warm_up()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('group', nargs='?', choices=sorted(GROUPS),
                    help='run one group in this process (default: every group, side by side)')
    args = ap.parse_args(argv)
    if args.group:
        warm(args.group)
        return 0
    first, *others = GROUPS
    children = [subprocess.Popen([sys.executable, __file__, g]) for g in others]
    try:
        warm(first)          # an error here: its traceback and exit 1, once the others ended
    finally:
        codes = [child.wait() for child in children]
    return 1 if any(codes) else 0


if __name__ == '__main__':
    sys.exit(main())
