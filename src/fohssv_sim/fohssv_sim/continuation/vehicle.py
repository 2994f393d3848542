"""The vehicle's closed loop as continuation problems: the delay-free model as a piecewise
smooth field for shooting, the FOM as a harmonic-balance problem; one numeric model parameter
varies (``fractional_order``, ``speed``, ...).

The physics is the model's own: eq. 17 (:func:`fohssv_sim.physics.eq17`), the planing forces
of :mod:`fohssv_sim.planing`, the coefficients of :mod:`fohssv_sim.coefficients` and the
closed-loop right-hand side of :mod:`fohssv_sim.equilibria`. The controller must be an affine
state feedback (``affine()``, as the batched sweeps need), clamped to its deflection limits.

Immersion is reported as |h*| - R' in body radii (h* = L w / (R V), eq. 12): negative while
the tail is clear of the cavity wall, positive its depth in the wall; an orbit whose maximum
crosses zero grazes the wall.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..coefficients import Coefficients, coefficients
from ..equilibria import find_equilibria
from ..kernels import pack_law
from ..params import PARAMETERS, ModelParameters, ParameterError
from ..physics import eq17, planing_exact
from ..planing import planing_exact_array, planing_smooth_array
from .flow import flow, pack_coefficients, planing_delayed_many
from .harmonic import HarmonicBalance
from .shooting import Field

__all__ = ['VehicleSystem', 'immersion', 'orbit_measures', 'varied_names', 'W']

#: Index of w in the state [z, w, theta, q].
W = 1


def immersion(w: np.ndarray, c: Coefficients) -> np.ndarray:
    """|h*| - R' (body radii) for vertical velocities ``w`` (delay-free immersion, eq. 12)."""
    return np.abs(c.L * np.asarray(w) / (c.R * c.V)) - c.R_prime


def orbit_measures(states: np.ndarray, c: Coefficients) -> dict[str, float]:
    """Amplitude and mean of w and the immersion range of an orbit sampled over one period
    (``states`` of shape (4, N))."""
    w = states[W]
    h = immersion(w, c)
    return {'w_amplitude': float(0.5 * (w.max() - w.min())), 'w_mean': float(w.mean()),
            'w_min': float(w.min()), 'w_max': float(w.max()),
            'immersion_min': float(h.min()), 'immersion_max': float(h.max())}


#: Solver settings: numeric, but not the model's.
_SETTINGS = ('step', 'soe_tolerance', 'soe_horizon_steps')


def controller_gains(controller: Any) -> list[str]:
    """The numeric parameters of a controller but its deflection limits (held fixed): the
    gains a branch can vary (the names of ``--gain`` and ``fohssv gainmap``)."""
    p = getattr(controller, 'params', None)
    if p is None or not dataclasses.is_dataclass(p):
        return []
    return [f.name for f in dataclasses.fields(p) if isinstance(getattr(p, f.name), float)
            and f.name not in ('max_fin_deflection', 'max_cavitator_deflection')]


def varied_names(params: ModelParameters) -> list[str]:
    """The model parameters a branch can vary: the numeric ones holding a number in
    ``params`` (an option left at 'consistent' is set first with --set)."""
    return [s.name for s in PARAMETERS if s.numeric and s.name not in _SETTINGS
            and isinstance(getattr(params, s.name), float)]


