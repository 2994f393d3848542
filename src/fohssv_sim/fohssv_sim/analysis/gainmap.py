"""Gain maps: two gains of a controller swept over a grid, each closed loop classified and
scored, with the linearisation's Matignon boundary (issue 15; docs/gainmap.md).

A map is a grid of gain pairs (``gain_x`` x ``gain_y``, every other controller parameter
fixed) run over one scenario (model, alpha, V), or over an envelope of scenarios (a grid of V
and alpha) for the worst case. Each (pair, scenario) is a point; points are split into chunks
that run as Dask tasks through the sweeps' machinery (:func:`.sweep.run_chunks`: chunk CSV
files, sidecar ``gainmap.json``, resume, progress per point), so an interrupted map resumes
where it stopped.

Per chunk, the points of an affine controller (``Controller.affine()``: the eq. 31
``state_feedback`` law, ``lqr``) run in **one** batched solver call
(:func:`fohssv_sim.batch.simulate_batch`); controllers with internal memory
(``fractional_pid``) run point by point with :func:`fohssv_sim.simulate.simulate` (column
``path``). Every run starts from x(0) = 0, under a zero-order hold of ``control_period``
(default 1e-4 s, the plant's default).

Per point (columns of the rows; all from samples every ``sample_every`` steps, by default
one per control period, so the held command is sampled exactly):

* ``outcome``: the classifier of :mod:`.orbits` on w after ``transient``, grouped as
  steady (settled or converging) < drifting < periodic < chaotic (aperiodic: chaotic or
  quasi-periodic, the 0-1 statistic K in ``k01``) < diverged (non-finite state, or |w| > V or
  |theta| > pi/2, the plant's physical bounds); ``label`` keeps the classifier's label.
* ``peak_fp``: max |Fp| (normalised planing force, m^2/s^2) over the whole run;
  ``peak_fp_window`` over the window after the transient (for a steady loop, the
  equilibrium's own |Fp|: the tail planes at rest).
* ``settle_time``: the first sample time after which |w - w*| <= settle_band * max(|w*|,
  0.1 m/s) holds to the end of the run, with x* the closed-loop equilibrium nearest the
  cavity centre; inf when w leaves the band anywhere in the window after ``transient`` (a
  settling seen only at the very end is not verifiable), NaN if no equilibrium was found.
* ``effort_rms``: RMS of the cavitator command delta_c (rad, after clamping) over the whole
  run (the held commands; it includes the trim delta_c* of the equilibrium).
* ``alpha_c``: the critical order min |arg lambda| / (pi/2) of the Jacobian of the closed
  loop at x* (:mod:`fohssv_sim.equilibria`); Matignon-stable at the scenario's alpha iff
  alpha < alpha_c. NaN for controllers with internal fractional states (no linearisation of
  the closed loop in the 4-state form) and when no equilibrium was found.
  ``eq_w`` / ``eq_dc``: w* and delta_c* of that equilibrium.

Diverged points get inf for peak_fp, settle_time and effort_rms.

Worst case over an envelope (:meth:`GainMapResult.worst`): per gain pair, the highest-ranked
outcome, the largest peak_fp / settle_time / effort_rms, and ``alpha_margin`` = the smallest
alpha_c(V) - alpha over the envelope (the linear boundary is where it crosses 0).

Pure: numpy, scipy, dask, matplotlib (Agg); never imports rclpy or the CLI.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..params import ModelParameters, ParameterError
from .orbits import METHOD, STEADY_RTOL, classify
from .sweep import ChunkedResult, check_half_step, read_chunk_rows, run_chunks

__all__ = ['GainMapSpec', 'GainMapResult', 'GainMapError', 'OUTCOMES', 'OUTCOME_RANK',
           'outcome', 'controller_parameters', 'run_gain_map', 'summary_lines', 'run_points',
           'load_gain_map', 'plot_gain_map', 'METRICS', 'ROW_FIELDS', 'evaluate_points',
           'scheduled_gains']

#: Outcomes from best to worst (the worst case over an envelope takes the highest rank).
OUTCOMES = ('steady', 'drifting', 'periodic', 'chaotic', 'diverged')
OUTCOME_RANK = {o: i for i, o in enumerate(OUTCOMES)}
OUTCOME_COLORS = {'steady': 'tab:green', 'drifting': 'tab:cyan', 'periodic': 'tab:blue',
                  'chaotic': 'tab:red', 'diverged': 'k'}

#: Metric columns with their axis labels.
METRICS = {'settle_time': 'time to settle in the band (s)',
           'peak_fp': 'peak |Fp| over the run (m²/s²)',
           'effort_rms': 'RMS of δc over the run (rad)'}

ROW_FIELDS = ('point', 'pair', 'ix', 'iy', 'x', 'y', 'alpha', 'speed', 'outcome', 'label',
              'kind', 'period', 'k01', 'amplitude', 'failed', 'peak_fp', 'peak_fp_window',
              'settle_time', 'effort_rms', 'alpha_c', 'eq_w', 'eq_dc', 'step', 'path')
_INT = ('point', 'pair', 'ix', 'iy', 'period')
_STR = ('outcome', 'label', 'kind', 'path')

METRIC_TEXT = ('outcome: orbit classifier on w after the transient (steady = settled or '
               'converging); peak_fp: max |Fp| over the run; settle_time: first time after '
               'which |w - w*| <= settle_band * max(|w*|, 0.1 m/s) to the end (inf: out of the '
               'band in the window after the transient; NaN: no equilibrium); effort_rms: '
               'RMS of the held delta_c over the run; alpha_c: '
               'min |arg lambda| / (pi/2) of the closed-loop Jacobian at x* (NaN: controller '
               'with internal states or no equilibrium)')


class GainMapError(ValueError):
    """A gain map that cannot be run as specified (the message names the value and what is
    allowed)."""


def outcome(kind: str) -> str:
    """The map's outcome for a classifier kind (see the module docstring)."""
    return {'steady': 'steady', 'drifting': 'drifting',
            'periodic': 'periodic', 'aperiodic': 'chaotic'}.get(kind, 'diverged')


