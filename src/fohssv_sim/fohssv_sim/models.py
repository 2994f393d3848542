"""The three HSSV models behind one stepping contract.

Contract (:class:`Plant`), shaped like scipy's steppers:

* ``reset(initial_state=None)`` puts the model back at t = 0 (history cleared);
* ``step(u)`` advances one integration step h. ``u`` is the input ``(delta_f, delta_c)`` in
  rad, held constant over the step (zero-order hold, as through ROS), or a callable
  ``u(t, state) -> (delta_f, delta_c)`` evaluated at every solver stage (continuous feedback,
  as in the paper's simulations). It returns the new state;
* ``advance(u, steps)`` takes ``steps`` steps with the same ``u``: a held input or an
  :class:`AffineLaw` runs them in one compiled call (:mod:`.kernels`), any other callable
  interpreted, step by step; ``record(u, steps, out, row, first, every)`` does the same and
  keeps every ``every``-th state (with Fp and the input there) in preallocated arrays;
* ``t`` (s), ``n`` (steps taken; t = n h exactly), ``x`` (the state as a tuple, no copy),
  ``state`` (copy of [z, w, theta, q]),
  ``planing_force`` (Fp at the current state, eq. 10), ``status`` ('ready' | 'running' |
  'failed').

A state that turns non-finite sets ``status = 'failed'`` and raises ``FloatingPointError``
naming the time and the state; a failed plant refuses further steps until ``reset``.

Models: :class:`DelayFreeModel` (eq. 17, RK4), :class:`DelayedModel` (eqs. 22-25, RK4 with the
method of steps and cubic-Hermite history), :class:`FractionalModel` (eqs. 26-30, Caputo,
predictor-corrector from :mod:`fohssv_sim.fractional`). :func:`make_plant` builds the one the
parameters name. ``engine='python'`` steps every model interpreted: the readable reference
the compiled kernels are tested against (``test/test_kernels.py``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import drivers, kernels
from .bounds import MAX_PITCH, StateOutOfBounds, check_state
from .coefficients import Coefficients, coefficients
from .held_period import HeldPeriod
from .kernels import pack_law
from .params import ModelParameters
from .physics import eq17, hermite_delayed
from .planing import planing_delayed, planing_exact, planing_smooth
from .solvers import SOLVERS, soe_options

__all__ = ['Plant', 'DelayFreeModel', 'DelayedModel', 'FractionalModel', 'make_plant',
           'StateOutOfBounds', 'MAX_PITCH', 'check_state', 'HeldPeriod',
           'InputLike', 'STATE_NAMES', 'eq17', 'AffineLaw', 'ENGINES', 'warm_up']

#: How a plant steps: 'compiled' (numba kernels, :mod:`.kernels`) or 'python' (the interpreted
#: reference); 'auto' = compiled when numba is available.
ENGINES = ('auto', 'compiled', 'python')

#: Names of the state components, in order (docs/model.md §1).
STATE_NAMES = ('z', 'w', 'theta', 'q')

Input = tuple[float, float]
#: Where :meth:`Plant.record` keeps samples: states (N, 4), planing forces (N,), inputs (N, 2).
Record = tuple[np.ndarray, np.ndarray, np.ndarray]
InputLike = Sequence[float] | Callable[[float, Sequence[float]], Sequence[float]]


def _as_state(x: Sequence[float] | None, name: str = 'initial_state') -> tuple:
    if x is None:
        return (0.0, 0.0, 0.0, 0.0)
    try:
        vals = tuple(float(v) for v in x)
    except (TypeError, ValueError):
        raise ValueError(f'{name}={x!r} must be 4 numbers [z m, w m/s, theta rad, q rad/s]'
                         ) from None
    if len(vals) != 4 or not all(math.isfinite(v) for v in vals):
        raise ValueError(f'{name}={x!r} must be 4 finite numbers '
                         '[z m, w m/s, theta rad, q rad/s]')
    return vals


class AffineLaw:
    """The input law u = clamp(K x + u0, limit), evaluated at every solver stage.

    The continuous feedback the compiled kernels can run (:meth:`Plant.advance`); called as
    ``law(t, x)`` it gives the same numbers interpreted. ``K`` is (2, 4), ``u0`` (2,),
    ``limit`` (2,) in rad (inf = no limit). :meth:`from_controller` builds it from a
    controller's ``affine()`` and its deflection limits (None when the law is not affine).
    """

    def __init__(self, K, u0=(0.0, 0.0), limit=(math.inf, math.inf)) -> None:
        self.packed = pack_law(K, u0, limit)

    @classmethod
    def from_controller(cls, controller: Any) -> AffineLaw | None:
        affine = getattr(controller, 'affine', None)
        law = affine() if affine is not None else None
        if law is None:
            return None
        p = getattr(controller, 'params', None)
        return cls(law[0], law[1], (getattr(p, 'max_fin_deflection', math.inf),
                                    getattr(p, 'max_cavitator_deflection', math.inf)))

    def __call__(self, t: float, x: Sequence[float]) -> tuple[float, float]:
        return kernels._input(self.packed, True, x[0], x[1], x[2], x[3])


class Plant:
    """Base of the three models; see the module docstring for the contract.

    Subclasses implement ``_advance(u) -> tuple`` (one interpreted step from the current
    state), ``_run_compiled(law, continuous, steps) -> (steps taken, state array)`` (steps
    through their kernel), ``_compiled()`` and ``planing_force``. Cost per step: O(1) for the
    integer models; see the solver for the FOM.
    """

    def __init__(self, params: ModelParameters | None = None,
                 initial_state: Sequence[float] | None = None, *, engine: str = 'auto',
                 duration: float | None = None) -> None:
        self.params = params if params is not None else ModelParameters()
        self.coefficients: Coefficients = coefficients(self.params)
        self.h: float = self.params.step
        self.initial_state = _as_state(initial_state)
        if engine not in ENGINES:
            raise ValueError(f"engine={engine!r} is not one of {', '.join(map(repr, ENGINES))}")
        if engine == 'auto':
            engine = 'compiled' if kernels.AVAILABLE else 'python'
        self.engine = engine
        self.duration = duration
        self._cv = np.array(self.coefficients.kernel, dtype=float)
        self._c = self.coefficients.kernel     # the scalars the interpreted arithmetic reads
        self._law = pack_law()                 # the held input, set per call
        self._held = pack_law()                # the same for advance_sampled
        self._xa = np.zeros(4)                 # the state as the kernels advance it
        self._bad = np.zeros(4)
        self.reset()

    # -- contract -----------------------------------------------------------------------------
    def reset(self, initial_state: Sequence[float] | None = None) -> None:
        """Back to t = 0 at ``initial_state`` (default: the one given at construction)."""
        if initial_state is not None:
            self.initial_state = _as_state(initial_state)
        self.n = 0
        self._x = self.initial_state
        self._stale = True
        self.status = 'ready'
        self._reset_history()
        self._use_kernel = self.engine == 'compiled' and self._compiled()

    @property
    def t(self) -> float:
        """Simulation time t = n h (s), computed by multiplication so it is exact to rounding."""
        return self.n * self.h

    @property
    def x(self) -> tuple:
        """The current state (z, w, theta, q) as a tuple of floats (read-only, no copy)."""
        return self._x

    @property
    def state(self) -> np.ndarray:
        """The current state [z, w, theta, q] (a copy)."""
        return np.array(self._x, dtype=float)

    def step(self, u: InputLike) -> np.ndarray:
        """Advance one step with input ``u`` (see module docstring); return the new state.

        Raises:
            RuntimeError: the plant failed earlier and was not reset.
            FloatingPointError: the state turned non-finite (status becomes 'failed').
        """
        self.advance(u, 1)
        return np.array(self._x, dtype=float)

    def advance(self, u: InputLike | AffineLaw, steps: int) -> None:
        """Advance ``steps`` steps with ``u``: a held input (delta_f, delta_c), an
        :class:`AffineLaw` (continuous feedback) or any callable ``u(t, state)``.

        With the compiled engine a held input or an AffineLaw runs all the steps in one
        compiled call; any other callable is evaluated step by step, interpreted.

        Raises:
            RuntimeError: the plant failed earlier and was not reset.
            FloatingPointError: the state turned non-finite (status becomes 'failed').
        """
        self._refuse_failed()
        if steps <= 0:
            return
        law, continuous = self._kernel_law(u)
        if law is not None and self._use_kernel:
            taken, xa = self._run_compiled(law, continuous, steps)
            self._x = tuple(xa.tolist())
            self.n += taken
            self.status = 'running'
            if taken < steps:
                self._failed(self._bad.tolist(), _show(u))
            return
        u = u if law is None or continuous else (law[8], law[9])
        self._stale = True                       # the kernels' copy of the state
        for _ in range(steps):
            x = self._advance(u)
            if not all(math.isfinite(v) for v in x):
                self._failed(x, _show(u))
            self._x = x
            self.n += 1
            self.status = 'running'

    def record(self, u: InputLike | AffineLaw, steps: int, out: Record, row: int,
               first: int = 0, every: int = 1) -> int:
        """:meth:`advance` ``steps`` steps with ``u``, keeping the state before step ``first``,
        ``first + every``, ... of them (< ``steps``) as rows ``row``, ``row + 1``, ... of
        ``out`` = (states (N, 4), planing forces (N,), inputs (N, 2)): the state, Fp there
        and the input applied from it on (the held one, or the law's value there). Returns
        the next free row.

        A held input or an :class:`AffineLaw` runs all the steps and writes every row in one
        compiled call, whatever ``every`` is; any other callable steps interpreted.

        Raises:
            RuntimeError, FloatingPointError: as :meth:`advance`.
            StateOutOfBounds: a kept state or the last one is beyond the bounds
                (:func:`check_state`: the plant stops there).
        """
        self._refuse_failed()
        law, continuous = self._kernel_law(u)
        if law is not None and self._use_kernel:
            end, taken, status, xa = self._run_recorded(law, continuous, steps, first, every,
                                                        out, row)
            self._x = tuple(xa.tolist())
            self.n += taken
            self.status = 'running'
            if status == 1:
                self._failed(self._bad.tolist(), _show(u))
            check_state(self)
            return end
        held = None if callable(u) else (law[8], law[9])
        done = 0
        while first < steps:
            self.advance(u, first - done)
            done = first
            x = self._x
            out[0][row] = x
            out[1][row] = self.planing_force
            out[2][row] = held or u(self.t, x)
            row += 1
            check_state(self)
            first += every
        self.advance(u, steps - done)
        check_state(self)
        return row

    def _refuse_failed(self) -> None:
        if self.status == 'failed':
            raise RuntimeError('the plant failed earlier; call reset() before stepping again')

    def _kernel_law(self, u: InputLike | AffineLaw) -> tuple[np.ndarray | None, bool]:
        """``u`` as the kernels' ``law`` array and its ``continuous`` flag (a held input goes
        into this plant's own array), or (None, False) for a callable the kernels cannot run."""
        if isinstance(u, AffineLaw):
            return u.packed, True
        if callable(u):
            return None, False
        law = self._law
        law[8] = float(u[0])
        law[9] = float(u[1])
        return law, False

    def advance_sampled(self, law: AffineLaw, held: Sequence[float], hold: int, periods: int,
                        limits: np.ndarray, out: np.ndarray) -> tuple[int, int]:
        """Up to ``periods`` control periods of ``hold`` steps in one compiled call, the
        affine ``law`` sampled at the end of each period and held over the next (zero-order
        hold), starting with the command ``held`` in force: the samples a plant hosting the
        law publishes, written to rows of ``out`` as ``[z, w, theta, q, Fp, delta_f,
        delta_c]`` (:mod:`.drivers`). ``limits`` = [max |delta_f|, max
        |delta_c|, max |w|, max |theta|].

        Returns ``(samples, status)``: status 0 all done; 1 the state turned non-finite in
        period ``samples`` (the plant holds the last finite step; :meth:`raise_failure`
        raises what :meth:`advance` would); 2 the last sample is outside ``limits``; 3 the
        law's command at the last sample is non-finite or beyond the limits (its columns are
        not written). ``(0, -1)`` when this plant has no compiled kernel (then step it with
        :meth:`advance`).
        """
        if self.status == 'failed':
            raise RuntimeError('the plant failed earlier; call reset() before stepping again')
        if not self._use_kernel or periods <= 0:
            return 0, -1
        h = self._held
        h[8] = held[0]
        h[9] = held[1]
        done, status, last, xa = self._run_sampled(law.packed, h, hold, periods, limits, out)
        self._x = tuple(xa.tolist())
        self.n += done * hold + (last if status == 1 else 0)
        self.status = 'running'
        if status == 1:
            self.status = 'failed'
            self._failure = self._bad.tolist(), _show((h[8], h[9]))
        return done, status

    def raise_failure(self) -> None:
        """Raise the FloatingPointError of the non-finite state :meth:`advance_sampled`
        met (the text :meth:`advance` gives)."""
        bad, shown = self._failure
        self.status = 'running'
        self._failed(bad, shown)

    def _run_sampled(self, law: np.ndarray, held: np.ndarray, hold: int, periods: int,
                     limits: np.ndarray, out: np.ndarray) -> tuple[int, int, int, np.ndarray]:
        """The model's ``*_sampled`` kernel: (samples, status, steps of the last period, the
        state array)."""
        raise NotImplementedError

    def _run_recorded(self, law: np.ndarray, continuous: bool, steps: int, first: int,
                      every: int, out: Record, row: int) -> tuple[int, int, int, np.ndarray]:
        """The model's ``*_recorded`` kernel: (next row, steps taken, status, the state
        array)."""
        raise NotImplementedError

    def _state_array(self) -> np.ndarray:
        """The state as the integer models' kernels advance it (refreshed after interpreted
        steps or a reset)."""
        if self._stale:
            self._xa[:] = self._x
            self._stale = False
        return self._xa

    def compile(self) -> float:
        """Compile this plant's kernel now (or load it from numba's on-disk cache), on a
        scratch copy, so that the first control period of a run does not pay for it. Returns
        the seconds it took: a few seconds the first time on a machine, well under one after.
        """
        start = time.perf_counter()
        if self._use_kernel:
            scratch = type(self)(self.params, engine=self.engine, duration=1.0)
            scratch.advance((0.0, 0.0), 1)
            scratch.record(AffineLaw(np.zeros((2, 4))), 1,
                           (np.zeros((1, 4)), np.zeros(1), np.zeros((1, 2))), 0)
            scratch.advance_sampled(AffineLaw(np.zeros((2, 4))), (0.0, 0.0), 1, 1,
                                    np.array([1.0, 1.0, self.params.speed, MAX_PITCH]),
                                    np.zeros((1, 7)))
        return time.perf_counter() - start

    def _failed(self, x: Sequence[float], shown: str) -> None:
        self.status = 'failed'
        raise FloatingPointError(
            f'state became non-finite at t={(self.n + 1) * self.h:.9g} s: '
            f'[z, w, theta, q] = {[float(v) for v in x]} (from {list(self._x)} with '
            f'u={shown})')

    @property
    def planing_force(self) -> float:
        """Fp (eq. 10, m^2/s^2) at the current state."""
        raise NotImplementedError

    # -- for subclasses ---------------------------------------------------------------------
    def _reset_history(self) -> None:
        pass

    def _advance(self, u: InputLike) -> tuple:
        raise NotImplementedError

    def _compiled(self) -> bool:
        """True when this instance has a compiled kernel."""
        return True

    def _run_compiled(self, law: np.ndarray, continuous: bool, steps: int
                      ) -> tuple[int, np.ndarray]:
        """Run ``steps`` steps through the kernel; return (steps taken, the state array)."""
        raise NotImplementedError

    def describe(self) -> str:
        p = self.params
        extra = f', alpha={p.fractional_order:g}' if p.model == 'fractional' else ''
        engine = 'compiled' if self.engine == 'compiled' and self._compiled() else 'interpreted'
        return (f'{p.model} model, solver {p.solver} ({engine}), step {p.step:g} s, '
                f'V={p.speed:g} m/s{extra}')


def _show(u: Any) -> str:
    if isinstance(u, AffineLaw):
        return 'affine law'
    return 'callable' if callable(u) else repr(tuple(u))


def _input(u: InputLike, t: float, x: tuple) -> Input:
    if callable(u):
        v = u(t, x)
        return float(v[0]), float(v[1])
    return u  # already normalised by the caller


def _rk4(x: tuple, t: float, h: float, u: InputLike,
         deriv: Callable[[float, tuple, float, float], tuple]) -> tuple:
    """One classical RK4 step; ``deriv(c, x, uf, uc)`` at stage fraction c of the step."""
    k1 = deriv(0.0, x, *_input(u, t, x))
    x2 = tuple(a + 0.5 * h * b for a, b in zip(x, k1))
    k2 = deriv(0.5, x2, *_input(u, t + 0.5 * h, x2))
    x3 = tuple(a + 0.5 * h * b for a, b in zip(x, k2))
    k3 = deriv(0.5, x3, *_input(u, t + 0.5 * h, x3))
    x4 = tuple(a + h * b for a, b in zip(x, k3))
    k4 = deriv(1.0, x4, *_input(u, t + h, x4))
    return tuple(a + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
                 for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4))


