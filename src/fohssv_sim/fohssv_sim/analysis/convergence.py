"""Step-halving study: how much halving the step changes an established oscillation.

Used by the test that guards the default steps (``test/test_convergence.py``) and by
``bench/bench_convergence.py``, which prints the figures the README quotes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..batch import simulate_batch
from ..params import ModelParameters

__all__ = ['halving_change']


def halving_change(params: ModelParameters, controller: Any, duration: float = 2.0,
                   window: float = 0.5, sample: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Run ``params`` at its step and at half of it (x(0) = 0, continuous feedback) and return
    (max |difference| / peak-to-peak, peak-to-peak) per state component over the last
    ``window`` seconds, compared on a common grid of ``sample`` seconds."""
    runs = []
    for step in (params.step, params.step / 2):
        p = params.replace(step=step)
        r = simulate_batch([p], [controller], duration, sample_every=round(sample / step))
        runs.append(r)
    a, b = runs
    if not np.array_equal(a.t, b.t):
        raise ValueError(f'sample={sample} s is not a whole multiple of both steps')
    last = a.t >= duration - window - 1e-12
    ptp = np.ptp(b.states[0, last], axis=0)
    diff = np.abs(a.states[0, last] - b.states[0, last]).max(axis=0)
    return diff / ptp, ptp
