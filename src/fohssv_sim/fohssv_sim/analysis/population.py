"""Many FOM parameter points run together: one compiled call per batch (issue 23).

A *population* is a list of :class:`~fohssv_sim.params.ModelParameters` of the fractional
model ('soe' solver) that share the step and the planing form and may differ in anything else
(the order alpha, V, the geometry, the planing offset, ...). :func:`run_population` runs them
all from the same initial state over ``n_periods`` control periods of ``hold`` steps each, in
one compiled call (:func:`_population_kernel`, numba), driven either

* **open loop** by a table of held inputs ``inputs[k] = (delta_f, delta_c)`` applied over
  period k (the recorded commands of a bag, zero-order hold as the lockstep plant applies
  them), or
* **closed loop** by an affine law u = clamp(K x + u0) (:class:`fohssv_sim.models.AffineLaw`),
  evaluated at the start of each period and held over it (as through ROS) or, with
  ``continuous=True``, at every solver stage.

Every point keeps its own SOE history (:class:`fohssv_sim.fractional.soe.SOEHistory` with one
group per point; mode sets padded with zero-weight modes) and is advanced by the plant's own
kernel :func:`fohssv_sim.kernels.fom_soe_run` on its slice of those arrays, so each point equals
the plant stepped period by period (``Plant.advance``) to the last bit (tested against that
interpreted driver in ``test/test_fit.py``). A point whose state turns non-finite or leaves
the physical bounds (|w| <= V, |theta| <= pi/2, as :func:`fohssv_sim.models.check_state`) is
marked failed and its remaining samples are NaN.

Cost: the kernel's (about 1-2 us per step per point on one core); memory P x (n_periods + 1)
x 4 doubles for the samples plus the SOE arrays (a few kB per point).

Pure: numpy, numba; no rclpy.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from .. import kernels
from ..coefficients import coefficients
from ..fractional.soe import SOEHistory
from ..fractional.soe_kernel import soe_modes
from ..params import ModelParameters
from ..solvers import soe_options

T = TypeVar('T')

__all__ = ['PopulationResult', 'run_population', 'run_population_reference',
           'check_population']


@dataclass
class PopulationResult:
    """``states[p, k]``: point p at t = k * hold * step (k = 0 .. n_periods); ``failed[p]``:
    the point diverged (NaN from the failing period on); ``inputs[p, k]``: the input held over
    period k (NaN after a failure)."""

    t: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    failed: np.ndarray


def check_population(params: Sequence[ModelParameters]) -> None:
    """Raise ValueError unless every point is the fractional model with the 'soe' solver and
    all share the step and the planing form."""
    if not params:
        raise ValueError('a population needs at least one point')
    for p in params:
        if p.model != 'fractional' or p.solver != 'soe':
            raise ValueError(f"population points must be model='fractional' with solver='soe' "
                             f'(the compiled kernel); got model={p.model!r}, solver={p.solver!r}')
    for name in ('step', 'planing_form', 'soe_tolerance', 'soe_horizon_steps'):
        values = {getattr(p, name) for p in params}
        if len(values) > 1:
            raise ValueError(f'population points must share {name}; got {sorted(map(str, values))}')


if kernels.numba is not None:
    _njit = kernels.numba.njit(cache=True, nogil=True, error_model='numpy')
else:  # pragma: no cover - numba is pinned
    def _njit(fn):
        return fn


@_njit
def _population_kernel(X0, CV, smooth, inputs, law, closed, continuous, hold, n_periods,
                       H, W, fill, eps_k, ET, a0_coef, a0_small, alphas, cp, cc, speeds,
                       out, used, failed):
    """Advance every point p over ``n_periods`` periods of ``hold`` steps (see the module
    docstring); samples into ``out[p, k]``, held inputs into ``used[p, k]``."""
    P = X0.shape[0]
    x = np.empty(4)
    last_f = np.empty(4)
    bad = np.empty(4)
    held = np.zeros(12)
    held[10] = math.inf
    held[11] = math.inf
    for p in range(P):
        for i in range(4):
            x[i] = X0[p, i]
            out[p, 0, i] = x[i]
        n = 0
        for k in range(n_periods):
            if closed and continuous:
                used[p, k, 0], used[p, k, 1] = kernels._input(law, True, x[0], x[1], x[2], x[3])
                taken = kernels.fom_soe_run(
                    x, X0[p], n, hold, CV[p], smooth, law, True, H[p:p + 1], W[:, p:p + 1],
                    fill[p:p + 1], eps_k[p:p + 1], ET[p:p + 1], a0_coef[p:p + 1],
                    a0_small[p:p + 1], alphas[p], cp[p], cc[p], last_f, bad)
            else:
                if closed:
                    uf, uc = kernels._input(law, True, x[0], x[1], x[2], x[3])
                else:
                    uf, uc = inputs[k, 0], inputs[k, 1]
                held[8] = uf
                held[9] = uc
                used[p, k, 0] = uf
                used[p, k, 1] = uc
                taken = kernels.fom_soe_run(
                    x, X0[p], n, hold, CV[p], smooth, held, False, H[p:p + 1], W[:, p:p + 1],
                    fill[p:p + 1], eps_k[p:p + 1], ET[p:p + 1], a0_coef[p:p + 1],
                    a0_small[p:p + 1], alphas[p], cp[p], cc[p], last_f, bad)
            n += taken
            v = speeds[p]
            if taken < hold or not (-v <= x[1] <= v and -1.5707963267948966 <= x[2]
                                    <= 1.5707963267948966):
                failed[p] = True
                for j in range(k + 1, n_periods + 1):
                    for i in range(4):
                        out[p, j, i] = np.nan
                for j in range(k, n_periods):
                    used[p, j, 0] = np.nan
                    used[p, j, 1] = np.nan
                break
            for i in range(4):
                out[p, k + 1, i] = x[i]


def _soe_arrays(params: Sequence[ModelParameters], duration: float | None):
    """One SOE history with a group per point (padded modes), and each point's factors."""
    from scipy.special import gamma

    h = params[0].step
    alphas = np.array([p.fractional_order for p in params], dtype=float)
    opts = soe_options(params[0], duration)
    with np.errstate(divide='ignore', invalid='ignore'):   # the quadrature's edge at tiny alpha
        modes = [soe_modes(a, opts['tolerance'], opts['horizon_steps'], 16)
                 for a in alphas.tolist()]
    cp = h ** alphas / gamma(alphas + 1.0)
    cc = h ** alphas / gamma(alphas + 2.0)
    hist = SOEHistory(alphas, modes, 4, cp, cc)
    return hist, alphas, cp, cc


