"""LQR on the linearisation at the eq. 31 operating point: the comparison law for eq. 31.

Design point: the equilibrium (x*, u*) of the plant under the paper's state feedback (eq. 31
with its default gains, fins at zero), found by :func:`fohssv_sim.equilibria.find_equilibria`
on the delay-free right-hand side (eq. 17) with the smooth planing force (eqs. 28-29) at
``design_speed``, with the other model parameters at their defaults (Table A1). At V = 75 m/s
it is x* = [0.0452 m, 1.670 m/s, 0.02227 rad, 0], u* = (0, 0.00986 rad): the tail planes on
the lower cavity wall. This is also the equilibrium of the FOM and of the delayed model (the
same f(x) = 0), so both laws regulate to the same operating point.

Law, with A = df/dx(x*, u*) (central differences) and B = df/du (the b-coefficients of eq. 17)::

    u = u* - K (x - x*),   K = R^-1 B^T P,   A^T P + P A - P B R^-1 B^T P + Q = 0

Q = diag(depth_weight, vertical_velocity_weight, pitch_weight, pitch_rate_weight) and
R = diag(fin_weight, cavitator_weight); both deflections are used. The design is
integer-order: for the FOM, the closed-loop eigenvalues of A - BK all have |arg| > pi/2, so by
Matignon's test (eq. 30) the linearised FOM loop is stable for every alpha in (0, 1]. The
deflections are clamped to the limits (like eq. 31). Stateless.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fohssv_sim.control import Controller, deflection_limit
from fohssv_sim.params import ParameterSpec, spec_field, validate_fields

from .state_feedback import StateFeedback

__all__ = ['LQR', 'LQRParameters', 'LQRDesign', 'design']


def _weight(name: str, default: float, unit: str, text: str) -> ParameterSpec:
    return ParameterSpec(name, '-', default, unit, text, low=0.0, low_open=False, high=1e12,
                         high_open=False, needs_reset=False)


@dataclass(frozen=True)
class LQRParameters:
    """Design speed, LQR weights and deflection limits. Validated on construction.

    Defaults follow Bryson's rule: 1 cm of depth, 1 mrad of pitch, 0.1 m/s of w, 1 rad/s of
    q and 0.05 rad of either deflection cost about the same.
    """

    design_speed: float = spec_field(ParameterSpec(
        'design_speed', 'V', 75.0, 'm/s', 'speed of the linearisation (operating point of '
        'eq. 31 at this speed)', low=0.0, high=1000.0, high_open=False, needs_reset=False))
    depth_weight: float = spec_field(_weight('depth_weight', 1e4, '1/m^2', 'Q weight on z'))
    vertical_velocity_weight: float = spec_field(_weight(
        'vertical_velocity_weight', 100.0, 's^2/m^2', 'Q weight on w'))
    pitch_weight: float = spec_field(_weight('pitch_weight', 1e6, '1/rad^2',
                                             'Q weight on theta'))
    pitch_rate_weight: float = spec_field(_weight('pitch_rate_weight', 1.0, 's^2/rad^2',
                                                  'Q weight on q'))
    fin_weight: float = spec_field(ParameterSpec(
        'fin_weight', '-', 400.0, '1/rad^2', 'R weight on delta_f', low=0.0, high=1e12,
        high_open=False, needs_reset=False))
    cavitator_weight: float = spec_field(ParameterSpec(
        'cavitator_weight', '-', 400.0, '1/rad^2', 'R weight on delta_c', low=0.0, high=1e12,
        high_open=False, needs_reset=False))
    max_cavitator_deflection: float = spec_field(deflection_limit('max_cavitator_deflection',
                                                        '|delta_c| is clamped to this'))
    max_fin_deflection: float = spec_field(deflection_limit('max_fin_deflection',
                                                  '|delta_f| is clamped to this'))

    def __post_init__(self) -> None:
        validate_fields(self)


@dataclass(frozen=True)
class LQRDesign:
    """The operating point and gain of one design."""

    state: np.ndarray           # x*
    inputs: np.ndarray          # u* = (delta_f, delta_c)
    A: np.ndarray
    B: np.ndarray
    K: np.ndarray               # 2 x 4
    closed_loop_eigenvalues: np.ndarray


@functools.lru_cache(maxsize=32)
def design(params: LQRParameters) -> LQRDesign:
    """Solve the LQR problem for ``params`` (cached: the parameters are immutable).

    Raises:
        ValueError: no operating point at that speed, or the Riccati equation has no
            stabilising solution.
    """
    from scipy.linalg import solve_continuous_are

    from fohssv_sim.coefficients import coefficients
    from fohssv_sim.equilibria import closed_loop_rhs, find_equilibria, jacobian
    from fohssv_sim.params import ModelParameters

    model = ModelParameters(model='delay-free', speed=params.design_speed,
                            planing_form='smooth')
    eqs = find_equilibria(model, StateFeedback())
    if not eqs:
        raise ValueError(f'lqr: no eq. 31 operating point at design_speed='
                         f'{params.design_speed:g} m/s')
    eq = min(eqs, key=lambda e: abs(e.state[1]))
    x_eq = np.asarray(eq.state, dtype=float)
    u_eq = np.asarray(eq.inputs, dtype=float)
    ufix = (float(u_eq[0]), float(u_eq[1]))
    A = jacobian(closed_loop_rhs(model, lambda t, x: ufix), x_eq)
    c = coefficients(model)
    B = np.array([[0.0, 0.0], [c.b21, c.b22], [0.0, 0.0], [c.b41, c.b42]])
    Q = np.diag([params.depth_weight, params.vertical_velocity_weight, params.pitch_weight,
                 params.pitch_rate_weight])
    R = np.diag([params.fin_weight, params.cavitator_weight])
    try:
        P = solve_continuous_are(A, B, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ValueError(f'lqr: the Riccati equation has no stabilising solution for '
                         f'{params}: {exc}') from None
    K = np.linalg.solve(R, B.T @ P)
    eig = np.linalg.eigvals(A - B @ K)
    return LQRDesign(state=x_eq, inputs=u_eq, A=A, B=B, K=K, closed_loop_eigenvalues=eig)


class LQR(Controller):
    """u = u* - K (x - x*): see the module docstring for the design. Stateless."""

    name = 'lqr'
    Parameters = LQRParameters

    def reset(self) -> None:
        d = design(self.params)
        self._x = tuple(float(v) for v in d.state)
        self._u = tuple(float(v) for v in d.inputs)
        self._k = tuple(tuple(float(v) for v in row) for row in d.K)

    def update(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        e = [float(state[i]) - self._x[i] for i in range(4)]
        kf, kc = self._k
        df = self._u[0] - (kf[0] * e[0] + kf[1] * e[1] + kf[2] * e[2] + kf[3] * e[3])
        dc = self._u[1] - (kc[0] * e[0] + kc[1] * e[1] + kc[2] * e[2] + kc[3] * e[3])
        return df, dc

    def affine(self) -> tuple[list[list[float]], list[float]]:
        """u = -K x + (u* + K x*): the same law in the batched runners' form."""
        k = [list(row) for row in self._k]
        u0 = [self._u[i] + sum(k[i][j] * self._x[j] for j in range(4)) for i in range(2)]
        return [[-v for v in row] for row in k], u0
