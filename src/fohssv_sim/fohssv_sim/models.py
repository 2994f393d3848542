"""The three HSSV models behind one stepping contract.

Contract (:class:`Plant`), shaped like scipy's steppers:

* ``reset(initial_state=None)`` puts the model back at t = 0 (history cleared);
* ``step(u)`` advances one integration step h. ``u`` is the input ``(delta_f, delta_c)`` in
  rad, held constant over the step (zero-order hold, as through ROS), or a callable
  ``u(t, state) -> (delta_f, delta_c)`` evaluated at every solver stage (continuous feedback,
  as in the paper's simulations). It returns the new state;
* ``t`` (s), ``n`` (steps taken; t = n h exactly), ``state`` (copy of [z, w, theta, q]),
  ``planing_force`` (Fp at the current state, eq. 10), ``status`` ('ready' | 'running' |
  'failed').

A state that turns non-finite sets ``status = 'failed'`` and raises ``FloatingPointError``
naming the time and the state; a failed plant refuses further steps until ``reset``.

Models: :class:`DelayFreeModel` (eq. 17, RK4), :class:`DelayedModel` (eqs. 22-25, RK4 with the
method of steps and cubic-Hermite history), :class:`FractionalModel` (eqs. 26-30, Caputo,
predictor-corrector from :mod:`fohssv_sim.fractional`). :func:`make_plant` builds the one the
parameters name.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from .coefficients import Coefficients, coefficients
from .params import ModelParameters
from .planing import planing_delayed, planing_exact, planing_smooth

__all__ = ['Plant', 'DelayFreeModel', 'DelayedModel', 'FractionalModel', 'make_plant',
           'InputLike', 'STATE_NAMES', 'eq17']

#: Names of the state components, in order (docs/model.md §1).
STATE_NAMES = ('z', 'w', 'theta', 'q')

Input = tuple[float, float]
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


class Plant:
    """Base of the three models; see the module docstring for the contract.

    Subclasses implement ``_advance(u) -> tuple`` (one step from the current state) and
    ``planing_force``. Cost per step: O(1) for the integer models; see the solver for the FOM.
    """

    def __init__(self, params: ModelParameters | None = None,
                 initial_state: Sequence[float] | None = None) -> None:
        self.params = params if params is not None else ModelParameters()
        self.coefficients: Coefficients = coefficients(self.params)
        self.h: float = self.params.step
        self.initial_state = _as_state(initial_state)
        self.reset()

    # -- contract -----------------------------------------------------------------------------
    def reset(self, initial_state: Sequence[float] | None = None) -> None:
        """Back to t = 0 at ``initial_state`` (default: the one given at construction)."""
        if initial_state is not None:
            self.initial_state = _as_state(initial_state)
        self.n = 0
        self._x = self.initial_state
        self.status = 'ready'
        self._reset_history()

    @property
    def t(self) -> float:
        """Simulation time t = n h (s), computed by multiplication so it is exact to rounding."""
        return self.n * self.h

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
        if self.status == 'failed':
            raise RuntimeError('the plant failed earlier; call reset() before stepping again')
        x = self._advance(u)
        if not all(math.isfinite(v) for v in x):
            self.status = 'failed'
            raise FloatingPointError(
                f'state became non-finite at t={(self.n + 1) * self.h:.9g} s: '
                f'[z, w, theta, q] = {list(x)} (from {list(self._x)} with u={_show(u)})'
            )
        self._x = x
        self.n += 1
        self.status = 'running'
        return np.array(x, dtype=float)

    @property
    def planing_force(self) -> float:
        """Fp (eq. 10, m^2/s^2) at the current state."""
        raise NotImplementedError

    # -- for subclasses ---------------------------------------------------------------------
    def _reset_history(self) -> None:
        pass

    def _advance(self, u: InputLike) -> tuple:
        raise NotImplementedError

    def describe(self) -> str:
        p = self.params
        extra = f', alpha={p.fractional_order:g}' if p.model == 'fractional' else ''
        return (f'{p.model} model, solver {p.solver}, step {p.step:g} s, V={p.speed:g} m/s'
                f'{extra}')


def _show(u: InputLike) -> str:
    return 'callable' if callable(u) else repr(tuple(u))


def _input(u: InputLike, t: float, x: tuple) -> Input:
    if callable(u):
        v = u(t, x)
        return float(v[0]), float(v[1])
    return u  # already normalised by the caller


def eq17(c: Coefficients, w: float, th: float, q: float, uf: float, uc: float,
         fp: float) -> tuple:
    """dx/dt = A x + B u + G + D Fp of eq. 17 in float arithmetic (z does not enter)."""
    return (w - c.V * th,
            c.a22 * w + c.a24 * q + c.b21 * uf + c.b22 * uc + c.g + c.d2 * fp,
            q,
            c.a42 * w + c.a44 * q + c.b41 * uf + c.b42 * uc + c.d4 * fp)


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
                 initial_state: Sequence[float] | None = None) -> None:
        params = params if params is not None else ModelParameters(model='delay-free')
        if params.model not in ('delay-free', 'fractional'):
            raise ValueError(f"DelayFreeModel needs model='delay-free', got {params.model!r}")
        super().__init__(params, initial_state)
        self._fp = planing_smooth if self.params.planing_form == 'smooth' else planing_exact

    def rhs(self, x: Sequence[float], uf: float, uc: float) -> tuple:
        """dx/dt of eq. 17 for state ``x`` and input (``uf``, ``uc``)."""
        c = self.coefficients
        return eq17(c, x[1], x[2], x[3], uf, uc, self._fp(x[1], c))

    def _advance(self, u: InputLike) -> tuple:
        rhs = self.rhs
        return _rk4(self._x, self.t, self.h, _held(u), lambda _c, x, uf, uc: rhs(x, uf, uc))

    @property
    def planing_force(self) -> float:
        return self._fp(self._x[1], self.coefficients)


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
                 initial_state: Sequence[float] | None = None) -> None:
        params = params if params is not None else ModelParameters(model='delayed')
        if params.model != 'delayed':
            raise ValueError(f"DelayedModel needs model='delayed', got {params.model!r}")
        self.tau = params.delay
        self._lag = self.tau / params.step  # delay in steps
        self._size = int(math.ceil(self._lag)) + 3
        super().__init__(params, initial_state)
        self._form = self.params.immersion_form

    def _reset_history(self) -> None:
        self._hx: list = [None] * self._size   # states x_k at t_k, k % size
        self._hf: list = [None] * self._size   # derivatives f_k at t_k

    def _delayed(self, c_stage: float, x_stage: tuple) -> tuple:
        """x(t_n + c h - tau), from the history (Hermite) or x(0) before t = 0."""
        if self.tau == 0.0:
            return x_stage
        s = self.n + c_stage - self._lag   # in steps
        if s <= 0.0:
            return self.initial_state
        k = int(s)
        theta = s - k
        size = self._size
        xk = self._hx[k % size]
        if theta == 0.0:
            return xk
        xk1, fk, fk1 = self._hx[(k + 1) % size], self._hf[k % size], self._hf[(k + 1) % size]
        t2, t3 = theta * theta, theta * theta * theta
        h00 = 2.0 * t3 - 3.0 * t2 + 1.0
        h10 = (t3 - 2.0 * t2 + theta) * self.h
        h01 = -2.0 * t3 + 3.0 * t2
        h11 = (t3 - t2) * self.h
        return tuple(h00 * a + h10 * b + h01 * c + h11 * d
                     for a, b, c, d in zip(xk, fk, xk1, fk1))

    def _force(self, x: tuple, xd: tuple) -> float:
        return planing_delayed(x[0], x[2], xd[0], xd[1], xd[2], self.coefficients, self._form)

    def rhs(self, x: Sequence[float], x_delayed: Sequence[float], uf: float, uc: float) -> tuple:
        """dx/dt of eqs. 22-25 for state ``x``, delayed state and input."""
        return eq17(self.coefficients, x[1], x[2], x[3], uf, uc, self._force(x, x_delayed))

    def _advance(self, u: InputLike) -> tuple:
        n, size, rhs, delayed = self.n, self._size, self.rhs, self._delayed
        self._hx[n % size] = self._x

        def deriv(c: float, x: tuple, uf: float, uc: float) -> tuple:
            f = rhs(x, delayed(c, x), uf, uc)
            if c == 0.0:
                self._hf[n % size] = f   # f_n: the Hermite slope at t_n (stages need it)
            return f

        return _rk4(self._x, self.t, self.h, _held(u), deriv)

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
                 initial_state: Sequence[float] | None = None) -> None:
        params = params if params is not None else ModelParameters(model='fractional')
        if params.model != 'fractional':
            raise ValueError(f"FractionalModel needs model='fractional', got {params.model!r}")
        self._fp = planing_smooth if params.planing_form == 'smooth' else planing_exact
        super().__init__(params, initial_state)

    def _reset_history(self) -> None:
        from .fractional import ABMStepper, SOEStepper

        p = self.params
        x0 = np.array(self._x, dtype=float)
        if p.solver == 'soe':
            self._stepper = SOEStepper(self.rhs, p.fractional_order, p.step, x0,
                                       tolerance=p.soe_tolerance,
                                       horizon_steps=int(p.soe_horizon_steps))
        else:
            self._stepper = ABMStepper(self.rhs, p.fractional_order, p.step, x0)

    def rhs(self, t: float, x: np.ndarray, u: Sequence[float]) -> np.ndarray:
        """Right-hand side f(t, x, u) of D^alpha x = f (eq. 26)."""
        c = self.coefficients
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
        return self._fp(self._x[1], self.coefficients)


def make_plant(params: ModelParameters | None = None,
               initial_state: Sequence[float] | None = None) -> Plant:
    """The model that ``params.model`` names, ready at t = 0."""
    params = params if params is not None else ModelParameters()
    cls = {'fractional': FractionalModel, 'delay-free': DelayFreeModel,
           'delayed': DelayedModel}[params.model]
    return cls(params, initial_state)