def _held(u: InputLike) -> InputLike:
    if callable(u):
        return u
    return float(u[0]), float(u[1])


class DelayFreeModel(Plant):
    """Delay-free integer-order model (eq. 17, docs/model.md §3), classical RK4.

    Planing force: exact switching (eqs. 10, 12-14) or, with ``planing_form='smooth'``, the
    FOM's tanh form (eqs. 28-29), so that alpha = 1 of the FOM can be compared with it.
    Accuracy O(h^4) between planing contacts; a contact's slope jump costs order. Cost: 4
    right-hand sides per step.
    """

    def __init__(self, params: ModelParameters | None = None,
                 initial_state: Sequence[float] | None = None, **options: Any) -> None:
        params = params if params is not None else ModelParameters(model='delay-free')
        if params.model not in ('delay-free', 'fractional'):
            raise ValueError(f"DelayFreeModel needs model='delay-free', got {params.model!r}")
        super().__init__(params, initial_state, **options)
        self._smooth = self.params.planing_form == 'smooth'
        self._fp = planing_smooth if self._smooth else planing_exact

    def rhs(self, x: Sequence[float], uf: float, uc: float) -> tuple:
        """dx/dt of eq. 17 for state ``x`` and input (``uf``, ``uc``)."""
        c = self._c
        return eq17(c, x[1], x[2], x[3], uf, uc, self._fp(x[1], c))

    def _advance(self, u: InputLike) -> tuple:
        rhs = self.rhs
        return _rk4(self._x, self.t, self.h, _held(u), lambda _c, x, uf, uc: rhs(x, uf, uc))

    def _run_compiled(self, law: np.ndarray, continuous: bool, steps: int
                      ) -> tuple[int, np.ndarray]:
        xa = self._state_array()
        return kernels.delay_free_run(xa, steps, self.h, self._cv, self._smooth, law,
                                      continuous, self._bad), xa

    def _run_recorded(self, law, continuous, steps, first, every, out, row):
        xa = self._state_array()
        return (*drivers.delay_free_recorded(xa, steps, first, every, self.h, self._cv,
                                             self._smooth, law, continuous, self._bad, *out,
                                             row, self.params.speed, MAX_PITCH), xa)

    def _run_sampled(self, law, held, hold, periods, limits, out):
        xa = self._state_array()
        return (*drivers.delay_free_sampled(xa, hold, periods, self.h, self._cv, self._smooth,
                                            law, held, limits, self._bad, out), xa)

    @property
    def planing_force(self) -> float:
        return self._fp(self._x[1], self._c)