class VehicleSystem:
    """The closed loop of ``params`` under ``controller`` with the model parameter
    ``parameter`` set to p.

    Raises:
        ParameterError: ``parameter`` is not a numeric model parameter, or the controller is
            not affine.
    """

    def __init__(self, params: ModelParameters, controller: Any, parameter: str) -> None:
        gains = controller_gains(controller)
        if parameter not in varied_names(params) and parameter not in gains:
            raise ParameterError(f'parameter {parameter!r} is not a numeric model parameter '
                                 'nor a gain of the controller; choose one of '
                                 f"{', '.join(varied_names(params) + gains)}")
        law = controller.affine() if hasattr(controller, 'affine') else None
        if law is None:
            raise ParameterError(f'controller {getattr(controller, "name", controller)!r} is '
                                 'not an affine state feedback (u = K x + u0)')
        self.params = params
        self.controller = controller
        self.parameter = parameter
        #: the varied name is a controller gain (the model parameters stay fixed)
        self.gain = parameter not in varied_names(params)
        self._laws: dict[float, tuple[Any, np.ndarray, np.ndarray]] = {}
        p = controller.params
        self.limits = (getattr(p, 'max_fin_deflection', math.inf),
                       getattr(p, 'max_cavitator_deflection', math.inf))
        self._cache: dict[float, tuple[ModelParameters, Coefficients]] = {}
        self._equilibria: dict[float | None, Any] = {}

    # -- parameters ------------------------------------------------------------------------
    def law(self, p: float) -> tuple[Any, np.ndarray, np.ndarray]:
        """(controller, K, u0) with the varied gain at ``p`` (the given controller when a
        model parameter varies)."""
        key = float(p) if self.gain else 0.0
        got = self._laws.get(key)
        if got is None:
            ctl = self.controller
            if self.gain:
                ctl = type(ctl)(**{**dataclasses.asdict(ctl.params), self.parameter: key})
            K, u0 = ctl.affine()
            got = (ctl, np.asarray(K, dtype=float), np.asarray(u0, dtype=float))
            if len(self._laws) > 64:
                self._laws.clear()
            self._laws[key] = got
        return got

    def at(self, p: float) -> tuple[ModelParameters, Coefficients]:
        """Model parameters and coefficients with the varied parameter at ``p`` (the order is
        not validated here: Newton's differences may step just past alpha = 1)."""
        key = float(p)
        got = self._cache.get(key)
        if got is None:
            if self.parameter == 'fractional_order' or self.gain:
                mp = self.params
            else:
                mp = self.params.replace(**{self.parameter: key})
            got = (mp, coefficients(mp))
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[key] = got
        return got

    def order(self, p: float) -> float:
        return float(p) if self.parameter == 'fractional_order' else \
            self.params.fractional_order

    # -- right-hand sides ------------------------------------------------------------------
    def rhs(self, X: np.ndarray, p: float, smooth: bool = True) -> np.ndarray:
        """eq. 17 of the closed loop at the states X (4, N), vectorised."""
        _, c = self.at(p)
        w = X[W]
        return self._eq17(X, p, c, planing_smooth_array(w, c) if smooth else
                          planing_exact_array(w, c))

    def _eq17(self, X: np.ndarray, p: float, c: Coefficients, fp: np.ndarray) -> np.ndarray:
        _, K, u0 = self.law(p)
        u = K @ X + u0[:, None]
        uf = np.clip(u[0], -self.limits[0], self.limits[0])
        uc = np.clip(u[1], -self.limits[1], self.limits[1])
        return np.array(np.broadcast_arrays(*eq17(c.kernel, X[W], X[2], X[3], uf, uc, fp)))

    def delayed_rhs(self, X: np.ndarray, p: float, Xd: np.ndarray) -> np.ndarray:
        """The delayed model's closed loop (eqs. 22-25) at the states X and the states Xd a
        delay tau earlier, both (4, N)."""
        mp, c = self.at(p)
        fp = planing_delayed_many(np.ascontiguousarray(X, dtype=float),
                                  np.ascontiguousarray(Xd, dtype=float),
                                  pack_coefficients(c), str(mp.immersion_form))
        return self._eq17(X, p, c, fp)

    def harmonic_balance_delayed(self, harmonics: int) -> HarmonicBalance:
        """The delayed model by harmonic balance of its delay-differential equation, with
        tau = L/V (or as set) moving with the parameter; phase fixed on w."""
        return HarmonicBalance(self.delayed_rhs, 4, harmonics, lambda p: 1.0, phase_state=W,
                               delay=lambda p: self.at(p)[1].tau, switch=self.delayed_contact)

    def delayed_contact(self, X: np.ndarray, p: float, Xd: np.ndarray) -> np.ndarray:
        """|h*| - R' of the delayed model (eq. 25 in the model's immersion form) at the states
        X and delayed states Xd: positive in contact with the cavity wall."""
        mp, c = self.at(p)
        if mp.immersion_form == 'paper':
            hs = (X[0] - Xd[0] + c.L * (X[2] - Xd[2]) + c.L * Xd[1] / c.V) / c.R
        else:
            hs = (X[0] - Xd[0] + c.L * X[2]) / c.R
        return np.abs(hs) - c.R_prime

    def harmonic_balance(self, harmonics: int) -> HarmonicBalance:
        """The FOM with its smooth planing force (eqs. 28-29), phase fixed on w."""
        return HarmonicBalance(lambda X, p: self.rhs(X, p, smooth=True), 4, harmonics,
                               self.order, phase_state=W)

    def field(self, steps: int = 1000, compiled: bool = True) -> Field:
        """The delay-free closed loop with the exact switching planing force (eqs. 12-14):
        a field continuous across the contact surfaces w = +-R'RV/L, which it names;
        integrated by the compiled RK4 of :mod:`.flow` with ``steps`` steps per period (or,
        ``compiled=False``, by DOP853).

        In the matrix form of eq. 17 (the coefficients' A, B, G, D), f = A x + B u + G +
        D Fp(w) with u the clamped law, and df/dx = A + B K' + D Fp'(w) e_w (K' the gain
        rows whose output is not clamped; Fp' by central differences): per evaluation a few
        small products instead of differencing the whole field."""
        def input_of(x: np.ndarray, p: float) -> tuple[np.ndarray, np.ndarray]:
            _, K, u0 = self.law(p)
            raw = K @ x + u0
            lim = np.asarray(self.limits)
            return np.clip(raw, -lim, lim), (np.abs(raw) < lim).astype(float)

        def f(x: np.ndarray, p: float) -> np.ndarray:
            _, c = self.at(p)
            u, _ = input_of(x, p)
            return c.A @ x + c.B @ u + c.G + c.D * planing_exact(float(x[W]), c.kernel)

        def dfdx(x: np.ndarray, p: float) -> np.ndarray:
            _, c = self.at(p)
            _, free = input_of(x, p)
            w = float(x[W])
            d = 1e-7 * max(1.0, abs(w))
            slope = (planing_exact(w + d, c.kernel) - planing_exact(w - d, c.kernel)) / (2 * d)
            J = c.A + c.B @ (free[:, None] * self.law(p)[1])
            J[:, W] += c.D * slope
            return J

        def switches(x: np.ndarray, p: float) -> tuple[float, float]:
            wc = self.at(p)[1].contact_velocity
            return (x[W] - wc, x[W] + wc)

        def integrate(x0: np.ndarray, T: float, p: float, variational: bool, count: int):
            cv = pack_coefficients(self.at(p)[1])
            law = pack_law(*self.law(p)[1:], self.limits)
            every = -(-steps // count) if count else 0
            n = every * count if count else steps
            record = np.empty((count + 1 if count else 1, 4))
            xT, X = flow(x0, T, n, cv, law, variational, every, record)
            return xT, (X if variational else None), (record[:count] if count else None)

        return Field(f, 4, switches, dfdx, integrate if compiled else None)

    # -- equilibria ------------------------------------------------------------------------
    def equilibrium(self, p: float):
        """The closed-loop equilibrium nearest the cavity centre (as the Matignon curve of
        ``fohssv stability`` takes it), or None. The equilibrium does not depend on the
        order alpha (the derivative of a constant is zero): over alpha it is found once."""
        key = None if self.parameter == 'fractional_order' else float(p)
        if key not in self._equilibria:
            eqs = find_equilibria(self.at(p)[0], self.law(p)[0])
            self._equilibria[key] = min(eqs, key=lambda e: abs(e.state[W])) if eqs else None
        return self._equilibria[key]
