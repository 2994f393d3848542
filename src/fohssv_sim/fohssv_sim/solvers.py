"""The solver table: every integrator by name, the models it serves and how each part of
fohssv steps it. Models (:mod:`.models`), the batch runner (:mod:`.batch`), the parameter
table (:mod:`.params`, ``solver='auto'`` = the first solver listed for the model) and the
docs read this one table.

Light on purpose (no numpy import at module level): :mod:`.params` imports it; the stepper
classes are imported when first asked for.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from importlib import import_module
from typing import Any

__all__ = ['Solver', 'SOLVERS', 'SOLVERS_BY_MODEL', 'UnknownSolverError', 'get_solver',
           'soe_options', 'SOE_HORIZON_MIN', 'SOE_HORIZON_OPEN']

#: Smallest 'auto' horizon of the 'soe' history (steps): finite runs shorter than this get it.
SOE_HORIZON_MIN = 10**8
#: 'auto' horizon of an open-ended run (steps): 2e7 s (231 days) at the FOM's 2e-5 s step.
SOE_HORIZON_OPEN = 10**12


class UnknownSolverError(KeyError, ValueError):
    """An unknown solver name (a ValueError, and a KeyError so Mapping.get works)."""

    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0]) if self.args else ''


def _load(path: str | None) -> Any:
    if path is None:
        return None
    module, _, name = path.partition(':')
    return getattr(import_module(module, __package__), name)


@dataclass(frozen=True)
class Solver:
    """One integrator.

    ``models``: the models it integrates; ``compiled``: the plant steps it with a compiled
    kernel (:mod:`.kernels`); ``accuracy`` and ``cost``: one-line statements (``doc`` joins
    them); ``stepper`` / ``batch`` / ``offline``: the online stepper class, the batched stepper
    class and the whole-horizon function of the fractional solvers (None where there is none;
    the integer models' RK4 lives in :mod:`.models` and :mod:`.batch`).
    """

    name: str
    models: tuple[str, ...]
    compiled: bool
    accuracy: str
    cost: str
    stepper_path: str | None = None
    batch_path: str | None = None
    offline_path: str | None = None

    @property
    def stepper(self) -> Any:
        return _load(self.stepper_path)

    @property
    def batch(self) -> Any:
        return _load(self.batch_path)

    @property
    def offline(self) -> Any:
        return _load(self.offline_path)

    @property
    def doc(self) -> str:
        return f'{self.name}: {self.accuracy}; {self.cost}'


class _Table(Mapping):
    def __init__(self, entries: tuple[Solver, ...]) -> None:
        self._entries = {s.name: s for s in entries}

    def __getitem__(self, name: str) -> Solver:
        try:
            return self._entries[name]
        except (KeyError, TypeError):
            raise UnknownSolverError(
                f"solver={name!r} is not one of {', '.join(repr(k) for k in self._entries)}"
            ) from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"SOLVERS({', '.join(self._entries)})"


#: name -> :class:`Solver`, in order of preference: ``solver='auto'`` is the first entry that
#: serves the model. Unknown names raise :class:`UnknownSolverError` listing the valid ones.
SOLVERS: Mapping[str, Solver] = _Table((
    Solver('rk4', ('delay-free', 'delayed'), True,
           accuracy='classical Runge-Kutta, O(h^4) between planing contacts (the delayed '
                    'model with cubic-Hermite history)',
           cost='4 right-hand sides per step, O(1); memory O(tau / h) for the delayed model'),
    Solver('soe', ('fractional',), True,
           accuracy='the ABM scheme with the history tail weights to a relative tolerance '
                    '(default 1e-10) over soe_horizon_steps (auto: the run, at least 1e8 '
                    'steps; 1e12 when open-ended): within about 1e-11 of abm',
           cost='online, O(1) per step (~60-120 exponential modes + 16..48 exact lags), '
                'memory O(1); compiled in the plant',
           stepper_path='.fractional.soe:SOEStepper', batch_path='.fractional.soe:BatchSOE'),
    Solver('abm', ('fractional',), False,
           accuracy='exact Diethelm-Ford-Freed ABM predictor-corrector, error O(h^(1+alpha))',
           cost='online, O(n) per step at step n, O(N^2) in all, memory O(N); interpreted',
           stepper_path='.fractional.abm:ABMStepper', batch_path='.fractional.abm:BatchABM'),
    Solver('abm-fft', ('fractional',), False,
           accuracy='same numbers as abm (to rounding, <= 1e-12 relative)',
           cost='offline: O(N log^2 N) in all via FFT-blocked history sums (inner loop '
                'compiled when rhs is a numba.njit function); online stepping is abm',
           stepper_path='.fractional.abm:ABMStepper', batch_path='.fractional.abm:BatchABM',
           offline_path='.fractional.fft:solve_abm_fft'),
))

#: model -> the solvers it accepts, preferred first (derived from :data:`SOLVERS`).
SOLVERS_BY_MODEL: dict[str, tuple[str, ...]] = {
    model: tuple(s.name for s in SOLVERS.values() if model in s.models)
    for model in ('fractional', 'delay-free', 'delayed')
}


def get_solver(name: str) -> Solver:
    """The :class:`Solver` called ``name``.

    Raises:
        UnknownSolverError: unknown name (a ValueError; the message lists the valid names).
    """
    return SOLVERS[name]


def soe_options(params: Any, duration: float | None = None) -> dict[str, Any]:
    """Keyword arguments of the 'soe' steppers for ``params``: tolerance and horizon.

    ``soe_horizon_steps='auto'`` is the run's length in steps (``duration`` / step, at least
    :data:`SOE_HORIZON_MIN`), or :data:`SOE_HORIZON_OPEN` when ``duration`` is None or 0 (an
    open-ended run), so the kernel tolerance holds over the whole run.
    """
    horizon = params.soe_horizon_steps
    if horizon == 'auto':
        if duration:
            horizon = max(SOE_HORIZON_MIN, math.ceil(duration / params.step) + 1)
        else:
            horizon = SOE_HORIZON_OPEN
    return {'tolerance': params.soe_tolerance, 'horizon_steps': int(horizon)}