class DelayedModel(Plant):
    """Delayed integer-order model (eqs. 22-25, docs/model.md §4), RK4 by the method of steps.

    The planing force uses the states at t - tau (tau = L/V unless ``advection_delay`` sets
    it). The history before t = 0 is x(s) = x(0); past states are kept in a ring buffer
    covering tau and interpolated with cubic Hermite polynomials (states and derivatives at
    the step points), which keeps RK4's order at the half-step stages. ``tau`` must be 0 (the
    delay-free limit) or at least one step. Cost: 4 right-hand sides and 3 interpolations per
    step; memory O(tau / h).
    """

    def __init__(self, params: ModelParameters | None = None,
                 initial_state: Sequence[float] | None = None, **options: Any) -> None:
        params = params if params is not None else ModelParameters(model='delayed')
        if params.model != 'delayed':
            raise ValueError(f"DelayedModel needs model='delayed', got {params.model!r}")
        self.tau = params.delay
        self._lag = self.tau / params.step  # delay in steps
        self._size = int(math.ceil(self._lag)) + 3
        self._form = params.immersion_form
        super().__init__(params, initial_state, **options)

    def _reset_history(self) -> None:
        self._hx = np.zeros((self._size, 4))   # states x_k at t_k, row k % size
        self._hf = np.zeros((self._size, 4))   # derivatives f_k at t_k
        self._x_init = np.array(self.initial_state)

    def _delayed(self, c_stage: float, x_stage: tuple) -> tuple:
        """x(t_n + c h - tau), from the history (Hermite) or x(0) before t = 0."""
        if self.tau == 0.0:
            return x_stage
        return hermite_delayed(self._hx, self._hf, self.n, c_stage, self._lag, self.h,
                               self.initial_state)

    def _force(self, x: tuple, xd: tuple) -> float:
        return planing_delayed(x[0], x[2], xd[0], xd[1], xd[2], self._c, self._form)

    def rhs(self, x: Sequence[float], x_delayed: Sequence[float], uf: float, uc: float) -> tuple:
        """dx/dt of eqs. 22-25 for state ``x``, delayed state and input."""
        return eq17(self._c, x[1], x[2], x[3], uf, uc, self._force(x, x_delayed))

    def _advance(self, u: InputLike) -> tuple:
        n, size, rhs, delayed = self.n, self._size, self.rhs, self._delayed
        self._hx[n % size] = self._x

        def deriv(c: float, x: tuple, uf: float, uc: float) -> tuple:
            f = rhs(x, delayed(c, x), uf, uc)
            if c == 0.0:
                self._hf[n % size] = f   # f_n: the Hermite slope at t_n (stages need it)
            return f

        return _rk4(self._x, self.t, self.h, _held(u), deriv)

    def _run_compiled(self, law: np.ndarray, continuous: bool, steps: int
                      ) -> tuple[int, np.ndarray]:
        xa = self._state_array()
        return kernels.delayed_run(xa, self.n, steps, self.h, self._cv, self._hx, self._hf,
                                   self._lag, self.tau, self._x_init, self._form == 'paper',
                                   law, continuous, self._bad), xa

    def _run_recorded(self, law, continuous, steps, first, every, out, row):
        xa = self._state_array()
        return (*drivers.delayed_recorded(xa, self.n, steps, first, every, self.h, self._cv,
                                          self._hx, self._hf, self._lag, self.tau,
                                          self._x_init, self._form == 'paper', law, continuous,
                                          self._bad, *out, row, self.params.speed, MAX_PITCH),
                xa)

    def _run_sampled(self, law, held, hold, periods, limits, out):
        xa = self._state_array()
        return (*drivers.delayed_sampled(xa, self.n, hold, periods, self.h, self._cv, self._hx,
                                         self._hf, self._lag, self.tau, self._x_init,
                                         self._form == 'paper', law, held, limits, self._bad,
                                         out), xa)

    @property
    def planing_force(self) -> float:
        return self._force(self._x, self._delayed(0.0, self._x))


