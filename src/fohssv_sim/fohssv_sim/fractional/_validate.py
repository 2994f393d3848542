"""Argument checks shared by the fractional solvers.

Every message names the parameter, its value, the allowed range and the unit, e.g.
``fractional_order alpha=1.3 is outside (0, 1] (dimensionless)``.
"""

from __future__ import annotations

import math

import numpy as np


def check_alpha(alpha: object) -> float:
    """Return ``alpha`` as a float in (0, 1]; raise ValueError otherwise."""
    try:
        a = float(alpha)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(
            f"fractional_order alpha={alpha!r} is outside (0, 1] (dimensionless)") from None
    if not (0.0 < a <= 1.0):
        raise ValueError(f"fractional_order alpha={a!r} is outside (0, 1] (dimensionless)")
    return a


def check_step(step: object) -> float:
    """Return ``step`` as a finite positive float (seconds); raise ValueError otherwise."""
    try:
        h = float(step)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"step h={step!r} is outside (0, inf) (s)") from None
    if not (h > 0.0 and math.isfinite(h)):
        raise ValueError(f"step h={h!r} is outside (0, inf) (s), must be finite")
    return h


def check_t0(t0: object) -> float:
    """Return ``t0`` as a finite float (seconds); raise ValueError otherwise."""
    try:
        t = float(t0)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"t0={t0!r} is outside (-inf, inf) (s)") from None
    if not math.isfinite(t):
        raise ValueError(f"t0={t!r} is outside (-inf, inf) (s), must be finite")
    return t


def check_state(x0: object, name: str = 'x0', shape: tuple[int, ...] | None = None,
                ndim: int = 1) -> np.ndarray:
    """Return ``x0`` as a finite float64 array of ``ndim`` dimensions (and ``shape``).

    Raises:
        ValueError: wrong shape or non-finite entries (message names ``name`` and the value).
    """
    try:
        x = np.array(x0, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={x0!r} is not a real array (state units)") from None
    if x.ndim != ndim or x.size == 0:
        raise ValueError(f"{name} must be a non-empty {ndim}-D array (state units), "
                         f"got shape {x.shape}")
    if shape is not None and x.shape != shape:
        raise ValueError(f"{name} must have shape {shape} (state units), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name}={x.tolist()!r} must be finite, i.e. in (-inf, inf) "
                         f"(state units)")
    return x


def check_positive_int(value: object, name: str, low: int = 1, unit: str = 'steps') -> int:
    """Return ``value`` as an int >= ``low``; raise ValueError otherwise."""
    try:
        v = int(value)  # type: ignore[call-overload]
        ok = v == value and v >= low
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise ValueError(f"{name}={value!r} is outside [{low}, inf) ({unit}), must be an integer")
    return v


def check_tolerance(tol: object) -> float:
    """Return ``tol`` as a float in [1e-13, 1e-2]; raise ValueError otherwise."""
    try:
        t = float(tol)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"tolerance={tol!r} is outside [1e-13, 1e-2] (relative)") from None
    if not (1e-13 <= t <= 1e-2):
        raise ValueError(f"tolerance={t!r} is outside [1e-13, 1e-2] (relative)")
    return t