def over_threads(run: Callable[[int, int], T], points: int, threads: int) -> list[T]:
    """``run(a, b)`` of contiguous slices of ``points`` points, one slice per thread (at most
    ``threads``), in order: the compiled kernels release the GIL, and the points are
    independent, so the numbers are those of one call."""
    from concurrent.futures import ThreadPoolExecutor

    m = max(1, min(int(threads), points))
    cuts = np.linspace(0, points, m + 1).round().astype(int)
    with ThreadPoolExecutor(m) as pool:
        return list(pool.map(lambda ab: run(*ab), zip(cuts[:-1].tolist(), cuts[1:].tolist())))


def run_population(params: Sequence[ModelParameters], n_periods: int, hold: int, *,
                   inputs: np.ndarray | None = None, law: np.ndarray | None = None,
                   continuous: bool = False, initial_state: Sequence[float] = (0, 0, 0, 0),
                   duration: float | None = None, threads: int = 1) -> PopulationResult:
    """Run every point of ``params`` for ``n_periods`` periods of ``hold`` steps in one
    compiled call; see the module docstring.

    Args:
        inputs: (n_periods, 2) held inputs (open loop), or None with ``law``.
        law: the packed affine law of :class:`fohssv_sim.models.AffineLaw` (``.packed``).
        continuous: with ``law``, evaluate it at every solver stage (else held per period).
        duration: the run length the 'soe' horizon is sized for (:func:`soe_options`; None =
            open-ended), as the plant that recorded the data sized it.
        threads: split the points into this many contiguous slices, one compiled call each,
            run in parallel threads (the kernel releases the GIL); the same numbers bit for
            bit, as the points are independent.

    Raises:
        ValueError: points that do not form a population (:func:`check_population`), both or
            neither of ``inputs`` and ``law``, inputs of the wrong shape or non-finite.
    """
    params = list(params)
    check_population(params)
    kw = {'inputs': inputs, 'law': law, 'continuous': continuous,
          'initial_state': initial_state, 'duration': duration}
    if threads > 1 and len(params) > 1:
        parts = over_threads(lambda a, b: run_population(params[a:b], n_periods, hold, **kw),
                             len(params), threads)
        return PopulationResult(t=parts[0].t,
                                states=np.concatenate([r.states for r in parts]),
                                inputs=np.concatenate([r.inputs for r in parts]),
                                failed=np.concatenate([r.failed for r in parts]))
    if (inputs is None) == (law is None):
        raise ValueError('give exactly one of inputs (open loop) and law (closed loop)')
    n_periods, hold = int(n_periods), int(hold)
    if n_periods < 0 or hold < 1:
        raise ValueError(f'n_periods={n_periods} must be >= 0 and hold={hold} >= 1')
    if inputs is not None:
        inputs = np.ascontiguousarray(inputs, dtype=float)
        if inputs.shape != (n_periods, 2) or not np.isfinite(inputs).all():
            raise ValueError(f'inputs must be a finite ({n_periods}, 2) array, got '
                             f'{inputs.shape}')
        law_arr = kernels.pack_law()
    else:
        law_arr = np.ascontiguousarray(law, dtype=float)
        inputs = np.zeros((0, 2))
    P = len(params)
    X0 = np.tile(np.asarray(initial_state, dtype=float), (P, 1))
    CV = np.array([coefficients(p).kernel for p in params], dtype=float)
    hist, alphas, cp, cc = _soe_arrays(params, duration)
    fill = np.zeros(P, dtype=np.int64)
    speeds = np.array([p.speed for p in params], dtype=float)
    out = np.empty((P, n_periods + 1, 4))
    used = np.empty((P, n_periods, 2))
    failed = np.zeros(P, dtype=np.bool_)
    _population_kernel(X0, CV, params[0].planing_form == 'smooth', inputs, law_arr,
                       law is not None, bool(continuous), hold, n_periods, hist.H, hist.W,
                       fill, hist.eps_k, hist.ET, hist.a0_coef, hist.a0_small, alphas, cp, cc,
                       speeds, out, used, failed)
    t = np.arange(n_periods + 1) * (hold * params[0].step)
    return PopulationResult(t=t, states=out, inputs=used, failed=failed)


