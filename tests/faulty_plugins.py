"""Controller plugins with a bug, registered the way ``pip install`` registers a plugin (a
dist-info with ``entry_points.txt``): :func:`register` writes them under a directory to put
on the path (``sys.path`` in the test process, ``PYTHONPATH`` for a node process)."""

from __future__ import annotations

from pathlib import Path

__test__ = False  # nothing to collect

MODULE = '''
import sys
import time

from fohssv_controller.state_feedback import StateFeedback


class BadReset(StateFeedback):
    """Eq. 31, whose reset() raises once built (the constructor resets it first)."""
    name = 'bad_reset'

    def __init__(self, parameters=None):
        super().__init__(parameters)
        self.built = True

    def reset(self):
        if getattr(self, 'built', False):
            raise RuntimeError('memory stuck')
        super().reset()


class BadInit(StateFeedback):
    """A plugin whose constructor raises."""
    name = 'bad_init'

    def __init__(self, parameters=None):
        raise RuntimeError('no gains file')


class Quits(StateFeedback):
    """Eq. 31 per sample (not affine) that calls sys.exit(3) from t = 0.005 s on."""
    name = 'quits'

    def affine(self):
        return None

    def update(self, t, state):
        if t >= 0.005:
            sys.exit(3)
        return super().update(t, state)


class Interrupts(Quits):
    """Eq. 31 per sample that raises KeyboardInterrupt from t = 0.005 s on."""
    name = 'interrupts'

    def update(self, t, state):
        if t >= 0.005:
            raise KeyboardInterrupt
        return StateFeedback.update(self, t, state)


class Slow(Quits):
    """Eq. 31 per sample that takes 300 us a call (three 1e-4 s control periods)."""
    name = 'slow'

    def update(self, t, state):
        end = time.perf_counter() + 3e-4
        while time.perf_counter() < end:
            pass
        return StateFeedback.update(self, t, state)


class Hangs(Quits):
    """Eq. 31 per sample whose call at t >= 0.005 s never returns (sleeps forever)."""
    name = 'hangs'

    def update(self, t, state):
        while t >= 0.005:
            time.sleep(0.05)
        return StateFeedback.update(self, t, state)


class Stalls(Quits):
    """Eq. 31 per sample whose first call at t >= 0.2 s takes 0.12 s (a stall, once)."""
    name = 'stalls'
    stalled = False

    def update(self, t, state):
        if t >= 0.2 and not self.stalled:
            self.stalled = True
            time.sleep(0.12)
        return StateFeedback.update(self, t, state)
'''


def register(root: Path) -> Path:
    """Write the module ``faulty_laws`` and its dist-info under ``root``; returns ``root``."""
    (root / 'faulty_laws.py').write_text(MODULE)
    dist = root / 'faulty_laws-0.1.dist-info'
    dist.mkdir()
    (dist / 'METADATA').write_text('Metadata-Version: 2.1\nName: faulty-laws\nVersion: 0.1\n')
    (dist / 'entry_points.txt').write_text(
        '[fohssv.controllers]\nbad_reset = faulty_laws:BadReset\n'
        'bad_init = faulty_laws:BadInit\nquits = faulty_laws:Quits\n'
        'interrupts = faulty_laws:Interrupts\nslow = faulty_laws:Slow\n'
        'hangs = faulty_laws:Hangs\nstalls = faulty_laws:Stalls\n')
    return root
