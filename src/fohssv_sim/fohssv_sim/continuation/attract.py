"""Stability of the FOM's orbits by simulation: harmonic balance gives no Floquet multipliers
(a Caputo system has no monodromy matrix: its state is its whole past), so an orbit is called
stable when a simulation of the model started on it stays on it.

Along a branch, stability can change only at a bifurcation, and harmonic balance detects the
ones it can (the Hopf point at the branch's end, folds from the tangent); period doubling and
torus bifurcations it cannot see (no multipliers). So the branch is cut at its detected
bifurcations and one orbit per segment, the segment's middle point, is tested: the model is
simulated from the orbit's state at phase 0 (w at its top, the state scaled 2 % away from the
orbit's mean, a small kick) with the Caputo memory empty, for ``duration`` seconds; if the
half range of w over the last ``window`` seconds is within ``tolerance`` of the orbit's, the
orbit attracts: stable; otherwise (the run decays to the equilibrium or goes to another
orbit) unstable. The verdict holds for the whole segment. A Caputo run from a fixed start
approaches the periodic solution algebraically, not exponentially, hence the loose tolerance
(10 %): an unstable orbit within 10 % of a stable one (near a fold) would be called stable,
which is why the segment's middle point, away from its ends, is the one tested.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ['simulated_verdict', 'segment_verdicts']


def simulated_verdict(system: Any, prob: Any, u: np.ndarray, p: float, *,
                      duration: float = 2.0, window: float = 0.5, kick: float = 0.02,
                      tolerance: float = 0.1) -> dict[str, Any]:
    """Simulate the model at ``p`` from the orbit u (harmonic-balance unknowns of ``prob``)
    with a ``kick``: ``{'stable': bool, 'orbit_amplitude', 'simulated_amplitude'}``."""
    from ..simulate import simulate

    mp, _ = system.at(p)
    if system.parameter == 'fractional_order':
        mp = mp.replace(fractional_order=float(p))
    x = prob.signal(u, 1024)
    mean = x.mean(axis=1)
    x0 = mean + (1.0 + kick) * (x[:, 0] - mean)
    amp = 0.5 * float(x[1].max() - x[1].min())
    r = simulate(mp, system.law(p)[0], duration, initial_state=x0.tolist(), sample_every=10)
    w = r.state[r.t > duration - window, 1]
    got = 0.5 * float(w.max() - w.min())
    return {'stable': bool(abs(got - amp) <= tolerance * amp), 'orbit_amplitude': amp,
            'simulated_amplitude': got}


def segment_verdicts(points: list, cuts: list[int], verdict: Any) -> list[dict[str, Any]]:
    """Cut ``points`` (branch points) before each index in ``cuts`` and ask ``verdict(point)``
    for the middle point of each segment: per segment ``{'first', 'last', 'tested',
    **verdict}`` (indices into ``points``)."""
    bounds = [0] + sorted(c for c in set(cuts) if 0 < c < len(points)) + [len(points)]
    out = []
    for a, b in zip(bounds, bounds[1:]):
        mid = (a + b - 1) // 2
        out.append({'first': a, 'last': b - 1, 'tested': mid, **verdict(points[mid])})
    return out
