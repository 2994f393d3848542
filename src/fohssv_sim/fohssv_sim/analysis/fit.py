"""Identify model parameters (the fractional order first) from a run (issue 23).

**Problem.** The FOM (eqs. 26-30, 'soe' solver, compiled) is run from the run's initial state
with parameters ``names`` free in ``bounds`` and every other parameter as the run recorded it
(``--set`` overrides), driven either

* open loop by the run's own commands, each held from its recorded time (zero-order hold, as
  the lockstep plant applies them), or
* closed loop by a controller plugin (``controller``), its command held over each control
  period as through ROS: an affine law runs compiled in the population kernel; any other
  (a law with memory: fractional_pid) point by point through the plant contract
  (:func:`.population.run_population_reference`, a fresh controller per point), slower.

It is compared with the run's states at the control instants in a window [t0, t1]:

* ``trajectory``: weighted least squares on z, w, theta, q; residual r = w_j (x_sim - x_data)
  / s_j with s_j the standard deviation of state j over the window (clipped to +-10: a point
  10 standard deviations off is simply not the run);
* ``cycle``: for periodic or chaotic runs, where a pointwise fit is ill-posed: the frequency of
  w (mean up-crossings), its peak-to-peak amplitude and mean over the window, relative to the
  data's, and the orbit class (:mod:`.orbits`; 1 when it differs).

The *residual* is the RMS of r (dimensionless: standard deviations, or relative errors); the
run is *reproduced* when it is at most ``threshold`` (default 0.05): over the whole window for
a closed loop (``controller``), over the last reproduced horizon for an open-loop replay (see
below: a replay departs from the run from any error, a fitted closed loop only by misfit).

**Open-loop replays diverge.** The vehicle is open-loop unstable (eigenvalue +15.5 1/s at
V = 75, faster with planing contacts): replaying recorded commands through a model whose
parameters differ by 1e-6 departs from the data within tens of milliseconds of tail-slap.
A trajectory fit over a long window would have a basin far narrower than any population.
So (``horizon='auto'``) the fit grows its horizon: stage 0 fits the first 1/2^S of the window
(halved while even that is not reproduced, down to 20 samples), each later stage doubles it,
warm-started from the previous stage, and bisects back towards the last reproduced horizon
where a stage is not reproduced; it reports the last reproduced horizon with its fit
(``horizon_end``). ``horizon='full'`` fits the whole window in one stage. A closed loop is
searched the same way (its basin also narrows as the horizon grows) but judged over the whole
window (``window_residual``).

**Global, then local.** Each stage evaluates a population (until a horizon is reproduced: a
Latin hypercube over the bounds; later stages: the current estimate and, per parameter the last
stage could not see, a line of values over its bounds through it) in batched compiled calls
(:mod:`.population`, one per chunk) on Dask, through the sweeps' chunk machinery
(:func:`.sweep.run_chunks`: chunk CSV files under ``out/population/``, resume, progress per
point). The best ``starts`` points (later stages: the best one, normally the warm start) start
``scipy.optimize.least_squares`` (trf, within the bounds, ending at a relative step of
:data:`LOCAL_TOL`; the Jacobian by forward differences: each new point is simulated with its p
perturbed points in one batched call split over ``threads``, so the Jacobian least_squares asks
for at an accepted point is already there).

**Cost** (``bench/bench_fit.py``): the kernel's ~1.2 us per step and point; a one-parameter
fit of a 2 s bag simulates about 120 full-length points (the coarse and fine profiles and the
half-step check are most of it once the horizon grows warm-started).

**Uncertainty.** At the estimate, the Jacobian interval x +- t_{0.975, N-p} sigma with
cov = s^2 (J^T J)^-1, s^2 = sum r^2 / (N - p); and a profile of the objective over alpha (or the
first name): a coarse profile over the whole bounds with the other names at the estimate (the
figure; it shows whether any alpha comes near), and a fine one around the estimate with the
other names re-optimised, whose interval is {alpha: SSR(alpha) <= SSR_min + s^2 chi2_1(0.95)}.
The reported interval of alpha is the hull of the two; of the others, the Jacobian interval.
Both assume the residuals are independent noise; with a model that cannot reproduce the run
they are not confidence intervals and the result says so (``reproduces`` false).

Pure: numpy, scipy, dask, matplotlib (Agg); never imports rclpy or the CLI.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..params import PARAMETER_BY_NAME, PARAMETERS, ModelParameters, ParameterError
from .orbits import classify
from .population import run_population, run_population_reference

__all__ = ['FitError', 'FitSpec', 'FitData', 'FitResult', 'OBJECTIVES', 'fittable_names',
           'check_names', 'resolve_bounds', 'data_from_run', 'data_from_simulation',
           'base_from_run', 'run_fit', 'write_outputs', 'params_yaml', 'bag_sha256',
           'DEFAULT_THRESHOLD', 'STATE_NAMES', 'summary_line', 'reference_data',
           'write_reference', 'Problem']

OBJECTIVES = ('trajectory', 'cycle')
STATE_NAMES = ('z', 'w', 'theta', 'q')
DEFAULT_THRESHOLD = 0.05
#: Residual of a sample where the simulation failed (or is more than this many scales off).
CLIP = 10.0
#: Parameters that are numbers but not fit targets: solver settings and the delayed model's
#: delay (which the FOM does not have).
NOT_FITTED = {'step': 'a solver setting', 'soe_tolerance': 'a solver setting',
              'soe_horizon_steps': 'a solver setting',
              'advection_delay': "the delayed model's delay; it does not enter the FOM"}


class FitError(ValueError):
    """A fit that cannot run as asked; the message names the option or value and what is
    allowed (the CLI prints it as one line, exit 2)."""


def fittable_names() -> list[str]:
    """The numeric model parameters a fit can estimate (the parameter table's order)."""
    return [s.name for s in PARAMETERS if s.numeric and s.name not in NOT_FITTED]


def check_names(names: Sequence[str]) -> tuple[str, ...]:
    """The names, checked: each a numeric model parameter, none twice.

    Raises:
        FitError: naming the first bad name and listing the valid ones.
    """
    valid = fittable_names()
    if not names:
        raise FitError(f"--fit names no parameter; numeric model parameters: {', '.join(valid)}")
    for n in names:
        if n in NOT_FITTED:
            raise FitError(f'--fit {n}: {NOT_FITTED[n]}, not a model parameter to fit; numeric '
                           f"model parameters: {', '.join(valid)}")
        if n not in valid:
            what = 'not numeric' if n in PARAMETER_BY_NAME else 'not a model parameter'
            raise FitError(f'--fit {n}: {what}; numeric model parameters: {", ".join(valid)}')
    if len(set(names)) != len(names):
        raise FitError(f"--fit {','.join(names)}: a name appears twice")
    return tuple(names)


def _default_bounds(name: str, value: Any) -> tuple[float, float]:
    """The allowed range of ``name``; an open end is moved inside by 1e-2 of the range; an
    infinite end (or an end at 0 below a value) is a decade from the run's value."""
    s = PARAMETER_BY_NAME[name]
    v = float(value) if not isinstance(value, str) else float('nan')
    if not math.isfinite(v):            # 'consistent' etc.: the spec default is a name too
        v = 1.0
    hi = s.high if s.high is not None and math.isfinite(s.high) else 10.0 * abs(v)
    lo = s.low if s.low is not None else -10.0 * abs(v)
    if s.low == 0.0 and s.high is None:
        lo = abs(v) / 10.0
    span = hi - lo
    if s.low is not None and lo == s.low and s.low_open:
        lo += 1e-2 * span
    if s.high is not None and hi == s.high and s.high_open:
        hi -= 1e-3 * span
    return float(lo), float(hi)


def resolve_bounds(names: Sequence[str], given: dict[str, tuple[float, float]],
                   base: ModelParameters) -> tuple[tuple[float, float], ...]:
    """The search bounds of each name: ``given`` (checked) or the parameter's allowed range.

    Raises:
        FitError: bounds for a name not fitted, an end outside the allowed range (name, value,
            range, unit), or low >= high.
    """
    extra = sorted(set(given) - set(names))
    if extra:
        raise FitError(f'--bounds {extra[0]}: not among the fitted names ({", ".join(names)})')
    out = []
    for n in names:
        if n not in given:
            out.append(_default_bounds(n, getattr(base, n)))
            continue
        lo, hi = given[n]
        s = PARAMETER_BY_NAME[n]
        for v in (lo, hi):
            try:
                s.validate(v)
            except ParameterError:
                unit = f' {s.unit}' if s.unit and s.unit != '-' else ''
                raise FitError(f'--bounds {n}={lo:g}:{hi:g}: {v:g} is outside the allowed range '
                               f'{s.range_text()}{unit} ({s.description})') from None
        if not lo < hi:
            raise FitError(f'--bounds {n}={lo:g}:{hi:g}: the low end must be below the high end')
        out.append((float(lo), float(hi)))
    return tuple(out)


# -- data ----------------------------------------------------------------------------------
@dataclass
class FitData:
    """The run at the control instants t_k = k * control_period, k = 0 .. n_periods.

    ``states[k]`` NaN where the run has no sample; ``inputs[k]`` the command held over period
    k (None: the run has no command, closed loop only); ``initial_state`` the state at t = 0;
    ``duration`` what the recording plant sized its 'soe' horizon for (None = open-ended).
    """

    t: np.ndarray
    states: np.ndarray
    inputs: np.ndarray | None
    control_period: float
    initial_state: tuple[float, float, float, float]
    duration: float | None = None
    source: dict[str, Any] = field(default_factory=dict)

    @property
    def n_periods(self) -> int:
        return self.t.size - 1


def bag_sha256(path: Path) -> str:
    """sha256 of the bag's MCAP file(s), in the order the bag lists them."""
    from ..bag.loader import locate

    h = hashlib.sha256()
    for f in locate(path).mcap_files:
        with open(f, 'rb') as fh:
            for block in iter(lambda: fh.read(1 << 20), b''):
                h.update(block)
    return h.hexdigest()


def base_from_run(run: Any, overrides: dict[str, Any] | None = None,
                  preset: str = 'resolved') -> ModelParameters:
    """The FOM parameters the fit starts from: the model parameters the run's plant recorded
    (its parameter table's names), the model set to 'fractional' (step and solver re-resolved
    when the run was another model), then ``overrides``.

    Raises:
        FitError: an override or recorded value the parameter table refuses.
    """
    recorded = {k: v for k, v in run.parameters.items() if k in PARAMETER_BY_NAME}
    values = dict(recorded)
    if values.get('model', 'fractional') != 'fractional':
        values['step'] = 'auto'
        values['solver'] = 'auto'
    values['model'] = 'fractional'
    if values.get('solver') not in (None, 'auto', 'soe'):
        values['solver'] = 'soe'            # the population kernel is the compiled 'soe' one
    values.update(overrides or {})
    try:
        return ModelParameters.preset(preset, **values)
    except ParameterError as e:
        raise FitError(str(e)) from None


def data_from_run(run: Any, base: ModelParameters, control_period: float | None = None
                  ) -> FitData:
    """The run's states at the control instants and its commands held per period.

    The control period is the recorded plant's (``control_period``) unless given, else the
    median spacing of the state times; it must be a whole multiple of the step.

    Raises:
        FitError: no state samples, a control period that is not a multiple of the step,
            state times off the control instants.
    """
    from ..params import steps_per_period

    if run.t.size == 0:
        raise FitError(f'{run.path}: no state messages to fit')
    params = run.parameters
    cp = control_period or params.get('control_period')
    if not cp:
        cp = float(np.median(np.diff(run.t))) if run.t.size > 1 else 0.0
    cp = float(cp)
    try:
        steps_per_period(cp, base.step)
    except ValueError as e:
        raise FitError(str(e)) from None
    k = np.round(run.t / cp).astype(np.int64)
    off = np.abs(run.t - k * cp)
    if np.any(off > 1e-9 * max(cp, 1.0)) or np.any(k < 0):
        raise FitError(f'{run.path}: state times are not at multiples of control_period='
                       f'{cp:g} s (e.g. t = {run.t[np.argmax(off)]!r} s); give --control-period')
    n = int(k.max())
    states = np.full((n + 1, 4), np.nan)
    states[k] = run.state
    if np.isfinite(states[0]).all():
        x0 = tuple(float(v) for v in states[0])
    else:
        x0 = tuple(float(v) for v in params.get('initial_state', (0.0, 0.0, 0.0, 0.0)))
    inputs = None
    if run.command_t.size:
        order = np.argsort(run.command_t, kind='stable')
        ct = run.command_t[order]
        cmd = np.column_stack([run.delta_f[order], run.delta_c[order]])
        t = np.arange(n) * cp
        j = np.searchsorted(ct, t + 1e-9 * cp, side='right') - 1     # last command at or before
        inputs = np.where(j[:, None] >= 0, cmd[np.maximum(j, 0)], 0.0)
        if not np.isfinite(inputs).all():
            raise FitError(f'{run.path}: a recorded command is not finite')
    duration = params.get('duration')
    duration = float(duration) if isinstance(duration, (int, float)) and duration > 0 else None
    return FitData(t=np.arange(n + 1) * cp, states=states, inputs=inputs, control_period=cp,
                   initial_state=x0, duration=duration,
                   source={'bag': str(run.path), 'recovery': run.recovery})


def data_from_simulation(t: np.ndarray, states: np.ndarray, control_period: float,
                         source: dict[str, Any], duration: float | None = None) -> FitData:
    """A closed-loop reference run (no commands) sampled every control period."""
    return FitData(t=np.asarray(t, dtype=float), states=np.asarray(states, dtype=float),
                   inputs=None, control_period=control_period,
                   initial_state=tuple(float(v) for v in states[0]), duration=duration,
                   source=source)


# -- the problem ---------------------------------------------------------------------------
@dataclass(frozen=True)
class FitSpec:
    """Everything that defines a fit's numbers (recorded in fit.json).

    ``base``: the FOM's parameters (table names) apart from ``names``; ``window`` in s (None =
    the whole run); ``controller`` None = open loop on the recorded commands; ``weights`` per
    state (z, w, theta, q); ``stages`` the horizon doublings of ``horizon='auto'``.
    """

    names: tuple[str, ...]
    bounds: tuple[tuple[float, float], ...]
    base: dict[str, Any]
    objective: str = 'trajectory'
    window: tuple[float, float] | None = None
    controller: str | None = None
    gains: dict[str, Any] = field(default_factory=dict)
    weights: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    threshold: float = DEFAULT_THRESHOLD
    horizon: str = 'auto'
    stages: int = 4
    max_stages: int = 16
    population: int = 64
    starts: int = 2
    seed: int = 0
    profile_points: int = 41
    fine_points: int = 11
    chunk_size: int = 16
    max_nfev: int = 20
    step_check: bool = True

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d['names'] = list(self.names)
        d['bounds'] = [list(b) for b in self.bounds]
        d['window'] = list(self.window) if self.window else None
        d['weights'] = list(self.weights)
        return d

    def validate(self) -> None:
        """Raises FitError for an unknown objective, horizon, or a bad count."""
        if self.objective not in OBJECTIVES:
            raise FitError(f"--objective {self.objective!r}: choose one of "
                           f"{' | '.join(OBJECTIVES)}")
        if self.horizon not in ('auto', 'full'):
            raise FitError(f"--horizon {self.horizon!r}: choose 'auto' or 'full'")
        if not (self.threshold > 0 and math.isfinite(self.threshold)):
            raise FitError(f'--threshold {self.threshold:g} must be a positive number')
        for name, v, low in (('--population', self.population, 2), ('--starts', self.starts, 1),
                             ('--profile-points', self.profile_points, 3),
                             ('--chunk-size', self.chunk_size, 1)):
            if v < low:
                raise FitError(f'{name} {v} must be >= {low}')
        if any(not (w >= 0 and math.isfinite(w)) for w in self.weights) or not any(self.weights):
            raise FitError(f'--weights {list(self.weights)}: need non-negative weights, one > 0')


class Problem:
    """The objective of one fit: the data in the window, the base parameters, the drive.
    Picklable (it travels to the Dask workers)."""

    def __init__(self, spec: FitSpec, data: FitData) -> None:
        self.spec = spec
        self.data = data
        self.base = ModelParameters.from_dict(spec.base)
        self.hold = round(data.control_period / self.base.step)
        t = data.t
        t0, t1 = spec.window if spec.window else (0.0, float(t[-1]))
        eps = 1e-9 * data.control_period
        self.window = (float(t0), float(t1))
        ok = np.isfinite(data.states).all(axis=1) & (t >= t0 - eps) & (t <= t1 + eps)
        ok[0] = False            # t = 0 is the initial state the model starts from, not data
        self.index = np.flatnonzero(ok)
        if self.index.size < (2 if spec.objective == 'trajectory' else 8):
            have = t[np.isfinite(data.states).all(axis=1)]
            span = f'[{have[0]:g}, {have[-1]:g}] s' if have.size else 'nothing'
            raise FitError(f'--window {t0:g}:{t1:g} s holds {self.index.size} state sample(s) '
                           f'(the run spans {span}); the {spec.objective} objective needs more')
        x = data.states[self.index]
        scale = x.std(axis=0)
        scale = np.where(scale > 0, scale, np.maximum(np.abs(x).max(axis=0), 1.0))
        self.scale = scale
        w = np.asarray(spec.weights, dtype=float)
        self.w = w / np.sqrt(np.mean(w[w > 0] ** 2)) if w.any() else w
        self.law = None
        if spec.controller is not None:
            # None: a plugin that is not affine, run point by point (see simulate)
            self.law = _packed_law(spec.controller, spec.gains)
        elif data.inputs is None:
            raise FitError(f"{data.source.get('bag', 'the run')}: no command messages, so the "
                           'recorded commands cannot drive the model; give --controller NAME '
                           'to close the loop with a plugin')
        if spec.objective == 'cycle':
            self.features = cycle_features(t[self.index], x[:, 1])

    # -- evaluation ------------------------------------------------------------------------
    def params_for(self, values: Sequence[float]) -> ModelParameters | None:
        try:
            return self.base.replace(**{n: float(v) for n, v in zip(self.spec.names, values)})
        except ParameterError:
            return None

    def first_horizon(self) -> int:
        """Samples of the first stage: the whole window ('full', or the cycle objective),
        else 1/2^stages of it (at least 20 samples)."""
        m = self.index.size
        if self.spec.horizon == 'full' or self.spec.objective == 'cycle':
            return m
        return min(m, max(20, int(math.ceil(m / 2 ** self.spec.stages))))

    def simulate(self, values: Sequence[Sequence[float]], upto: int, threads: int = 1):
        """(PopulationResult, valid mask) of the points ``values`` up to sample ``upto``
        (``threads``: see :func:`.population.run_population`)."""
        params = [self.params_for(v) for v in values]
        valid = np.array([p is not None for p in params])
        n = int(self.index[upto - 1])
        ok = [p for p in params if p is not None]
        if not ok:
            return None, valid
        d = self.data
        if self.spec.controller is not None and self.law is None:
            # no compiled form (a law with memory, e.g. fractional_pid): each point through
            # the plant contract with a fresh controller, its command held per period
            from ..control import make

            spec = self.spec
            return run_population_reference(
                ok, n, self.hold, controller=lambda: make(spec.controller, spec.gains),
                initial_state=d.initial_state, duration=d.duration), valid
        kwargs: dict[str, Any] = {'initial_state': d.initial_state, 'duration': d.duration,
                                  'threads': threads}
        if self.law is not None:
            kwargs['law'] = self.law
        else:
            kwargs['inputs'] = d.inputs[:n]
        return run_population(ok, n, self.hold, **kwargs), valid

    def residuals(self, values: Sequence[Sequence[float]], upto: int | None = None,
                  threads: int = 1) -> np.ndarray:
        """(P, M) residual rows of the points ``values`` over the first ``upto`` samples."""
        upto = self.index.size if upto is None else upto
        res, valid = self.simulate(values, upto, threads)
        sel = self.index[:upto]
        if self.spec.objective == 'trajectory':
            M = sel.size * 4
            out = np.full((len(values), M), CLIP)
            if res is None:
                return out
            data = self.data.states[sel]
            r = (res.states[:, sel] - data[None]) * (self.w / self.scale)
            r = np.where(np.isfinite(r), np.clip(r, -CLIP, CLIP), CLIP).reshape(len(r), M)
            out[valid] = r
            return out
        out = np.full((len(values), 4), CLIP)
        if res is None:
            return out
        rows = []
        for j in range(res.states.shape[0]):
            if res.failed[j]:
                rows.append(np.full(4, CLIP))
            else:
                f = cycle_features(self.data.t[sel], res.states[j, sel, 1])
                rows.append(cycle_residual(f, self.features))
        out[valid] = np.array(rows)
        return out

    def norm(self, r: np.ndarray) -> float:
        """The residual: RMS of a residual row (weights of zero excluded)."""
        if self.spec.objective == 'trajectory':
            keep = np.tile(self.w > 0, r.size // 4)
            r = r[keep]
        return float(np.sqrt(np.mean(r ** 2)))


def _packed_law(name: str, gains: dict[str, Any]) -> np.ndarray | None:
    """The compiled form of the plugin ``name`` with ``gains`` (an affine law), or None (a
    law without one, run point by point).

    Raises:
        FitError: an unknown plugin or a gain it refuses.
    """
    from ..control import UnknownController, make
    from ..models import AffineLaw

    try:
        ctl = make(name, gains)
    except UnknownController as e:
        raise FitError(f'--controller {name}: {e}') from None
    except (ParameterError, TypeError, ValueError) as e:
        raise FitError(f'--gain: {e}') from None
    law = AffineLaw.from_controller(ctl)
    return None if law is None else law.packed


# -- the cycle objective -------------------------------------------------------------------
def cycle_features(t: np.ndarray, w: np.ndarray) -> dict[str, Any]:
    """Frequency (mean up-crossings of w, Hz), peak-to-peak amplitude and mean of w (m/s),
    and the orbit class of w over the samples."""
    w = np.asarray(w, dtype=float)
    mean = float(np.mean(w))
    y = w - mean
    i = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    freq = 0.0
    if i.size >= 2:
        tc = t[i] + (t[i + 1] - t[i]) * (-y[i]) / (y[i + 1] - y[i])
        freq = float((tc.size - 1) / (tc[-1] - tc[0]))
    cls, _ = classify(t, w)
    return {'frequency': freq, 'amplitude': float(np.ptp(w)), 'mean': mean,
            'kind': cls.kind, 'label': cls.label}


def cycle_residual(f: dict[str, Any], d: dict[str, Any]) -> np.ndarray:
    """[relative frequency, relative amplitude, mean / amplitude, class differs] of features
    ``f`` against the data's ``d`` (each clipped to +-CLIP)."""
    amp = max(d['amplitude'], 1e-9)
    r = np.array([(f['frequency'] - d['frequency']) / max(d['frequency'], 1e-9),
                  (f['amplitude'] - d['amplitude']) / amp,
                  (f['mean'] - d['mean']) / max(amp, abs(d['mean']), 1e-9),
                  0.0 if f['kind'] == d['kind'] else 1.0])
    return np.clip(r, -CLIP, CLIP)


# -- population on Dask ----------------------------------------------------------------------
POP_FIELDS = ('point', 'values', 'cost', 'residual')


def population_task(problem: Problem, values: list[list[float]], upto: int,
                    indices: Sequence[int], progress: Callable[[float], None] | None = None,
                    threads: int = 1) -> list[dict[str, Any]]:
    """The rows of the points ``indices`` of ``values`` (one Dask task, one batched call;
    ``threads`` > 1 splits it over threads, in-process only)."""
    pts = [values[i] for i in indices]
    R = problem.residuals(pts, upto, threads)
    if progress is not None:
        progress(1.0)
    return [{'point': i, 'values': list(map(float, pts[j])), 'cost': 0.5 * float(R[j] @ R[j]),
             'residual': problem.norm(R[j])} for j, i in enumerate(indices)]


def _decode_row(r: dict[str, str]) -> dict[str, Any]:
    return {'point': int(r['point']), 'values': [float(v) for v in r['values'].split(';')],
            'cost': float(r['cost']), 'residual': float(r['residual'])}


class Evaluator:
    """Costs of many points: on Dask through :func:`.sweep.run_chunks` (chunk files under
    ``out``, resumable) or, with ``client=None`` and ``workers < 0``, in this process."""

    def __init__(self, problem: Problem, out: Path, client: Any,
                 progress: Callable[[int, int, float], None] | None,
                 sidecar: dict[str, Any], threads: int = 1) -> None:
        self.problem, self.out, self.client, self.progress = problem, out, client, progress
        self.sidecar = sidecar
        self.threads = threads
        self.jobs = 0
        self.points = 0

    def costs(self, name: str, values: np.ndarray, upto: int) -> np.ndarray:
        from .sweep import read_chunk_rows, run_chunks

        vals = [list(map(float, v)) for v in values]
        self.points += len(vals)
        if self.client is None:
            rows = population_task(self.problem, vals, upto, list(range(len(vals))),
                                   threads=self.threads)
        else:
            cs = self.problem.spec.chunk_size
            chunks = [list(range(s, min(s + cs, len(vals)))) for s in range(0, len(vals), cs)]
            folder = self.out / name
            side = {'spec': {**self.sidecar, 'job': name, 'upto': upto, 'values': vals},
                    'chunks': chunks}
            run_chunks(folder, 'population.json', side, chunks, population_task,
                       (self.problem, vals, upto), POP_FIELDS, client=self.client,
                       progress=self.progress)
            rows = read_chunk_rows(folder, len(chunks), _decode_row)
        self.jobs += 1
        rows.sort(key=lambda r: r['point'])
        return np.array([r['cost'] for r in rows])


def _latin(bounds: np.ndarray, n: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    u = qmc.LatinHypercube(d=len(bounds), seed=seed).random(n)
    return np.column_stack([_spread(bounds[j], u[:, j]) for j in range(len(bounds))])


def _spread(b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Values in the bounds ``b`` at fractions ``u``: logarithmic when the bounds are positive
    and span a decade or more, else linear."""
    lo, hi = float(b[0]), float(b[1])
    if lo > 0 and hi / lo >= 10:
        return lo * (hi / lo) ** u
    return lo + u * (hi - lo)


def _lines(bounds: np.ndarray, around: np.ndarray, n: int, seen: np.ndarray) -> np.ndarray:
    """``around`` and, per parameter the last stage could not see (a zero Jacobian column:
    e.g. the planing offset before the first contact), a line of n values over its bounds with
    the others fixed. A parameter it saw is not searched again over its bounds: at a doubled
    horizon its basin is narrower than any line's spacing, and the warm start is what keeps
    it (the coarse profile at the end is the last global check)."""
    p = len(bounds)
    pts = [around]
    for j in range(p):
        if seen[j]:
            continue
        for v in _spread(bounds[j], np.linspace(0.0, 1.0, max(2, n))):
            x = around.copy()
            x[j] = v
            pts.append(x)
    return np.array(pts)


# -- local stage ------------------------------------------------------------------------------
#: Termination of the local stage (scipy's xtol, ftol, gtol): far below any interval, and
#: reached in a handful of iterations from a population's best point.
LOCAL_TOL = 1e-10


class _Local:
    """least_squares with the forward-difference Jacobian: the p perturbed points in one
    batched call. With ``threads`` > 1 every new point is evaluated together with its p
    perturbed points (speculatively: least_squares asks for the Jacobian at each accepted
    point), split over the threads, so an iteration costs one simulation of wall time."""

    def __init__(self, problem: Problem, bounds: np.ndarray, upto: int, threads: int = 1
                 ) -> None:
        self.problem, self.bounds, self.upto = problem, bounds, upto
        self.threads = max(1, int(threads))
        rel = 1e-7 if problem.spec.objective == 'trajectory' else 1e-3
        self.h = rel * (bounds[:, 1] - bounds[:, 0])
        self.cache: dict[tuple, tuple[np.ndarray, np.ndarray | None]] = {}
        self.evaluations = 0

    def _batch(self, pts: list[np.ndarray]) -> np.ndarray:
        self.evaluations += len(pts)
        return self.problem.residuals(pts, self.upto, self.threads)

    def _perturbed(self, x: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        steps, pts = [], []
        for j in range(x.size):
            h = self.h[j] if x[j] + self.h[j] <= self.bounds[j, 1] else -self.h[j]
            e = x.copy()
            e[j] += h
            pts.append(e)
            steps.append(h)
        return pts, np.array(steps)

    def fun(self, x: np.ndarray) -> np.ndarray:
        key = tuple(x.tolist())
        if key not in self.cache:
            if self.threads > 1:
                pts, steps = self._perturbed(x)
                R = self._batch([x, *pts])
                self.cache = {key: (R[0], ((R[1:] - R[0]) / steps[:, None]).T)}
            else:
                self.cache = {key: (self._batch([x])[0], None)}
        return self.cache[key][0]

    def jac(self, x: np.ndarray) -> np.ndarray:
        r0 = self.fun(x)
        key = tuple(x.tolist())
        J = self.cache[key][1]
        if J is None:
            pts, steps = self._perturbed(x)
            R = self._batch(pts)
            J = ((R - r0) / steps[:, None]).T
            self.cache = {key: (r0, J)}
        return J

    def solve(self, x0: np.ndarray, max_nfev: int, fixed: dict[int, float] | None = None):
        from scipy.optimize import least_squares

        lo, hi = self.bounds[:, 0], self.bounds[:, 1]
        x0 = np.clip(x0, lo, hi)
        if fixed:
            free = np.array([j not in fixed for j in range(x0.size)])

            def full(y):
                x = x0.copy()
                x[free] = y
                for j, v in fixed.items():
                    x[j] = v
                return x

            r = least_squares(lambda y: self.fun(full(y)), x0[free],
                              jac=lambda y: self.jac(full(y))[:, free],
                              bounds=(lo[free], hi[free]), x_scale=hi[free] - lo[free],
                              method='trf', max_nfev=max_nfev, xtol=LOCAL_TOL,
                              ftol=LOCAL_TOL, gtol=LOCAL_TOL)
            r.x = full(r.x)
            return r
        return least_squares(self.fun, x0, jac=self.jac, bounds=(lo, hi), x_scale=hi - lo,
                             method='trf', max_nfev=max_nfev, xtol=LOCAL_TOL, ftol=LOCAL_TOL,
                             gtol=LOCAL_TOL)


# -- the fit ------------------------------------------------------------------------------------
@dataclass
class FitResult:
    """What a fit found (see :func:`run_fit`); ``to_dict`` is fit.json."""

    spec: FitSpec
    values: dict[str, float]
    intervals: dict[str, list[float]]
    jacobian_intervals: dict[str, list[float]]
    profile_interval: list[float] | None
    #: what ``reproduces`` compares with the threshold: ``window_residual`` for a closed loop
    #: (``spec.controller``), ``horizon_residual`` for an open-loop replay
    residual: float
    #: over [window start, ``horizon_end``] (the last reproduced horizon, or the last tried)
    horizon_residual: float
    #: over the whole window
    window_residual: float
    reproduces: bool
    horizon_end: float
    window: tuple[float, float]
    stages: list[dict[str, Any]]
    profile: dict[str, Any]
    fitted_states: np.ndarray
    data_states: np.ndarray
    t: np.ndarray
    params: ModelParameters
    settings: dict[str, Any]
    message: str = ''
    #: cycle objective: the features (frequency, amplitude, mean, class of w) of the run and
    #: of the fitted FOM over the window
    cycle: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {'values': self.values, 'intervals': self.intervals,
                'jacobian_intervals': self.jacobian_intervals,
                'profile_interval': self.profile_interval, 'residual': self.residual,
                'horizon_residual': self.horizon_residual,
                'window_residual': self.window_residual,
                'threshold': self.spec.threshold, 'reproduces': self.reproduces,
                'message': self.message, 'objective': self.spec.objective,
                'window': list(self.window), 'horizon_end': self.horizon_end,
                'stages': self.stages, 'profile': self.profile,
                'parameters': self.params.to_dict(), 'settings': self.settings,
                'cycle': self.cycle, 'spec': self.spec.to_dict()}


def _jacobian_interval(local: _Local, x: np.ndarray, r: np.ndarray, bounds: np.ndarray,
                       problem: Problem) -> tuple[np.ndarray, float, int]:
    """(half widths, s^2, dof) of the Jacobian interval at ``x``."""
    from scipy.stats import t as student

    J = local.jac(x)
    n, p = J.shape
    dof = max(n - p, 1)
    s2 = float(r @ r) / dof
    try:
        cov = s2 * np.linalg.pinv(J.T @ J)
        half = student.ppf(0.975, dof) * np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        half = np.full(p, np.inf)
    half = np.where(np.isfinite(half), half, np.inf)
    return half, s2, dof


def _profile_interval(grid: np.ndarray, ssr: np.ndarray, level: float) -> list[float] | None:
    """The connected range of ``grid`` around the minimum of ``ssr`` where ssr <= level,
    crossings interpolated linearly (an end of the grid where it is still below: that end)."""
    ok = np.isfinite(ssr)
    if not ok.any():
        return None
    g, s = grid[ok], ssr[ok]
    i = int(np.argmin(s))
    lo_i = i
    while lo_i > 0 and s[lo_i - 1] <= level:
        lo_i -= 1
    hi_i = i
    while hi_i < s.size - 1 and s[hi_i + 1] <= level:
        hi_i += 1

    def cross(a: int, b: int) -> float:
        if s[b] == s[a]:
            return float(g[a])
        return float(g[a] + (g[b] - g[a]) * (level - s[a]) / (s[b] - s[a]))

    lo = cross(lo_i, lo_i - 1) if lo_i > 0 else float(g[0])
    hi = cross(hi_i, hi_i + 1) if hi_i < s.size - 1 else float(g[-1])
    return [min(lo, float(g[i])), max(hi, float(g[i]))]


def run_fit(spec: FitSpec, data: FitData, out: Path, *, client: Any = None,
            progress: Callable[[int, int, float], None] | None = None,
            log: Callable[[str], None] | None = None, sidecar: dict[str, Any] | None = None,
            threads: int = 0) -> FitResult:
    """Run the fit ``spec`` of ``data``; population jobs go to ``out/population`` on the
    Dask ``client`` (None: in this process). See the module docstring. ``threads``: the
    local stage's (and, without a client, the population's) simulations are split over this
    many threads (0: one per core); the numbers do not depend on it.

    Raises:
        FitError: an invalid spec, an empty window, no commands and no controller.
    """
    import os

    spec.validate()
    say = log or (lambda s: None)
    threads = threads or os.cpu_count() or 1
    problem = Problem(spec, data)
    bounds = np.array(spec.bounds, dtype=float)
    ev = Evaluator(problem, out / 'population', client, progress,
                   {**(sidecar or {}), 'fit': spec.to_dict()}, threads=threads)
    stages: list[dict[str, Any]] = []
    best = None          # (x, r, upto) of the last reproduced stage
    last = None          # of the last stage run
    m = problem.index.size
    upto = problem.first_horizon()
    min_step = max(5, m // 100)
    seen = np.zeros(len(spec.names), dtype=bool)     # which names the last stage could see
    for s in range(spec.max_stages):
        started, cpu = time.monotonic(), time.process_time()
        # a Latin hypercube until a horizon is reproduced (a halved horizon searches afresh:
        # its basin is wider); then lines through the estimate for the names not yet seen
        pts = (_latin(bounds, spec.population, spec.seed) if best is None
               else _lines(bounds, best[0], spec.population, seen))
        costs = ev.costs(f'stage{s}', pts, upto)
        order = np.argsort(costs, kind='stable')
        local = _Local(problem, bounds, upto, threads)
        # a search afresh starts from the best spec.starts points; later stages from the
        # warm start (or a better line point)
        starts = order[:spec.starts if best is None else 1]
        found = [local.solve(pts[j], spec.max_nfev) for j in starts]
        sol = min(found, key=lambda r: r.cost)
        r = local.fun(sol.x)
        seen = np.linalg.norm(sol.jac, axis=0) * (bounds[:, 1] - bounds[:, 0]) > 1e-6
        res = problem.norm(r)
        t_end = float(data.t[problem.index[upto - 1]])
        ok = res <= spec.threshold
        stages.append({'stage': s, 'horizon_end': t_end, 'samples': int(upto),
                       'population': len(pts), 'best_population_cost': float(costs[order[0]]),
                       'values': sol.x.tolist(), 'residual': res, 'reproduced': bool(ok),
                       'nfev': int(sol.nfev), 'evaluations': local.evaluations,
                       'wall_time': time.monotonic() - started,
                       'cpu_time': time.process_time() - cpu})
        say(f'  stage {s}: horizon {t_end:.6g} s ({upto} samples), residual {res:.3g}'
            f"{'' if ok else ' (not reproduced)'} in {time.monotonic() - started:.1f} s "
            f'(CPU {time.process_time() - cpu:.1f} s of this process): '
            + ', '.join(f'{n}={v:.8g}' for n, v in zip(spec.names, sol.x)))
        last = (sol.x, r, upto)
        if ok:
            best = last
            if upto >= m:
                break
            # doubled, or the whole window when less than half a horizon would be left
            upto = m if m - 2 * upto < upto // 2 else 2 * upto
            continue
        growing = spec.horizon == 'auto' and spec.objective == 'trajectory'
        if not growing:
            break
        if best is None:                     # not even the first horizon: halve it
            if upto <= min(m, 20):
                break
            upto = max(min(m, 20), upto // 2)
            continue
        nxt = (best[2] + upto) // 2          # bisect towards the last reproduced horizon
        if nxt - best[2] < min_step:
            break
        upto = nxt
    reproduced = best is not None
    x, r, upto = best if reproduced else last
    local = _Local(problem, bounds, upto, threads)
    started, cpu = time.monotonic(), time.process_time()
    # the coarse profile over the bounds is also a last global check: a better grid point
    # (the population missed its basin) starts one more local fit
    jp = spec.names.index('fractional_order') if 'fractional_order' in spec.names else 0
    coarse = np.linspace(bounds[jp, 0], bounds[jp, 1], spec.profile_points)
    cpts = np.repeat(x[None], coarse.size, axis=0)
    cpts[:, jp] = coarse
    coarse_cost = ev.costs('profile_coarse', cpts, upto)
    r = local.fun(x)
    i = int(np.argmin(coarse_cost))
    if coarse_cost[i] < 0.5 * float(r @ r) * (1 - 1e-9):
        sol = local.solve(cpts[i], spec.max_nfev)
        if sol.cost < 0.5 * float(r @ r):
            x = sol.x
            say(f'  the coarse profile found a better start: {spec.names[jp]}={coarse[i]:.6g} '
                f'-> ' + ', '.join(f'{n}={v:.8g}' for n, v in zip(spec.names, x)))
    r = local.fun(x)
    reproduced = problem.norm(r) <= spec.threshold
    half, s2, dof = _jacobian_interval(local, x, r, bounds, problem)
    jac_iv = {n: [float(max(bounds[j, 0], x[j] - half[j])), float(min(bounds[j, 1],
                                                                       x[j] + half[j]))]
              for j, n in enumerate(spec.names)}
    profile = _profile(problem, ev, local, spec, bounds, x, half, s2, upto, coarse,
                       coarse_cost)
    profile['wall_time'] = time.monotonic() - started
    profile['cpu_time'] = time.process_time() - cpu
    say(f"  profile over {profile['name']}: {len(profile['coarse'])} + "
        f"{len(profile['fine'])} points in {profile['wall_time']:.1f} s (CPU "
        f"{profile['cpu_time']:.1f} s of this process)")
    intervals = {n: list(v) for n, v in jac_iv.items()}
    j0 = profile['index']
    piv = profile.get('interval')
    if piv is not None:
        n0 = spec.names[j0]
        intervals[n0] = [min(jac_iv[n0][0], piv[0]), max(jac_iv[n0][1], piv[1])]
    check = (_step_check(problem, spec, data, bounds, x, upto, say, threads)
             if spec.step_check else None)
    if check is not None:
        for j, n in enumerate(spec.names):
            d = 2.0 * check['shift'][j]
            intervals[n] = [float(max(bounds[j, 0], intervals[n][0] - d)),
                            float(min(bounds[j, 1], intervals[n][1] + d))]
    res = problem.norm(r)
    # the residual over the whole window; a closed loop is judged by it: unlike an open-loop
    # replay (which departs from any error), a fitted closed loop that leaves the run after
    # the reproduced horizon is the model's misfit
    window_res = res if upto >= m else problem.norm(problem.residuals([x])[0])
    if spec.controller is not None:
        reproduced = window_res <= spec.threshold
    t_end = float(data.t[problem.index[upto - 1]])
    sim, _ = problem.simulate([x], problem.index.size)  # the overlay: the whole window
    fitted = sim.states[0] if sim is not None else np.full_like(data.states, np.nan)
    params = problem.params_for(x)
    values = {n: float(v) for n, v in zip(spec.names, x)}
    result = FitResult(spec=spec, values=values, intervals=intervals,
                       jacobian_intervals=jac_iv, profile_interval=piv,
                       residual=window_res if spec.controller is not None else res,
                       horizon_residual=res, window_residual=window_res,
                       reproduces=bool(reproduced), horizon_end=t_end,
                       window=(problem.window[0], float(data.t[problem.index[-1]])),
                       stages=stages, profile=profile,
                       fitted_states=fitted, data_states=data.states, t=data.t,
                       params=params,
                       settings={'model': 'fractional', 'solver': params.solver,
                                 'step': params.step, 'planing_form': params.planing_form,
                                 'control_period': data.control_period,
                                 'loop': _loop_text(problem),
                                 'initial_state': list(data.initial_state),
                                 'dof': dof, 's2': s2, 'population_points': ev.points,
                                 'step_check': check,
                                 'source': data.source})
    if spec.objective == 'cycle':
        sel = problem.index
        result.cycle = {'data': problem.features,
                        'fitted': cycle_features(data.t[sel], fitted[sel, 1])
                        if np.isfinite(fitted[sel, 1]).all() else None}
    result.message = summary_line(result)
    return result


def _loop_text(problem: Problem) -> str:
    """How the fitted model is driven (fit.json's settings, the figures' captions)."""
    if problem.spec.controller is None:
        return 'open (recorded commands, held)'
    how = ('compiled' if problem.law is not None
           else 'not affine: point by point through the plant')
    return f'closed ({problem.spec.controller}, held per control period, {how})'


def _step_check(problem: Problem, spec: FitSpec, data: FitData, bounds: np.ndarray,
                x: np.ndarray, upto: int, say: Callable[[str], None], threads: int = 1
                ) -> dict[str, Any] | None:
    """Refit at half the step from ``x`` (same horizon): the shift of the estimate is the
    discretisation's share of its uncertainty (the intervals are widened by twice it, a
    Richardson bound for a scheme of order >= 1). None when half the step does not divide the
    control period."""
    half = problem.base.step / 2
    hold = data.control_period / half
    if abs(hold - round(hold)) > 1e-9 * hold:
        return None
    try:
        base = problem.base.replace(step=half)
    except ParameterError:
        return None
    started, cpu = time.monotonic(), time.process_time()
    sub = Problem(dataclasses.replace(spec, base=base.to_dict()), data)
    local = _Local(sub, bounds, upto, threads)
    sol = local.solve(x, max(5, spec.max_nfev // 2))
    shift = np.abs(sol.x - x)
    res = sub.norm(local.fun(sol.x))
    say(f'  step check at h = {half:g} s: ' + ', '.join(
        f'{n}={v:.8g} (shift {d:.2g})' for n, v, d in zip(spec.names, sol.x, shift))
        + f', residual {res:.3g}, in {time.monotonic() - started:.1f} s (CPU '
        f'{time.process_time() - cpu:.1f} s)')
    return {'half_step': half, 'values': sol.x.tolist(), 'shift': shift.tolist(),
            'residual': res, 'widening': 'intervals widened by 2 x shift'}


def _profile(problem: Problem, ev: Evaluator, local: _Local, spec: FitSpec,
             bounds: np.ndarray, x: np.ndarray, half: np.ndarray, s2: float, upto: int,
             coarse: np.ndarray, coarse_cost: np.ndarray) -> dict[str, Any]:
    """The coarse (others fixed, given) and fine (others re-optimised) profiles over
    alpha, and the profile interval."""
    from scipy.stats import chi2

    j = spec.names.index('fractional_order') if 'fractional_order' in spec.names else 0
    lo, hi = bounds[j]
    width = half[j] if math.isfinite(half[j]) and half[j] > 0 else 0.01 * (hi - lo)
    width = max(4.0 * width, 1e-9 * (hi - lo))
    fine = np.unique(np.clip(np.linspace(x[j] - width, x[j] + width, spec.fine_points), lo, hi))
    if len(spec.names) == 1:
        fine_cost = ev.costs('profile_fine', fine[:, None], upto)
    else:
        fine_cost = []
        for v in fine:
            sol = local.solve(x, max(3, spec.max_nfev // 4), fixed={j: float(v)})
            fine_cost.append(float(sol.cost))
        fine_cost = np.array(fine_cost)
    r = local.fun(x)
    ssr_min = min(float(r @ r), 2.0 * float(np.nanmin(fine_cost)))
    level = ssr_min + s2 * float(chi2.ppf(0.95, 1))
    interval = _profile_interval(fine, 2 * fine_cost, level)
    scale = 4 * upto if spec.objective == 'trajectory' else 4     # entries of a residual row
    return {'name': spec.names[j], 'index': j, 'coarse': coarse.tolist(),
            'coarse_residual': np.sqrt(2 * coarse_cost / scale).tolist(),
            'fine': fine.tolist(), 'fine_residual': np.sqrt(2 * fine_cost / scale).tolist(),
            'level_residual': math.sqrt(level / scale), 'interval': interval,
            'others': 'held at the estimate (coarse); re-optimised (fine)'}


def summary_line(result: FitResult) -> str:
    """One sentence: the estimate with its interval and residual, or that nothing fits."""
    s = result.spec
    vals = ', '.join(f'{n} = {result.values[n]:.6g} [{result.intervals[n][0]:.6g}, '
                     f'{result.intervals[n][1]:.6g}]' for n in s.names)
    w0, w1 = result.window
    closed = s.controller is not None           # judged over the whole window
    span = f'[{w0:g}, {w1 if closed else result.horizon_end:g}] s'
    if not result.reproduces:
        names = ' and '.join(s.names)
        rng = ' x '.join(f'[{lo:g}, {hi:g}]' for lo, hi in s.bounds)
        one = 'value' if len(s.names) == 1 else 'values'
        vals = ', '.join(f'{n} = {result.values[n]:.6g}' for n in s.names)
        follows = ''
        if (closed and result.horizon_end < w1 - 1e-12
                and result.horizon_residual <= s.threshold):
            follows = (f'; its closed loop follows the run (residual '
                       f'{result.horizon_residual:.3g}) only up to t = {result.horizon_end:g} '
                       's and then departs from it')
        return (f'no {one} of {names} in {rng} reproduces this run: the best, {vals}, leaves '
                f'a residual of {result.residual:.3g} > threshold {s.threshold:g} over {span}'
                f'{follows} ({s.objective} objective)')
    if closed:
        return (f'{vals} reproduces this run: residual {result.residual:.3g} <= threshold '
                f'{s.threshold:g} over {span} ({s.objective} objective)')
    tail = ''
    if result.horizon_end < w1 - 1e-12:
        tail = (f' of the window [{w0:g}, {w1:g}] s (beyond it the fitted model departs from '
                f'the run: an open-loop replay of an unstable vehicle diverges from any error; '
                f'--controller NAME or --objective cycle fit longer runs)')
    return (f'{vals} reproduces this run: residual {result.residual:.3g} <= threshold '
            f'{s.threshold:g} over {span}{tail} ({s.objective} objective)')


# -- outputs ------------------------------------------------------------------------------------
def params_yaml(params: ModelParameters, control_period: float,
                initial_state: Sequence[float], header: str) -> str:
    """A ``--params-file`` for the plant node with the fitted model: every model parameter,
    the control period and the initial state."""
    from ..ros.docs import yaml_value

    lines = [f'# {line}' for line in header.splitlines()]
    lines += ['/**:', '  ros__parameters:']
    for name, value in params.to_dict().items():
        lines.append(f'    {name}: {yaml_value(value)}')
    lines.append(f'    control_period: {yaml_value(float(control_period))}')
    lines.append(f'    initial_state: {yaml_value([float(v) for v in initial_state])}')
    return '\n'.join(lines) + '\n'


def write_outputs(result: FitResult, out: Path, extra: dict[str, Any] | None = None,
                  stem: str = 'fit') -> list[Path]:
    """``fit.json``, ``fit_params.yaml`` and the figures (overlay, alpha profile), PNG and
    SVG; returns the paths."""
    d = result.to_dict()
    d.update(extra or {})
    d['versions'] = _versions()
    paths = [out / f'{stem}.json', out / f'{stem}_params.yaml']
    paths[0].write_text(json.dumps(d, indent=2, default=float) + '\n')
    head = (f"fohssv fit: {result.message}\nplant --ros-args --params-file {paths[1].name}")
    paths[1].write_text(params_yaml(result.params, result.settings['control_period'],
                                    result.settings['initial_state'], head))
    paths += plot_overlay(result, out / f'{stem}_overlay')
    paths += plot_profile(result, out / f'{stem}_profile')
    return paths


def _versions() -> dict[str, str]:
    import scipy

    from .. import __version__
    return {'fohssv': __version__, 'python': sys.version.split()[0], 'numpy': np.__version__,
            'scipy': scipy.__version__}


def _caption(result: FitResult) -> str:
    st = result.settings
    return (f"FOM, solver {st['solver']}, step {st['step']:g} s, control period "
            f"{st['control_period']:g} s, {result.spec.objective} objective;\n"
            f"loop {st['loop']}")


def plot_overlay(result: FitResult, stem: Path, label: str = '') -> list[Path]:
    """The run's states and the fitted model's over the window (the fitted horizon marked)."""
    from .figures import STATE_UNITS, pyplot, save, titled

    plt = pyplot()
    fig, axes = plt.subplots(4, 1, figsize=(8, 8), sharex=True)
    t = result.t
    keep = np.isfinite(result.data_states).all(axis=1)
    w0, w1 = result.window
    sel = keep & (t >= w0 - 1e-12) & (t <= w1 + 1e-12)
    for i, (ax, n) in enumerate(zip(axes, STATE_NAMES)):
        ax.plot(t[sel], result.data_states[sel, i], 'k-', lw=1.2, label='run')
        ok = np.isfinite(result.fitted_states[:, i]) & (t >= w0 - 1e-12) & (t <= w1 + 1e-12)
        ax.plot(t[ok], result.fitted_states[ok, i], 'r--', lw=1.0, label='fitted FOM')
        ax.set_ylabel(f'{n} ({STATE_UNITS[n]})')
        if result.horizon_end < w1 - 1e-12:
            ax.axvline(result.horizon_end, color='0.5', ls=':', lw=1)
    axes[0].legend(fontsize=7, loc='best')
    axes[-1].set_xlabel('t (s)')
    vals = ', '.join(f'{n}={v:.6g}' for n, v in result.values.items())
    axes[0].set_title(titled(f'run vs fitted FOM ({vals}), residual {result.residual:.3g} '
                             f"({'reproduced' if result.reproduces else 'NOT reproduced'}, "
                             f'threshold {result.spec.threshold:g}; fitted up to '
                             f't = {result.horizon_end:g} s)\n{_caption(result)}', label),
                      fontsize=7)
    fig.tight_layout()
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=110)
    plt.close(fig)
    return paths


def plot_profile(result: FitResult, stem: Path, label: str = '') -> list[Path]:
    """The residual over alpha (coarse: others at the estimate; fine: re-optimised), the
    threshold and the profile interval."""
    from .figures import pyplot, save, titled

    plt = pyplot()
    pr = result.profile
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.semilogy(pr['coarse'], np.maximum(pr['coarse_residual'], 1e-16), 'o-', ms=3,
                label='residual, other names at the estimate')
    ax.semilogy(pr['fine'], np.maximum(pr['fine_residual'], 1e-16), 's-', ms=3,
                label='residual near the estimate (others re-optimised)')
    ax.axhline(result.spec.threshold, color='r', ls='--', lw=1,
               label=f'acceptance threshold {result.spec.threshold:g}')
    if pr.get('interval'):
        ax.axvspan(*pr['interval'], color='g', alpha=0.2, label='profile interval (95 %)')
    ax.set_xlabel(pr['name'])
    ax.set_ylabel('residual (RMS)')
    ax.legend(fontsize=7)
    ax.set_title(titled(f"profile over {pr['name']} (horizon up to t = {result.horizon_end:g} "
                        f's)\n{_caption(result)}', label), fontsize=7)
    fig.tight_layout()
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=110)
    plt.close(fig)
    return paths


# -- the paper's question: the FOM against the delayed model -----------------------------------
def reference_data(fom: ModelParameters, controller: str, gains: dict[str, Any],
                   duration: float, control_period: float, delayed_step: float | None = None
                   ) -> FitData:
    """The delayed model's closed loop (same parameters as ``fom`` but model 'delayed', tau =
    L/V unless set) under ``controller`` with a zero-order hold of ``control_period``, from
    x(0) = 0, sampled every control period: the data the FOM's alpha is fitted to.

    Raises:
        FitError: a controller, duration or control period the simulation refuses.
    """
    from ..control import UnknownController, make
    from ..simulate import simulate

    try:
        changes: dict[str, Any] = {'model': 'delayed'}
        if delayed_step is not None:
            changes['step'] = delayed_step
        delayed = fom.replace(**changes)
        ctl = make(controller, gains)
        hold = round(control_period / delayed.step)
        r = simulate(delayed, ctl, duration, control_period=control_period, sample_every=hold)
    except (ParameterError, UnknownController, TypeError, ValueError) as e:
        raise FitError(str(e)) from None
    except FloatingPointError as e:
        raise FitError(f'the delayed reference at V = {fom.speed:g} m/s diverged: {e}') from None
    return data_from_simulation(r.t, r.state, control_period, duration=duration, source={
        'reference': 'delayed', 'speed': fom.speed, 'tau': delayed.delay,
        'delayed_step': delayed.step, 'delayed_solver': delayed.solver,
        'immersion_form': delayed.immersion_form, 'controller': controller})


def write_reference(results: Sequence[tuple[float, FitResult, FitData]], out: Path
                    ) -> list[Path]:
    """Per speed the fit's outputs in ``out/V<speed>/``; the table ``reference.md`` and
    ``reference.json``; the figure alpha*(tau) with the residual floor."""
    from ..docs import markdown_table

    paths: list[Path] = []
    rows = []
    for v, res, data in results:
        sub = out / f'V{v:g}'
        sub.mkdir(parents=True, exist_ok=True)
        paths += write_outputs(res, sub, {'reference': data.source})
        n = res.spec.names[0]
        rows.append({'speed': v, 'tau': data.source['tau'], 'name': n,
                     'value': res.values[n], 'interval': res.intervals[n],
                     'residual': res.residual, 'reproduces': res.reproduces,
                     'horizon_end': res.horizon_end, 'message': res.message})
    spec = results[0][1].spec
    first = results[0][1]
    table = markdown_table(
        ('V (m/s)', 'tau = L/V (s)', f'{rows[0]["name"]}*', '95 % interval', 'residual',
         f'reproduced (<= {spec.threshold:g})'),
        [(f"{r['speed']:g}", f"{r['tau']:.5g}", f"{r['value']:.4f}",
          f"[{r['interval'][0]:.4f}, {r['interval'][1]:.4f}]", f"{r['residual']:.3g}",
          'yes' if r['reproduces'] else 'no') for r in rows])
    head = (f"FOM closed loop vs delayed closed loop, {spec.objective} objective over "
            f"[{first.window[0]:g}, {first.window[1]:g}] s;\n{_caption(first)}")
    (out / 'reference.md').write_text(f'{head}\n\n{table}\n')
    (out / 'reference.json').write_text(json.dumps(
        {'rows': rows, 'spec': spec.to_dict(), 'settings': first.settings,
         'versions': _versions()}, indent=2, default=float) + '\n')
    paths += [out / 'reference.md', out / 'reference.json']
    paths += plot_alpha_tau(rows, spec, out / 'alpha_tau', head)
    return paths


def plot_alpha_tau(rows: list[dict[str, Any]], spec: FitSpec, stem: Path, caption: str,
                   label: str = '') -> list[Path]:
    """alpha*(tau) with the intervals, and the residual floor on a second axis (the figure
    of :func:`alpha_tau_figure`), saved as ``stem``.png and .svg."""
    from .figures import pyplot, save

    fig = alpha_tau_figure(rows, spec, caption, label)
    paths = [stem.parent / f'{stem.name}.png', stem.parent / f'{stem.name}.svg']
    save(fig, paths, dpi=110)
    pyplot().close(fig)
    return paths


def alpha_tau_figure(rows: list[dict[str, Any]], spec: FitSpec, caption: str,
                     label: str = '') -> Any:
    """The figure alpha*(tau): filled markers where the run is reproduced, open ones where
    the best value is not; a legend entry only for a kind of point the figure has."""
    from .figures import pyplot, titled

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    tau = np.array([r['tau'] for r in rows])
    val = np.array([r['value'] for r in rows])
    lo = val - np.array([r['interval'][0] for r in rows])
    hi = np.array([r['interval'][1] for r in rows]) - val
    ok = np.array([bool(r['reproduces']) for r in rows], dtype=bool)
    name = rows[0]['name']
    ax.errorbar(tau, val, yerr=[lo, hi], fmt='none', ecolor='tab:blue', capsize=3)
    if ok.any():
        ax.plot(tau[ok], val[ok], 'o', color='tab:blue', label=f'{name}* (reproduced)')
    if not ok.all():
        ax.plot(tau[~ok], val[~ok], 'o', mfc='none', color='tab:blue',
                label=f'{name}* (best, not reproduced)')
    ax.set_xlabel('τ = L/V (s)')
    ax.set_ylabel(f'{name}*')
    ax2 = ax.twinx()
    ax2.semilogy(tau, [max(r['residual'], 1e-16) for r in rows], 's--', color='tab:red',
                 ms=4, label='residual floor at the best α')
    ax2.axhline(spec.threshold, color='tab:red', ls=':', lw=1,
                label=f'threshold {spec.threshold:g}')
    ax2.set_ylabel('residual (RMS)', color='tab:red')
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=7, loc='best')
    ax.set_title(titled(f'the FOM order that best reproduces the delayed model\n{caption}',
                        label), fontsize=7)
    fig.tight_layout()
    return fig