def run_population_reference(params: Sequence[ModelParameters], n_periods: int, hold: int,
                             *, inputs: np.ndarray | None = None, law=None,
                             controller: Callable[[], Any] | None = None,
                             initial_state: Sequence[float] = (0, 0, 0, 0),
                             duration: float | None = None) -> PopulationResult:
    """The same numbers point by point through the plant contract (``make_plant`` and
    ``Plant.advance`` per period, inputs held): the readable reference :func:`run_population`
    is tested against.

    ``controller``, instead of ``inputs`` or ``law``: a factory of
    :class:`fohssv_sim.control.Controller` (e.g. ``lambda: control.make(name, gains)``),
    called once per point (a law with memory starts afresh), whose clamped
    ``command(t, x)`` is held over each period as through ROS: the closed loop of a plugin
    that is not affine (no compiled form), point by point."""
    from ..models import check_state, make_plant

    if sum(v is not None for v in (inputs, law, controller)) != 1:
        raise ValueError('give exactly one of inputs (open loop), law or controller')
    P = len(params)
    out = np.full((P, n_periods + 1, 4), np.nan)
    used = np.full((P, n_periods, 2), np.nan)
    failed = np.zeros(P, dtype=bool)
    for i, p in enumerate(params):
        plant = make_plant(p, initial_state, duration=duration)
        ctl = controller() if controller is not None else None
        out[i, 0] = plant.x
        for k in range(n_periods):
            try:
                if inputs is not None:
                    u = (float(inputs[k, 0]), float(inputs[k, 1]))
                elif ctl is not None:
                    u = ctl.command(plant.t, plant.x)
                else:
                    x = plant.x
                    u = kernels._input(law, True, x[0], x[1], x[2], x[3])
                used[i, k] = u
                plant.advance(u, hold)
                check_state(plant)
            except FloatingPointError:
                failed[i] = True
                used[i, k] = np.nan
                break
            out[i, k + 1] = plant.x
    t = np.arange(n_periods + 1) * (hold * params[0].step)
    return PopulationResult(t=t, states=out, inputs=used, failed=failed)


def warm_up() -> None:
    """Compile (or load from numba's cache) :func:`_population_kernel` with the argument types
    the sweeps and fits pass (``make test`` calls it once, before the test workers start)."""
    run_population([ModelParameters(model='fractional')], 2, 5, inputs=np.zeros((2, 2)))