def controller_parameters(name: str) -> dict[str, Any]:
    """The :class:`~fohssv_sim.params.ParameterSpec` of every parameter of the controller
    plugin ``name``, by name.

    Raises:
        GainMapError: unknown controller (lists the valid ones) or fohssv_controller missing.
    """
    from ..control import UnknownController, load
    from ..params import field_specs

    try:
        cls = load(name)
    except UnknownController as e:
        raise GainMapError(str(e)) from None
    return {s.name: s for s in field_specs(cls.Parameters)}


def _controller(name: str, gains: dict[str, Any]) -> Any:
    from ..control import load

    try:
        return load(name)(**gains)
    except (ParameterError, TypeError, ValueError) as e:
        raise GainMapError(str(e)) from None


@dataclass(frozen=True)
class GainMapSpec:
    """Everything that defines a gain map's numbers (recorded in the sidecar).

    ``x_values`` / ``y_values``: the grids of ``gain_x`` / ``gain_y`` (strictly increasing);
    ``gains``: the controller's other parameters (defaults otherwise); ``base``: model
    parameters (names of the parameter table) shared by every point, without
    fractional_order and speed. The scenario is (``alpha``, ``speed``); with
    ``envelope_speeds`` and/or ``envelope_alphas`` the points are the envelope grid instead
    (a missing list is the scenario's value). Times in s; ``settle_band`` relative (see the
    module docstring); ``sample_every`` 0 = one sample per control period.
    """

    controller: str
    gain_x: str
    x_values: tuple[float, ...]
    gain_y: str
    y_values: tuple[float, ...]
    gains: dict[str, Any] = field(default_factory=dict)
    base: dict[str, Any] = field(default_factory=dict)
    alpha: float = 0.85
    speed: float = 75.0
    envelope_speeds: tuple[float, ...] = ()
    envelope_alphas: tuple[float, ...] = ()
    duration: float = 2.0
    transient: float = 1.5
    control_period: float | None = 1e-4
    sample_every: int = 0
    settle_band: float = 0.02
    chunk_size: int = 128
    check_step: int = 0           # re-run every k-th point at half step (0 = off)
    steady_rtol: float = STEADY_RTOL   # steady tolerance, relative to w's scale
    rel_tol: float = 1e-3

    # -- grid ----------------------------------------------------------------------------
    @property
    def envelope(self) -> bool:
        return bool(self.envelope_speeds or self.envelope_alphas)

    def scenarios(self) -> list[tuple[float, float]]:
        """(alpha, V) of each scenario: the envelope grid (V outer), or the one scenario."""
        speeds = self.envelope_speeds or (self.speed,)
        alphas = self.envelope_alphas or (self.alpha,)
        if not self.envelope:
            return [(self.alpha, self.speed)]
        return [(a, v) for v in speeds for a in alphas]

    def pairs(self) -> list[tuple[int, int]]:
        """(ix, iy) of each gain pair, x fastest."""
        return [(ix, iy) for iy in range(len(self.y_values)) for ix in range(len(self.x_values))]

    def point(self, i: int) -> tuple[int, int, int, float, float]:
        """(pair, ix, iy, alpha, V) of point ``i`` (pair-major, scenario fastest)."""
        sc = self.scenarios()
        pair, s = divmod(i, len(sc))
        ix, iy = self.pairs()[pair]
        return pair, ix, iy, sc[s][0], sc[s][1]

    def has_scenario(self, alpha: float, speed: float) -> bool:
        """True when (``alpha``, ``speed``) is one of the scenarios (to rounding)."""
        return any(abs(a - alpha) < 1e-9 and abs(v - speed) < 1e-9
                   for a, v in self.scenarios())

    @property
    def n_points(self) -> int:
        return len(self.pairs()) * len(self.scenarios())

    def params_for(self, alpha: float, speed: float, step_factor: float = 1.0
                   ) -> ModelParameters:
        p = ModelParameters.from_dict({**self.base, 'fractional_order': alpha,
                                       'speed': speed})
        return p if step_factor == 1.0 else p.replace(step=p.step * step_factor)

    def gains_for(self, ix: int, iy: int) -> dict[str, Any]:
        return {**self.gains, self.gain_x: self.x_values[ix], self.gain_y: self.y_values[iy]}

    def controller_for(self, ix: int, iy: int) -> Any:
        return _controller(self.controller, self.gains_for(ix, iy))

    def every(self, step: float) -> int:
        if self.sample_every:
            return self.sample_every
        if self.control_period is None:
            return 5
        return max(1, round(self.control_period / step))

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for k in ('x_values', 'y_values', 'envelope_speeds', 'envelope_alphas'):
            d[k] = list(d[k])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GainMapSpec:
        d = dict(d)
        for k in ('x_values', 'y_values', 'envelope_speeds', 'envelope_alphas'):
            d[k] = tuple(d.get(k, ()))
        return cls(**d)

    # -- validation ----------------------------------------------------------------------
    def validate(self) -> None:
        """Check names and ranges before anything runs.

        Raises:
            GainMapError: unknown controller or gain (lists the controller's parameters), a
                grid value outside the parameter's range (name, value, allowed range), a grid
                that is not strictly increasing, bad scenario values.
        """
        specs = controller_parameters(self.controller)
        self._validate_names(specs)
        self._validate_grids(specs)
        _controller(self.controller, self.gains_for(0, 0))   # the fixed gains as a whole
        self._validate_scenario()

    def _validate_names(self, specs: dict[str, Any]) -> None:
        names = ', '.join(sorted(specs))
        for opt, name in (('gain_x', self.gain_x), ('gain_y', self.gain_y)):
            if name not in specs:
                raise GainMapError(f'{self.controller} has no parameter {name!r} ({opt}); its '
                                   f'parameters: {names}')
            if not specs[name].numeric:
                raise GainMapError(f'{self.controller} parameter {name!r} is not numeric')
        if self.gain_x == self.gain_y:
            raise GainMapError(f'the two swept gains must differ (both {self.gain_x!r})')
        for name in self.gains:
            if name not in specs:
                raise GainMapError(f'{self.controller} has no parameter {name!r}; its '
                                   f'parameters: {names}')
            if name in (self.gain_x, self.gain_y):
                raise GainMapError(f'{name!r} is swept; do not also fix it')

    def _validate_grids(self, specs: dict[str, Any]) -> None:
        for name, values in ((self.gain_x, self.x_values), (self.gain_y, self.y_values)):
            if len(values) < 1:
                raise GainMapError(f'{name}: no values')
            if any(b <= a for a, b in zip(values, values[1:])):
                raise GainMapError(f'{name}: values must be strictly increasing')
            s = specs[name]
            for v in values:
                try:
                    s.validate(v)
                except ParameterError:
                    raise GainMapError(
                        f'{self.controller} parameter {name}={v:g} is outside its allowed '
                        f'range {s.range_text()} {s.unit}'.rstrip()) from None

    def _validate_scenario(self) -> None:
        for a in (self.alpha, *self.envelope_alphas):
            if not 0 < a <= 1:
                raise GainMapError(f'alpha={a:g} is outside (0, 1]')
        for v in (self.speed, *self.envelope_speeds):
            if not v > 0:
                raise GainMapError(f'speed V={v:g} m/s must be > 0')
        if not (self.duration > 0 and 0 <= self.transient < self.duration):
            raise GainMapError(f'need duration > transient >= 0 (got duration '
                               f'{self.duration:g} s, transient {self.transient:g} s)')
        if not self.settle_band > 0:
            raise GainMapError(f'settle_band={self.settle_band:g} must be > 0')
        try:
            for a, v in self.scenarios():
                self.params_for(a, v)
        except ParameterError as e:
            raise GainMapError(str(e)) from None
        p = self.params_for(*self.scenarios()[0])
        if self.control_period is None and not getattr(
                self.controller_for(0, 0), 'stateless', True):
            raise GainMapError(f'{self.controller} keeps internal state: give a control period')
        if self.control_period is not None:
            from ..simulate import steps_per_period

            try:
                steps_per_period(self.control_period, p.step)
            except ValueError as e:
                raise GainMapError(str(e)) from None


