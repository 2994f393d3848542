"""Registry of the fractional solvers by name ('abm', 'abm-fft', 'soe')."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

from .abm import ABMStepper, BatchABM
from .fft import solve_abm_fft
from .soe import BatchSOE, SOEStepper

__all__ = ['SolverInfo', 'SOLVERS', 'UnknownSolverError', 'get_solver']


class UnknownSolverError(KeyError, ValueError):
    """An unknown solver name (a ValueError, and a KeyError so Mapping.get works).

    Raises:
        nothing itself; raised by ``SOLVERS[name]`` and :func:`get_solver`.
    """

    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0]) if self.args else ''


@dataclass(frozen=True)
class SolverInfo:
    """One solver: ``stepper`` (online class with step(u), or None), ``offline`` (function
    solving a whole horizon, or None), ``batch`` (batched class), one-line ``accuracy`` and
    ``cost`` statements; ``doc`` joins them in one line.

    Raises:
        nothing (plain data).
    """

    name: str
    stepper: type | None
    offline: Callable | None
    batch: type | None
    accuracy: str
    cost: str

    @property
    def doc(self) -> str:
        return f"{self.name}: {self.accuracy}; {self.cost}"


class _Registry(Mapping):
    def __init__(self, entries: dict[str, SolverInfo]) -> None:
        self._entries = entries

    def __getitem__(self, name: str) -> SolverInfo:
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


#: name -> :class:`SolverInfo`. Unknown names raise :class:`UnknownSolverError` (a ValueError)
#: listing the valid ones.
SOLVERS: Mapping[str, SolverInfo] = _Registry({
    'abm': SolverInfo(
        'abm', ABMStepper, None, BatchABM,
        accuracy='exact Diethelm-Ford-Freed ABM predictor-corrector, error O(h^(1+alpha))',
        cost='online, O(n) per step at step n, O(N^2) in all, memory O(N)'),
    'abm-fft': SolverInfo(
        'abm-fft', ABMStepper, solve_abm_fft, BatchABM,
        accuracy='same numbers as abm (to rounding, <= 1e-12 relative)',
        cost='offline: O(N log^2 N) in all via FFT-blocked history sums (inner loop compiled '
             'when rhs is a numba.njit function); online stepping falls back to abm'),
    'soe': SolverInfo(
        'soe', SOEStepper, None, BatchSOE,
        accuracy='abm with the history tail weights to a relative tolerance (default 1e-10) '
                 'over horizon_steps (default 1e8)',
        cost='online, O(1) per step (~60-90 exponential modes + 16..48 exact lags), memory O(1)'),
})


def get_solver(name: str) -> SolverInfo:
    """Return the :class:`SolverInfo` for ``name``.

    Raises:
        ValueError: unknown name (the message lists the valid names).
    """
    return SOLVERS[name]
