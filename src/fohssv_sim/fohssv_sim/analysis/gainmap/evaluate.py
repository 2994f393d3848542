"""One chunk of a gain map: each point simulated, classified and scored."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ...params import ModelParameters
from ..orbits import classify
from .spec import _INT, _STR, GainMapSpec, _controller, outcome


# -- one chunk ---------------------------------------------------------------------------
def _equilibrium(params: ModelParameters, ctl: Any) -> tuple[float, float, float]:
    """(alpha_c, w*, delta_c*) of the closed-loop equilibrium nearest the cavity centre,
    NaNs when none is found or the search fails (a law whose command overflows on the way,
    e.g. ``--gain depth_gain=1e308``: the point's run is still classified); alpha_c NaN for
    a controller with internal states."""
    from ...equilibria import find_equilibria

    stateless = getattr(ctl, 'stateless', True)
    if not stateless:
        return math.nan, math.nan, math.nan
    try:
        eqs = find_equilibria(params, ctl)
    except FloatingPointError:       # NonFiniteCommand in the search: no linearisation here
        return math.nan, math.nan, math.nan
    if not eqs:
        return math.nan, math.nan, math.nan
    e = min(eqs, key=lambda e: abs(e.state[1]))
    return float(e.critical_order), float(e.state[1]), float(e.inputs[1])


def _simulate_points(spec: GainMapSpec, params: list[ModelParameters], ctls: list[Any],
                     batched: bool, progress: Callable[[float], None] | None):
    """t, states (P, n, 4), delta_c (P, n), failed (P,) of the points, sampled from t = 0."""
    from ...batch import simulate_batch
    from ...simulate import simulate

    every = spec.every(params[0].step)
    if batched:
        res = simulate_batch(params, ctls, spec.duration, control_period=spec.control_period,
                             sample_every=every, progress=progress)
        K = np.stack([np.asarray(c.affine()[0], dtype=float)[1] for c in ctls])
        u0 = np.array([float(np.asarray(c.affine()[1], dtype=float)[1]) for c in ctls])
        lim = np.array([getattr(c.params, 'max_cavitator_deflection', math.inf) for c in ctls])
        dc = np.einsum('pj,pnj->pn', K, res.states) + u0[:, None]
        dc = np.clip(dc, -lim[:, None], lim[:, None])
        return res.t, res.states, dc, np.asarray(res.failed, dtype=bool)
    runs = []
    for i, (p, c) in enumerate(zip(params, ctls)):
        try:
            runs.append(simulate(p, c, spec.duration, control_period=spec.control_period,
                                 sample_every=every))
        except FloatingPointError:     # non-finite, out of the physical bounds
            runs.append(None)
        if progress is not None:
            progress((i + 1) / len(params))
    ok = next((r for r in runs if r is not None), None)
    t = ok.t if ok is not None else np.arange(
        int(math.ceil(spec.duration / params[0].step - 1e-9)) // every + 1) * params[0].step * every
    states = np.full((len(params), t.size, 4), np.nan)
    dc = np.full((len(params), t.size), np.nan)
    for i, r in enumerate(runs):
        if r is not None:
            states[i], dc[i] = r.state, r.inputs[:, 1]
    return t, states, dc, np.array([r is None for r in runs])


def _settle_time(t: np.ndarray, w: np.ndarray, w_eq: float, band: float,
                 transient: float) -> float:
    if math.isnan(w_eq):
        return math.nan
    out = np.abs(w - w_eq) > band * max(abs(w_eq), 0.1)
    idx = np.flatnonzero(out)
    if idx.size == 0:
        return float(t[0])
    settle = float(t[idx[-1] + 1]) if idx[-1] + 1 < t.size else math.inf
    return settle if settle <= transient + 1e-12 else math.inf


#: Share of a chunk's progress given to the runs; the equilibrium search (alpha_c, settle
#: reference), which is not batched, takes the rest (about 40 % of a batched chunk's time).
SIM_SHARE = 0.6


def scheduled_gains(law: type, gains: dict[str, Any], params: ModelParameters
                    ) -> dict[str, Any]:
    """``gains`` with the :attr:`~fohssv_sim.control.Controller.scheduling` parameters of
    the controller class ``law`` (e.g. the ``scheduled`` law's ``speed``) set from the
    scenario's ``params``."""
    follow = getattr(law, 'scheduling', {})
    if not follow:
        return gains
    return {**gains, **{c: getattr(params, m) for c, m in follow.items()}}


def evaluate_points(spec: Any, params: list[ModelParameters], ctls: list[Any],
                    eq_keys: Sequence[Any], *, batched: bool | None = None,
                    settle_to_final: bool = False,
                    progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """Run and score closed loops: point j is the model ``params[j]`` under ``ctls[j]``.

    ``spec``: the run settings (attributes ``duration``, ``transient``, ``control_period``,
    ``settle_band``, ``steady_rtol``, ``rel_tol`` and ``every(step)``, as :class:`GainMapSpec`).
    Points with equal ``eq_keys[j]`` share the closed-loop equilibrium (same law, same V:
    alpha does not move it), found once. ``batched``: None = one batched solver call when
    every law is affine, else point by point. ``settle_to_final``: when no equilibrium is
    known (a controller with internal states) settle to the run's last w instead of NaN.
    Returns one row per point with the metric columns of the module docstring (``outcome``
    ... ``path``).
    """
    from ...coefficients import coefficients
    from ...planing import planing_exact_array, planing_smooth_array

    if batched is None:
        batched = all(c.affine() is not None for c in ctls)
    # progress: the runs are the first SIM_SHARE of the chunk, the equilibria the rest
    sim_report = None if progress is None else (lambda f: progress(SIM_SHARE * f))
    t, states, dc, failed = _simulate_points(spec, params, ctls, batched, sim_report)
    eq_cache: dict[Any, tuple[float, float, float]] = {}
    for j, key in enumerate(eq_keys):
        if key not in eq_cache:
            eq_cache[key] = _equilibrium(params[j], ctls[j])
        if progress is not None:
            progress(SIM_SHARE + (1.0 - SIM_SHARE) * (j + 1) / len(eq_keys))
    win = t >= spec.transient - 1e-12
    rows = []
    for j, key in enumerate(eq_keys):
        alpha_c, w_eq, dc_eq = eq_cache[key]
        x = states[j]
        v = params[j].speed
        row = {'alpha_c': alpha_c, 'eq_w': w_eq, 'eq_dc': dc_eq, 'step': params[j].step,
               'path': 'batched' if batched else 'per-point'}
        bad = bool(failed[j]) or not np.isfinite(x).all() or bool(
            np.any(np.abs(x[:, 1]) > v) or np.any(np.abs(x[:, 2]) > math.pi / 2))
        if bad:
            row.update(outcome='diverged', label='diverged', kind='diverged', period=0,
                       k01=math.nan, amplitude=math.nan, failed=True, peak_fp=math.inf,
                       peak_fp_window=math.inf, settle_time=math.inf, effort_rms=math.inf)
            rows.append(row)
            continue
        cls, _ = classify(t[win], x[win, 1], steady_rtol=spec.steady_rtol,
                          rel_tol=spec.rel_tol)
        c = coefficients(params[j])
        fp_law = planing_smooth_array if params[j].planing_form == 'smooth' else \
            planing_exact_array
        fp = np.abs(fp_law(x[:, 1], c))
        w_ref = float(x[-1, 1]) if settle_to_final and math.isnan(w_eq) else w_eq
        row.update(outcome=outcome(cls.kind), label=cls.label, kind=cls.kind,
                   period=cls.period, k01=cls.k01, amplitude=cls.amplitude, failed=False,
                   peak_fp=float(fp.max()), peak_fp_window=float(fp[win].max()),
                   settle_time=_settle_time(t, x[:, 1], w_ref, spec.settle_band,
                                           spec.transient),
                   effort_rms=float(np.sqrt(np.mean(dc[j] ** 2))))
        rows.append(row)
    return rows


def run_points(spec_dict: dict[str, Any], indices: Sequence[int], *,
               batched: bool | None = None, step_factor: float = 1.0,
               progress: Callable[[float], None] | None = None) -> list[dict[str, Any]]:
    """The rows of the points ``indices`` of the gain map ``spec_dict`` (one Dask task).

    ``batched``: None = batched when the controller is affine, else point by point; False
    forces the per-point :func:`~fohssv_sim.simulate.simulate` loop (the benchmark's and the
    tests' reference). ``step_factor``: the model's step times this (the half-step check).
    Deterministic: any scheduler gives the same rows.
    """
    spec = GainMapSpec.from_dict(spec_dict)
    info = [spec.point(i) for i in indices]
    params = [spec.params_for(a, v, step_factor) for _, _, _, a, v in info]
    ctls = [_controller(spec.law, scheduled_gains(spec.law, spec.gains_for(ix, iy), p))
            for (_, ix, iy, _, _), p in zip(info, params)]
    scored = evaluate_points(spec, params, ctls, [(pair, v) for pair, _, _, _, v in info],
                             batched=batched, progress=progress)
    rows = []
    for i, (pair, ix, iy, a, v), row in zip(indices, info, scored):
        rows.append({'point': i, 'pair': pair, 'ix': ix, 'iy': iy, 'x': spec.x_values[ix],
                     'y': spec.y_values[iy], 'alpha': a, 'speed': v, **row})
    return rows


def decode_row(r: dict[str, str], ints: Sequence[str], strs: Sequence[str] = _STR
               ) -> dict[str, Any]:
    """A chunk row read back as text: ``ints`` as int, ``strs`` as str, ``failed`` as bool,
    every other column as float (the gain map's and the tuner's rows)."""
    out: dict[str, Any] = {}
    for k, v in r.items():
        if k in ints:
            out[k] = int(v)
        elif k in strs:
            out[k] = v
        elif k == 'failed':
            out[k] = v == 'True'
        else:
            out[k] = float(v)
    return out


def _decode(r: dict[str, str]) -> dict[str, Any]:
    return decode_row(r, _INT)
