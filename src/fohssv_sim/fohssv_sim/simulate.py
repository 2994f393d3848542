"""Batch runner: one closed-loop run in-process, no ROS.

``simulate(plant, controller, duration, control_period=...)`` steps a :class:`~.models.Plant`
under a controller either continuously (the controller evaluated at every solver stage, as in
the paper) or through a zero-order hold over a control period (as through ROS, where the
plant holds the last command). The ROS lockstep loop with the same control period reproduces
this runner's trajectory exactly.

The run goes through the plant's compiled kernel in long chunks (:meth:`~.models.Plant.record`):
1 % of the run in continuous mode (an affine law such as eq. 31 evaluated inside the kernel at
every stage), one control period in zero-order hold (the controller called between chunks);
every kept sample (state, planing force, input) is written from compiled code, so keeping
every step costs about as much as keeping a few. The bounds check and the progress callback
come once per chunk. In zero-order hold an affine law whose kept rows fall on control
instants only (``sample_every`` a multiple of the period's steps) is sampled in compiled code
too, thousands of periods per call (:meth:`~.models.Plant.advance_sampled`, what a plant
hosting the law runs). A law the kernels cannot run (a plain callable in continuous mode)
steps interpreted.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .bounds import MAX_PITCH, check_state
from .control import as_law
from .models import AffineLaw, Plant, make_plant
from .params import ModelParameters, steps_per_period

__all__ = ['SimulationResult', 'simulate', 'steps_per_period']


@dataclass
class SimulationResult:
    """Arrays sampled every ``sample_every`` steps (row i at time ``t[i]``).

    ``inputs[i]`` is the (delta_f, delta_c) applied from ``t[i]`` on (held until the next
    control sample in zero-order-hold mode; the controller's value at the state in continuous
    mode). ``planing_force[i]`` is Fp at ``state[i]``.
    """

    t: np.ndarray
    state: np.ndarray
    planing_force: np.ndarray
    inputs: np.ndarray
    params: ModelParameters
    control_period: float | None
    controller: str
    wall_time: float
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def step(self) -> float:
        return self.params.step


ControllerLike = Callable[[float, Sequence[float]], Sequence[float]]


def simulate(plant: Plant | ModelParameters, controller: Any, duration: float, *,
             control_period: float | None = None, initial_state: Sequence[float] | None = None,
             sample_every: int = 1,
             progress: Callable[[float], None] | None = None) -> SimulationResult:
    """Run ``plant`` (a Plant, or ModelParameters to build one) under ``controller`` for
    ``duration`` seconds from ``initial_state`` (default: the plant's, x(0) = 0).

    Args:
        controller: an object with ``command(t, state)`` (a
            :class:`fohssv_sim.control.Controller`), or a callable ``(t, state) ->
            (delta_f, delta_c)``, or ``None`` for zero input.
        control_period: ``None`` = continuous feedback (evaluated at every solver stage); a
            whole multiple of the step = zero-order hold over that period.
        sample_every: keep every k-th step in the result.
        progress: called with the fraction done, about every 1 %.

    Raises:
        ValueError: a bad duration, control period or sample interval; a stateful controller
            in continuous mode.
        FloatingPointError: the state turned non-finite (names the time and state); its
            subclass :class:`~fohssv_sim.models.StateOutOfBounds` when a finite state left
            the physical bounds |w| <= V, |theta| <= pi/2 (checked after every advance: each
            sample or control instant); :class:`fohssv_sim.control.NonFiniteCommand`
            when the controller's output is not finite.
    """
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f'duration={duration!r} s must be a positive number of seconds')
    if isinstance(plant, ModelParameters):
        plant = make_plant(plant, initial_state, duration=duration)
    else:
        plant.reset(initial_state)
    h = plant.h
    n_steps = int(math.ceil(duration / h - 1e-9))
    if int(sample_every) != sample_every or sample_every < 1:
        raise ValueError(f'sample_every={sample_every!r} must be a whole number >= 1')
    sample_every = int(sample_every)

    law, name = as_law(controller)
    if control_period is None:
        if controller is not None and not getattr(controller, 'stateless', True):
            raise ValueError(f'{name} keeps memory between calls; continuous mode evaluates '
                             'it at solver stages: give a control_period (zero-order hold)')
        hold = 0
        # an affine law runs inside the compiled kernels; any other law stage by stage
        drive: Any = ((0.0, 0.0) if controller is None
                      else AffineLaw.from_controller(controller) or law)
    else:
        hold = steps_per_period(control_period, h)

    n_rows = n_steps // sample_every + 1
    x_out, fp_out, u_out = out = _kept_arrays(n_rows)
    # the compiled kernel runs a whole chunk and writes its kept rows: a control period in
    # zero-order hold (the law is evaluated between chunks), else 1 % of the run
    chunk = hold or max(1, -(-n_steps // 100))
    report_every = max(1, n_steps // 100)
    start = time.perf_counter()
    row = n = 0
    if hold and sample_every % hold == 0 and controller is not None:
        # zero-order hold, rows on control instants only: an affine law sampled in compiled
        # code over the whole periods (0 steps when the plant has no compiled kernel)
        affine = AffineLaw.from_controller(controller)
        if affine is not None:
            n = _sampled_periods(plant, affine, law, hold, n_steps, sample_every, out,
                                 progress)
            row = -(-n // sample_every)
    while n < n_steps:
        if hold:
            u = law(plant.t, plant.x)
            drive = (float(u[0]), float(u[1]))
        nxt = min(n_steps, n + chunk)
        row = plant.record(drive, nxt - n, out, row, -n % sample_every, sample_every)
        if progress is not None and nxt // report_every != n // report_every:
            progress(nxt / n_steps)
        n = nxt
    if n_steps % sample_every == 0:     # the last state: its row has not been written
        x = plant.x
        u = law(plant.t, x) if not hold or n_steps % hold == 0 else drive
        x_out[row] = x
        fp_out[row] = plant.planing_force
        u_out[row] = u
    wall = time.perf_counter() - start
    t = np.arange(0, n_rows * sample_every, sample_every, dtype=float)
    t *= h                                   # n h exactly, as plant.t, in one array
    return SimulationResult(t=t, state=x_out,
                            planing_force=fp_out, inputs=u_out,
                            params=plant.params, control_period=control_period,
                            controller=name, wall_time=wall,
                            metadata={'steps': n_steps, 'sample_every': sample_every,
                                      'initial_state': list(plant.initial_state)})


def _kept_arrays(n_rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States (n, 4), planing forces (n,) and inputs (n, 2), each C-contiguous, as views of
    one block: numpy asks Linux for huge pages for a block of 4 MB or more, so the kernel's
    first writes into a long run's samples fault once per 2 MB instead of once per 4 kB
    (a page fault costs the kernel a few steps' time)."""
    block = np.empty(7 * n_rows)
    return (block[:4 * n_rows].reshape(n_rows, 4), block[4 * n_rows:5 * n_rows],
            block[5 * n_rows:].reshape(n_rows, 2))


#: Control periods per call of the sampled driver (their samples: 4096 x 7 doubles, in cache).
_BURST = 4096


def _sampled_periods(plant: Plant, affine: AffineLaw, law: Callable, hold: int, n_steps: int,
                     every: int, out: tuple, progress: Callable[[float], None] | None) -> int:
    """The whole control periods of ``hold`` steps of a run of ``n_steps`` from its start
    through the plant's sampled driver (:meth:`~.models.Plant.advance_sampled`): ``affine``
    sampled in compiled code at t = 0 (a sample of zero steps) and at each period's end, held
    over the next; the rows kept (every ``every``-th step, a multiple of ``hold``) copied out
    of each burst's samples. Returns the step reached (0 when the plant has no compiled
    kernel).

    Raises what the period-by-period loop raises, at the same sample: FloatingPointError
    (a non-finite state), StateOutOfBounds, NonFiniteCommand (``law`` at a sample whose
    command the driver refused)."""
    x_out, fp_out, u_out = out
    k = every // hold
    periods = n_steps // hold
    limits = np.array([math.inf, math.inf, plant.params.speed, MAX_PITCH])
    burst = np.empty((min(periods, _BURST), 7))
    report_every = max(1, n_steps // 100)
    done = -1                               # periods done; the sample at t = 0 first
    held = (0.0, 0.0)
    while done < periods:
        steps, want = (0, 1) if done < 0 else (hold, min(len(burst), periods - done))
        taken, status = plant.advance_sampled(affine, held, steps, want, limits, burst)
        if status == -1:
            return 0
        q0 = done if steps else -1              # sample i ends period q0 + i + 1 (t = 0: 0)
        i0 = -(q0 + 1) % k                      # the first sample on a kept row
        complete = taken - (status != 0)        # a stopping sample lacks its command
        rows = burst[i0:complete:k]
        r0 = (q0 + i0 + 1) // k
        x_out[r0:r0 + len(rows)] = rows[:, :4]
        fp_out[r0:r0 + len(rows)] = rows[:, 4]
        u_out[r0:r0 + len(rows)] = rows[:, 5:7]
        before, done = max(done, 0), max(done, 0) + (taken if steps else 0)
        if progress is not None and done * hold // report_every != before * hold // report_every:
            progress(done * hold / n_steps)
        if status == 1:
            plant.raise_failure()
        if status in (2, 3):
            if status == 2:
                check_state(plant)              # raises StateOutOfBounds
            u = law(plant.t, plant.x)           # says why (NonFiniteCommand)
            burst[taken - 1, 5:7] = u
            if (q0 + taken) % k == 0:
                u_out[(q0 + taken) // k] = u
        held = (float(burst[taken - 1, 5]), float(burst[taken - 1, 6]))
    return done * hold


class _ZeroAffine:
    """u = 0 x + 0 as an affine controller: what :func:`warm_up` passes to reach the drivers
    with the argument types an affine law gives them."""

    stateless = True

    def affine(self) -> tuple[np.ndarray, np.ndarray]:
        return np.zeros((2, 4)), np.zeros(2)

    def command(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        return 0.0, 0.0


def warm_up() -> None:
    """Compile (or load from numba's cache) the drivers :func:`simulate` runs for every model
    under an affine law in zero-order hold: the sampled ones (rows on control instants) and the
    recorded ones (a row every step), so that the first simulate() of a process pays no
    compilation (``make test`` calls it once before the workers start)."""
    for model in ('delay-free', 'delayed', 'fractional'):
        params = ModelParameters(model=model)
        hold = steps_per_period(1e-4, params.step)
        for every in (1, hold):
            simulate(params, _ZeroAffine(), 2e-3, control_period=1e-4, sample_every=every)