# -- one chunk ---------------------------------------------------------------------------
def _equilibrium(params: ModelParameters, ctl: Any) -> tuple[float, float, float]:
    """(alpha_c, w*, delta_c*) of the closed-loop equilibrium nearest the cavity centre,
    NaNs when none is found or the search fails (a law whose command overflows on the way,
    e.g. ``--gain depth_gain=1e308``: the point's run is still classified); alpha_c NaN for
    a controller with internal states."""
    from ..equilibria import find_equilibria

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
    from ..batch import simulate_batch
    from ..simulate import simulate

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


def scheduled_gains(controller: str, gains: dict[str, Any], params: ModelParameters
                    ) -> dict[str, Any]:
    """``gains`` with the controller's :attr:`~fohssv_sim.control.Controller.scheduling`
    parameters (e.g. the ``scheduled`` law's ``speed``) set from the scenario's ``params``."""
    from ..control import load

    follow = getattr(load(controller), 'scheduling', {})
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
    from ..coefficients import coefficients
    from ..planing import planing_exact_array, planing_smooth_array

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
    ctls = [_controller(spec.controller, scheduled_gains(spec.controller,
                                                         spec.gains_for(ix, iy), p))
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


# -- the map -----------------------------------------------------------------------------
class GainMapResult(ChunkedResult):
    """All rows of a gain map (sorted by point) and its sidecar."""

    @property
    def spec(self) -> GainMapSpec:
        return GainMapSpec.from_dict(self.sidecar['spec'])

    def scenario_rows(self, alpha: float, speed: float) -> list[dict[str, Any]]:
        """The rows of one scenario, in pair order."""
        return [r for r in self.rows
                if abs(r['alpha'] - alpha) < 1e-9 and abs(r['speed'] - speed) < 1e-9]

    def worst(self) -> list[dict[str, Any]]:
        """Per gain pair (pair order), the worst case over the scenarios: highest-ranked
        outcome, largest metrics, ``alpha_margin`` = min (alpha_c - alpha); also the
        scenario of the worst outcome (``worst_alpha``, ``worst_speed``)."""
        by_pair: dict[int, list[dict[str, Any]]] = {}
        for r in self.rows:
            by_pair.setdefault(r['pair'], []).append(r)
        out = []
        for pair in sorted(by_pair):
            rs = by_pair[pair]
            w = max(rs, key=lambda r: OUTCOME_RANK[r['outcome']])
            row = {k: rs[0][k] for k in ('pair', 'ix', 'iy', 'x', 'y')}
            row.update(outcome=w['outcome'], label=w['label'], worst_alpha=w['alpha'],
                       worst_speed=w['speed'], n_scenarios=len(rs))
            for m in ('peak_fp', 'settle_time', 'effort_rms'):
                row[m] = float(np.max([r[m] for r in rs]))
            row['alpha_margin'] = float(np.min([r['alpha_c'] - r['alpha'] for r in rs]))
            out.append(row)
        return out

    def grid(self, rows: Sequence[dict[str, Any]], name: str) -> np.ndarray:
        """Column ``name`` of ``rows`` (one per pair) as an (ny, nx) array."""
        s = self.spec
        g = np.full((len(s.y_values), len(s.x_values)), np.nan, dtype=object
                    if name in ('outcome', 'label') else float)
        for r in rows:
            g[r['iy'], r['ix']] = r[name]
        return g


def summary_lines(result: GainMapResult) -> list[str]:
    """What a map shows, as text: per scenario shown (the nominal one, and the worst case
    over an envelope) the outcome counts, how many pairs the linearisation and the
    simulation agree on (Matignon-stable iff steady), and the steady pair that settles
    first."""
    s, side = result.spec, result.sidecar
    lines = [f"step {side['step']:g} s, solver {side['solver']}, model {side['model']}, "
             f"samples every {side['sample_every']} steps; {result.computed_chunks} chunks "
             f'computed, {result.reused_chunks} reused']
    views = []
    if s.has_scenario(s.alpha, s.speed):
        rows = result.scenario_rows(s.alpha, s.speed)
        for r in rows:
            r['alpha_margin'] = r['alpha_c'] - r['alpha']
        views.append((f'alpha = {s.alpha:g}, V = {s.speed:g} m/s', rows))
    if s.envelope:
        views.append((f'worst case over {len(s.scenarios())} scenarios', result.worst()))
    checked = [r for r in result.rows if r.get('step_check')]
    if checked:
        changed = [r for r in checked if r['step_check'] != 'same']
        lines.append(f'step check: {len(checked)} points re-run at half step, {len(changed)} '
                     'changed outcome' + ''.join(
                         f"\n  {s.gain_x}={r['x']:g}, {s.gain_y}={r['y']:g}, alpha={r['alpha']:g},"
                         f" V={r['speed']:g}: {r['outcome']} {r['step_check']}"
                         for r in changed[:10]))
    for title, rows in views:
        counts = {o: sum(r['outcome'] == o for r in rows) for o in OUTCOMES}
        lines.append(f'{title}: ' + ', '.join(f'{o} {n}' for o, n in counts.items() if n))
        known = [r for r in rows if not math.isnan(r['alpha_margin'])]
        if known:
            agree = sum((r['alpha_margin'] > 0) == (r['outcome'] == 'steady') for r in known)
            lines.append(f'  Matignon (alpha_c > alpha) vs simulated steady: agree at '
                         f'{agree}/{len(known)} pairs')
        else:
            lines.append('  Matignon boundary: not available (no linearisation)')
        steady = [r for r in rows if r['outcome'] == 'steady' and math.isfinite(
            r['settle_time'])]
        if steady:
            b = min(steady, key=lambda r: r['settle_time'])
            lines.append(f"  settles first: {s.gain_x}={b['x']:g}, {s.gain_y}={b['y']:g} in "
                         f"{b['settle_time']:.3g} s (peak |Fp| {b['peak_fp']:.3g} m^2/s^2, RMS "
                         f"delta_c {b['effort_rms']:.3g} rad)")
    return lines


def _sidecar(spec: GainMapSpec, chunks: list[list[int]]) -> dict[str, Any]:
    from .. import __version__

    p0 = spec.params_for(*spec.scenarios()[0])
    return {'spec': spec.to_dict(), 'step': p0.step, 'solver': p0.solver, 'model': p0.model,
            'planing_form': p0.planing_form, 'sample_every': spec.every(p0.step),
            'classification': METHOD, 'metrics': METRIC_TEXT, 'n_points': spec.n_points,
            'chunks': chunks, 'fohssv_version': __version__,
            'python': sys.version.split()[0], 'numpy': np.__version__}


def _chunks(spec: GainMapSpec) -> list[list[int]]:
    from ..batch import group_points

    params = [spec.params_for(a, v) for *_, a, v in map(spec.point, range(spec.n_points))]
    chunks = []
    for idx in group_points(params).values():
        for s in range(0, len(idx), spec.chunk_size):
            chunks.append(idx[s:s + spec.chunk_size])
    return sorted(chunks, key=lambda c: c[0])


def load_gain_map(out: Path) -> GainMapResult:
    """Read a (finished or partial) gain-map folder."""
    import json

    side = json.loads((out / 'gainmap.json').read_text())
    return GainMapResult(read_chunk_rows(out, len(side['chunks']), _decode), side)


def run_gain_map(spec: GainMapSpec, out: Path, *, scheduler: str | None = None,
                 workers: int = 0, progress: Callable[[int, int, float], None] | None = None,
                 client: Any = None,
                 check_progress: Callable[[int, int, float], None] | None = None
                 ) -> GainMapResult:
    """Run (or resume) the gain map ``spec`` into folder ``out`` on Dask (a local cluster
    with ``workers`` processes, default one per core, or the cluster at ``scheduler``, or
    ``client``). ``progress(done, total, elapsed)`` counts points. With ``spec.check_step``
    = k, every k-th point is re-run at half the step in this process (``check_progress``
    counts those) and its row's ``step_check`` says whether the outcome changed.

    Raises:
        GainMapError: an invalid spec (see :meth:`GainMapSpec.validate`), or ``out`` holds
            another job.
    """
    spec.validate()
    chunks = _chunks(spec)
    try:
        computed, reused = run_chunks(out, 'gainmap.json', _sidecar(spec, chunks), chunks,
                                      run_points, (spec.to_dict(),), ROW_FIELDS,
                                      scheduler=scheduler, workers=workers,
                                      progress=progress, client=client)
    except ValueError as e:
        if isinstance(e, GainMapError):
            raise
        raise GainMapError(str(e)) from None
    result = load_gain_map(out)
    result.computed_chunks, result.reused_chunks = computed, reused
    if spec.check_step:
        check_half_step(out, result.rows, spec.check_step,
                        lambda i: spec.params_for(*spec.point(i)[3:]),
                        functools.partial(run_points, spec.to_dict()), 'outcome',
                        check_progress)
    return result


# -- figures -----------------------------------------------------------------------------
def _edges(values: Sequence[float]) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    if v.size == 1:
        return np.array([v[0] - 0.5, v[0] + 0.5])
    mid = 0.5 * (v[1:] + v[:-1])
    return np.r_[v[0] - (mid[0] - v[0]), mid, v[-1] + (v[-1] - mid[-1])]


def _caption(result: GainMapResult) -> str:
    side, s = result.sidecar, result.spec
    cp = s.control_period
    hold = 'continuous feedback' if cp is None else f'ZOH {cp:g} s'
    fixed = ', '.join(f'{k}={v:g}' if isinstance(v, float) else f'{k}={v}'
                      for k, v in s.gains.items())
    return (f"{side['model']} model, solver {side['solver']}, step {side['step']:g} s, {hold}, "
            f'{s.duration:g} s runs (transient {s.transient:g} s), x(0) = 0; '
            f"{s.controller}{' (' + fixed + ')' if fixed else ''}")


def gain_label(controller: str, name: str) -> str:
    """An axis label for a gain: its name and unit, e.g. 'pitch_rate_gain (rad s/rad)'."""
    spec = controller_parameters(controller).get(name)
    unit = getattr(spec, 'unit', '-')
    return name if unit in ('', '-') else f'{name} ({unit})'


def reference_gains(s: GainMapSpec) -> tuple[tuple[float, float], str] | None:
    """The controller's default (x, y) gains and a legend text, when they lie inside the map:
    for eq. 31 (defaults referenced to the paper) the paper's gains, named so when every other
    gain is at its default too."""
    specs = controller_parameters(s.controller)
    x0, y0 = specs[s.gain_x].default, specs[s.gain_y].default
    if not all(isinstance(v, (int, float)) for v in (x0, y0)):
        return None
    inside = (min(s.x_values) <= x0 <= max(s.x_values)
              and min(s.y_values) <= y0 <= max(s.y_values))
    if not inside:
        return None
    eq31 = {k for k, p in specs.items() if getattr(p, 'reference', '') == 'eq. 31'}
    paper = {s.gain_x, s.gain_y} <= eq31 and all(
        specs[k].default == v for k, v in s.gains.items() if k in eq31)
    text = "the paper's gains (eq. 31" if paper else 'default gains ('
    return (float(x0), float(y0)), f'{text}: {x0:g}, {y0:g})'


def _boundary(ax: Any, result: GainMapResult, margin: np.ndarray, what: str,
              unstable_text: str) -> str:
    """Draw the contour margin = 0 (alpha_c - alpha) and mark the Matignon-unstable cells
    (``unstable_text``: when a cell is, e.g. 'α_c < α'); returns a note for the title when
    nothing can be drawn."""
    s = result.spec
    if np.all(np.isnan(margin)):
        return ('Matignon boundary not drawn: no linearisation (controller with internal '
                'fractional states, or no equilibrium)')
    X, Y = np.meshgrid(s.x_values, s.y_values)
    unstable = margin < 0
    ax.plot(X[unstable], Y[unstable], 'x', color='m', ms=4, lw=0.8,
            label=f'linearisation unstable ({unstable_text})')
    finite = np.where(np.isnan(margin), np.nan, margin)
    note = ''
    if margin.shape[0] >= 2 and margin.shape[1] >= 2 and np.nanmin(finite) < 0 < np.nanmax(
            finite):
        ax.contour(X, Y, finite, levels=[0.0], colors='m', linewidths=1.5)
        ax.plot([], [], 'm-', label=f'Matignon boundary: {what} = 0')
    else:
        side = 'below' if np.nanmax(finite) < 0 else 'above'
        note = f'no Matignon boundary in the map ({what} {side} 0 everywhere)'
    if np.any(np.isnan(margin)):
        note += ('; ' if note else '') + 'α_c unknown at some pairs (no equilibrium)'
    return note


def plot_gain_map(result: GainMapResult, stem: Path, *, worst: bool = False,
                  alpha: float | None = None, speed: float | None = None,
                  label: str = '') -> list[Path]:
    """The classification map and one map per metric (:data:`METRICS`), PNG and SVG, with
    the Matignon boundary on each: for one scenario (``alpha``, ``speed``, default the
    spec's) or, with ``worst``, the worst case over the envelope. Files are
    ``<stem>_classes``, ``<stem>_<metric>``; returns the paths written."""
    from matplotlib.colors import BoundaryNorm, ListedColormap

    from .figures import pyplot, save, titled

    plt = pyplot()
    s = result.spec
    if worst:
        rows = result.worst()
        margin = result.grid(rows, 'alpha_margin')
        what = 'min over envelope of α_c(V) − α'
        unstable_text = 'α_c(V) < α somewhere in the envelope'
        speeds = sorted({r['speed'] for r in result.rows})
        alphas = sorted({r['alpha'] for r in result.rows})
        head = (f'worst case over V ∈ [{speeds[0]:g}, {speeds[-1]:g}] m/s ({len(speeds)}), '
                f'α ∈ [{alphas[0]:g}, {alphas[-1]:g}] ({len(alphas)})')
    else:
        alpha = s.alpha if alpha is None else alpha
        speed = s.speed if speed is None else speed
        rows = result.scenario_rows(alpha, speed)
        for r in rows:
            r['alpha_margin'] = r['alpha_c'] - r['alpha']
        margin = result.grid(rows, 'alpha_margin')
        what = 'α_c − α'
        unstable_text = 'α_c < α'
        head = f'α = {alpha:g}, V = {speed:g} m/s'
    if not rows:
        raise GainMapError(f'no points of scenario alpha={alpha}, V={speed} in the map')
    xe, ye = _edges(s.x_values), _edges(s.y_values)
    written: list[Path] = []

    shown = {r['pair'] for r in rows}
    changed = {r['pair'] for r in result.rows if r['pair'] in shown and r.get(
        'step_check', 'same') not in ('same', '')}
    pairs = s.pairs()

    reference = reference_gains(s)

    def finish(fig: Any, ax: Any, name: str, title: str) -> None:
        note = _boundary(ax, result, margin, what, unstable_text)
        if changed:
            ax.plot([s.x_values[pairs[k][0]] for k in sorted(changed)],
                    [s.y_values[pairs[k][1]] for k in sorted(changed)], 'o', mfc='none',
                    mec='orange', ms=9, label='outcome changes at half step')
        if reference is not None:
            (x0, y0), text = reference
            ax.plot([x0], [y0], '*', color='gold', mec='k', mew=0.8, ms=15, ls='none',
                    label=text)
        ax.set_xlabel(gain_label(s.controller, s.gain_x))
        ax.set_ylabel(gain_label(s.controller, s.gain_y))
        ax.set_title(titled(f'{title}, {head}\n{_caption(result)}' + (
            f'\n{note}' if note else ''), label), fontsize=7)
        handles, names = ax.get_legend_handles_labels()
        # below the plot, on the figure: centred under the axes it was cut at the edges when a
        # colour bar narrows them
        fig.tight_layout(rect=(0, 0.03 * ((len(names) + 1) // 2) + 0.02 if names else 0, 1, 1))
        if names:
            fig.legend(handles, names, fontsize=7, loc='lower center', ncol=2, frameon=False)
        paths = [stem.parent / f'{stem.name}_{name}.png', stem.parent / f'{stem.name}_{name}.svg']
        save(fig, paths, dpi=120)
        plt.close(fig)
        written.extend(paths)

    classes = result.grid(rows, 'outcome')
    codes = np.vectorize(lambda o: OUTCOME_RANK.get(o, np.nan) if isinstance(o, str)
                         else np.nan, otypes=[float])(classes)
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    cmap = ListedColormap([OUTCOME_COLORS[o] for o in OUTCOMES])
    ax.pcolormesh(xe, ye, np.ma.masked_invalid(codes), cmap=cmap,
                  norm=BoundaryNorm(np.arange(len(OUTCOMES) + 1) - 0.5, len(OUTCOMES)))
    present = set(classes.ravel().tolist())
    for o in OUTCOMES:
        if o in present:
            ax.fill_between([], [], color=OUTCOME_COLORS[o], label=o)
    finish(fig, ax, 'classes', ('worst outcome' if worst else 'outcome') + ' of each gain pair')

    for m, axis_label in METRICS.items():
        g = result.grid(rows, m)
        fig, ax = plt.subplots(figsize=(7.5, 6.5))
        finite = np.isfinite(g)
        if finite.any():
            mesh = ax.pcolormesh(xe, ye, np.ma.masked_where(~finite, g), cmap='viridis')
            fig.colorbar(mesh, ax=ax, label=axis_label)
        inf = np.isinf(g)
        if inf.any():
            ax.pcolormesh(xe, ye, np.ma.masked_where(~inf, np.ones_like(g)), cmap=ListedColormap(
                ['0.6']), vmin=0, vmax=1)
            ax.fill_between([], [], color='0.6', label='inf (never settles / diverged)')
        finish(fig, ax, m, ('worst ' if worst else '') + axis_label)
    return written