class FractionalModel(Plant):
    """Fractional-order model (eqs. 26-30, docs/model.md §5): Caputo derivative of commensurate
    order alpha in (0, 1], the coefficients of eq. 17, the smooth planing force (eqs. 28-29)
    or, with ``planing_form='exact'``, the switching one.

    Solved by the solver the parameters name (:data:`fohssv_sim.fractional.SOLVERS`): 'abm'
    (Diethelm-Ford-Freed predictor-corrector, O(n) at step n), 'soe' (same scheme, history
    compressed to a sum of exponentials, O(1) per step), 'abm-fft' (stepped online like 'abm';
    the FFT-blocked form serves offline runs). alpha = 1 gives the trapezoidal PECE scheme for
    the integer model with the same planing force.
    """

    def __init__(self, params: ModelParameters | None = None,
                 initial_state: Sequence[float] | None = None, **options: Any) -> None:
        params = params if params is not None else ModelParameters(model='fractional')
        if params.model != 'fractional':
            raise ValueError(f"FractionalModel needs model='fractional', got {params.model!r}")
        self._smooth = params.planing_form == 'smooth'
        self._fp = planing_smooth if self._smooth else planing_exact
        self._last_f = np.zeros(4)
        super().__init__(params, initial_state, **options)

    def _reset_history(self) -> None:
        p = self.params
        x0 = np.array(self._x, dtype=float)
        self._x0a = x0.copy()
        solver = SOLVERS[p.solver]
        st = self._stepper = solver.stepper(
            self.rhs, p.fractional_order, p.step, x0,
            **soe_options(p, self.duration) if p.solver == 'soe' else {})
        self._kernel_args = None
        self._held_call = None
        self._fp_at = -1          # the step count at which _fp_value is the planing force
        if solver.compiled:       # the arrays the compiled kernel advances, gathered once
            hist = st.history
            self._kernel_args = (hist.H, hist.W, hist.fill, hist.eps_k, hist.ET,
                                 hist.a0_coef, hist.a0_small, float(hist.alphas[0]),
                                 float(hist.cp[0]), float(hist.cc[0]), self._last_f,
                                 self._bad)

    @property
    def horizon_steps(self) -> int | None:
        """Steps over which the 'soe' history meets its kernel tolerance (None for 'abm')."""
        return getattr(self._stepper.history, 'horizon', None)

    def _compiled(self) -> bool:
        return self._kernel_args is not None

    def _run_compiled(self, law: np.ndarray, continuous: bool, steps: int
                      ) -> tuple[int, np.ndarray]:
        st = self._stepper                 # advanced in place: its state array and history
        x = st.live_state()
        if not continuous:             # a held input (a plant's control period)
            held = self._held_call
            if held is None or held is not False and (x is not held.x or law is not held.law):
                held = self._held_call = self._bind_held(x, law)
            if held is not False:
                taken = held.call(st.n, steps)
                self._stepped(taken, failed=taken < steps)
                self._fp_value = held.values[held.FP]   # computed by the kernel at x
                self._fp_at = st.n
                return taken, x
        taken = kernels.fom_soe_run(x, self._x0a, st.n, steps, self._cv, self._smooth, law,
                                    continuous, *self._kernel_args)
        self._stepped(taken, failed=taken < steps)
        return taken, x

    def _bind_held(self, x: np.ndarray, law: np.ndarray) -> kernels.FomHeldCall | bool:
        """The kernel's held-input call bound to this model's arrays, the stepper's state
        array ``x`` and the input ``law`` (built on the first held-input call, and again after
        a reset (new history arrays) or when ``x`` or ``law`` is another array than the bound
        one: interpreted steps replace the stepper's state array), or False where the C entry
        point is not available (:class:`fohssv_sim.kernels.FomHeldCall`)."""
        call = kernels.FomHeldCall.build(x, self._x0a, self._cv, self._smooth, law,
                                         *self._kernel_args)
        return False if call is None else call

    def _stepped(self, steps: int, failed: bool) -> None:
        """Tell the stepper what a kernel call did (and warn past the SOE horizon)."""
        st = self._stepper
        st.advanced(steps, self._last_f, failed=failed)
        hist = st.history
        if st.n > hist.horizon:
            hist.check_horizon(st.n)

    def _run_recorded(self, law, continuous, steps, first, every, out, row):
        st = self._stepper
        x = st.live_state()
        end, taken, status = drivers.fom_soe_recorded(
            x, self._x0a, st.n, steps, first, every, self._cv, self._smooth, law, continuous,
            *self._kernel_args, *out, row, self.params.speed, MAX_PITCH)
        self._stepped(taken, failed=status == 1)
        return end, taken, status, x

    def _run_sampled(self, law, held, hold, periods, limits, out):
        st = self._stepper
        x = st.live_state()
        a = self._kernel_args
        done, status, last = drivers.fom_soe_sampled(
            x, self._x0a, st.n, hold, periods, self._cv, self._smooth, law, held, limits, *a,
            out)
        self._stepped(done * hold + (last if status == 1 else 0), failed=status == 1)
        return done, status, last, x

    def rhs(self, t: float, x: np.ndarray, u: Sequence[float]) -> np.ndarray:
        """Right-hand side f(t, x, u) of D^alpha x = f (eq. 26)."""
        c = self._c
        w = float(x[1])
        return np.array(eq17(c, w, float(x[2]), float(x[3]), float(u[0]), float(u[1]),
                             self._fp(w, c)))

    def _advance(self, u: InputLike) -> tuple:
        u = _held(u)
        if callable(u):
            uu = u

            def u_arr(t: float, x: np.ndarray) -> Input:
                return _input(uu, t, tuple(float(v) for v in x))

        else:
            u_arr = np.array(u, dtype=float)
        try:
            x = self._stepper.step(u_arr)
        except FloatingPointError:
            return (math.nan,) * 4   # Plant.step reports time and state
        return tuple(float(v) for v in x)

    @property
    def planing_force(self) -> float:
        if self._fp_at == self.n:        # the held-input call left it (the same arithmetic)
            return self._fp_value
        return self._fp(self._x[1], self._c)


def make_plant(params: ModelParameters | None = None,
               initial_state: Sequence[float] | None = None, *, engine: str = 'auto',
               duration: float | None = None) -> Plant:
    """The model that ``params.model`` names, ready at t = 0.

    ``engine``: see :data:`ENGINES`. ``duration`` (s, None = open-ended) sizes the FOM's
    'soe' history when ``soe_horizon_steps='auto'`` (:func:`fohssv_sim.solvers.soe_options`).
    """
    params = params if params is not None else ModelParameters()
    cls = {'fractional': FractionalModel, 'delay-free': DelayFreeModel,
           'delayed': DelayedModel}[params.model]
    return cls(params, initial_state, engine=engine, duration=duration)


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel and driver the plants run, with the
    argument types they pass (:meth:`Plant.compile` of each model), so that the first control
    period of a run does not pay for it."""
    for model in ('delay-free', 'delayed', 'fractional'):
        make_plant(ModelParameters(model=model)).compile()
