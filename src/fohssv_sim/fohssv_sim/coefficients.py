"""Coefficients of the HSSV dive-plane model (docs/model.md §3; paper eqs. 5-21, Appendix A).

    d/dt [z, w, theta, q] = A x + B u + G + D Fp,     u = [delta_f, delta_c]

with the nose as reference point (hence T, the inverse determinant of the mass matrix, in
every coefficient), and the cavity quantities of eqs. 9-14.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .params import PARAMETERS, ModelParameters, ParameterError

__all__ = ['Coefficients', 'KernelCoefficients', 'coefficients']


class KernelCoefficients(NamedTuple):
    """The scalars the model's arithmetic reads (eq. 17, the planing forces): the compiled
    kernels of :mod:`.kernels` receive them as one float array in this order."""

    V: float
    L: float
    R: float
    g: float
    a22: float
    a24: float
    a42: float
    a44: float
    b21: float
    b22: float
    b41: float
    b42: float
    d2: float
    d4: float
    R_prime: float
    Rc_dot: float
    k: float
    w0: float


@dataclass(frozen=True)
class Coefficients:
    """Numbers derived from :class:`ModelParameters`; see :func:`coefficients`.

    The scalars of :class:`KernelCoefficients` (``kernel``) read as attributes too
    (``c.V``, ``c.a22``, ...). Scalars are plain floats (the plant's step evaluates them in
    float arithmetic); ``A``, ``B``, ``G``, ``D`` are the matrices of eq. 17 as read-only
    numpy arrays.
    """

    kernel: KernelCoefficients
    C: float
    S: float
    T: float
    K1: float
    K2: float
    Rc: float
    tau: float
    A: np.ndarray
    B: np.ndarray
    G: np.ndarray
    D: np.ndarray

    def __getattr__(self, name: str) -> float:
        # only called for names the dataclass does not have: the kernel's scalars
        if name != 'kernel' and name in KernelCoefficients._fields:
            return getattr(self.kernel, name)
        raise AttributeError(f'Coefficients has no attribute {name!r}')

    @property
    def contact_velocity(self) -> float:
        """|w| at which the tail first touches the cavity wall in the delay-free model:
        R'RV/L (m/s)."""
        return self.R_prime * self.R * self.V / self.L


def coefficients(p: ModelParameters) -> Coefficients:
    """Evaluate every coefficient of docs/model.md §3.2 and §3.3 for the parameters ``p``.

    Exact fractions are used where the paper prints rounded decimals (0.18 -> 11/60,
    0.328 -> 133/405, 0.7 -> 7/9, 0.2 -> 17/36 or 11/36).

    Raises:
        ParameterError: legal but extreme values (e.g. ``speed=1e308``) whose coefficients
            overflow; the message names the values that differ from the defaults.
    """
    try:
        c = _coefficients(p)
    except (OverflowError, ZeroDivisionError, ValueError):
        c = None
    if c is None or not all(math.isfinite(v) for v in (*c.kernel, c.C, c.S, c.T, c.K1, c.K2,
                                                        c.Rc)):
        changed = ', '.join(f'{s.name}={getattr(p, s.name)!r}' for s in PARAMETERS
                            if isinstance(s.default, float) and getattr(p, s.name) != s.default)
        raise ParameterError(f"the model's coefficients overflow with {changed or 'these values'}"
                             ': each is inside its range, but together they leave the floating-'
                             'point range; give values nearer the vehicle\'s scale')
    return c


def _coefficients(p: ModelParameters) -> Coefficients:
    V, L, R, Rn = p.speed, p.length, p.body_radius, p.cavitator_radius
    m, n, sigma = p.density_ratio, p.fin_effectiveness, p.cavitation_number

    Cx = p.cavitator_drag_coefficient * (1.0 + sigma)
    C = 0.5 * Cx * Rn**2 / R**2
    S = (11.0 / 60.0) * R**2 + (133.0 / 405.0) * L**2
    T = 1.0 / ((7.0 / 9.0) * S - (17.0 / 36.0) ** 2 * L**2)

    a22 = (C * V * T / m) * (-(1.0 + n) * S / L + (17.0 / 36.0) * n * L)
    a24 = V * T * S * (7.0 / 9.0 - C * n / m) - V * T * (17.0 / 36.0 - C * n / m) * (
        17.0 / 36.0) * L**2
    a42 = (C * V * T / m) * (17.0 / 36.0 - 11.0 * n / 36.0)
    a44 = -11.0 * C * V * T * n * L / (36.0 * m)
    b21 = (C * V**2 * T * n / m) * (-S / L + 17.0 * L / 36.0)
    b22 = -C * V**2 * T * S / (m * L)
    b41 = -11.0 * C * V**2 * T * n / (36.0 * m)
    b42 = 17.0 * C * V**2 * T / (36.0 * m)
    d2 = (T / m) * (S / L - 17.0 * L / 36.0)
    d4 = 11.0 * T / (36.0 * m)

    # Cavity at the transom (eqs. 12-14) and its contraction rate (docs/model.md §9.4: negative).
    closure = 1.92 / sigma - 3.0
    K1 = L / (Rn * closure) - 1.0
    shape = 1.0 - 4.5 * sigma / (1.0 + sigma)
    K2 = math.sqrt(1.0 - shape * K1 ** (40.0 / 17.0))
    radius_scale = math.sqrt(0.82 * (1.0 + sigma) / sigma)
    Rc = Rn * radius_scale * K2
    Rc_dot = -(20.0 / 17.0) * radius_scale * V * shape * K1 ** (23.0 / 17.0) / (K2 * closure)
    R_prime = (Rc - R) / R

    w0 = R_prime * R * V / L if p.planing_offset == 'consistent' else float(p.planing_offset)

    A = np.array([[0.0, 1.0, -V, 0.0],
                  [0.0, a22, 0.0, a24],
                  [0.0, 0.0, 0.0, 1.0],
                  [0.0, a42, 0.0, a44]])
    B = np.array([[0.0, 0.0], [b21, b22], [0.0, 0.0], [b41, b42]])
    G = np.array([0.0, p.gravity, 0.0, 0.0])
    D = np.array([0.0, d2, 0.0, d4])
    for arr in (A, B, G, D):
        arr.setflags(write=False)

    kernel = KernelCoefficients(
        V=V, L=L, R=R, g=p.gravity, a22=a22, a24=a24, a42=a42, a44=a44, b21=b21, b22=b22,
        b41=b41, b42=b42, d2=d2, d4=d4, R_prime=R_prime, Rc_dot=Rc_dot, k=p.tanh_sharpness,
        w0=w0)
    return Coefficients(kernel=kernel, C=C, S=S, T=T, K1=K1, K2=K2, Rc=Rc, tau=p.delay,
                        A=A, B=B, G=G, D=D)
