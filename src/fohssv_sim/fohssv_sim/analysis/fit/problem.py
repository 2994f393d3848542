"""The objective of one fit: :class:`FitSpec` (what defines its numbers) and
:class:`Problem` (the model driven open or closed loop, its residual rows against the data).

Pure: numpy; never imports rclpy or the CLI.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...params import ModelParameters, ParameterError
from ..orbits import classify
from ..population import run_population, run_population_reference
from . import observer
from .data import CLIP, DEFAULT_THRESHOLD, OBJECTIVES, STATE_NAMES, FitData, FitError
from .noise import DEFAULT_NOISE_FLOOR
from .noise import estimate as estimate_noise
from .noise import judge as judge_noise

#: How the model covers the window (FitSpec.horizon).
HORIZONS = ('auto', 'filter', 'grow', 'full')


# -- the problem ---------------------------------------------------------------------------
@dataclass(frozen=True)
class FitSpec:
    """Everything that defines a fit's numbers (recorded in fit.json).

    ``base``: the FOM's parameters (table names) apart from ``names``; ``window`` in s (None =
    the whole run); ``controller`` None = open loop on the recorded commands; ``weights`` per
    state (z, w, theta, q; a weight of 0: the state is not measured, never compared and may be
    missing from the data); ``noise`` per state in its unit (None: estimated from the data,
    :mod:`.noise`), never below ``noise_floor`` x the state's standard deviation;
    ``horizon``: 'filter' (the prediction errors of the model's Kalman filter over the whole
    window: :mod:`.observer`), 'grow' (a growing horizon, ``stages`` doublings), 'full' (one
    trajectory over the whole window) or 'auto' (filter for an open-loop replay, grow for a
    closed loop). ``threshold``: the cycle objective's
    acceptance (the trajectory objective is judged against the noise).
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
    noise: tuple[float | None, float | None, float | None, float | None] = (None,) * 4
    noise_floor: float = DEFAULT_NOISE_FLOOR
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
        d['noise'] = list(self.noise)
        return d

    def validate(self) -> None:
        """Raises FitError for an unknown objective, horizon, or a bad count."""
        if self.objective not in OBJECTIVES:
            raise FitError(f"--objective {self.objective!r}: choose one of "
                           f"{' | '.join(OBJECTIVES)}")
        if self.horizon not in HORIZONS:
            raise FitError(f"--horizon {self.horizon!r}: choose one of {' | '.join(HORIZONS)}")
        if not (self.threshold > 0 and math.isfinite(self.threshold)):
            raise FitError(f'--threshold {self.threshold:g} must be a positive number')
        for name, v, low in (('--population', self.population, 2), ('--starts', self.starts, 1),
                             ('--profile-points', self.profile_points, 3),
                             ('--chunk-size', self.chunk_size, 1)):
            if v < low:
                raise FitError(f'{name} {v} must be >= {low}')
        if any(not (w >= 0 and math.isfinite(w)) for w in self.weights) or not any(self.weights):
            raise FitError(f'--weights {list(self.weights)}: need non-negative weights, one > 0')
        for n, v in zip(STATE_NAMES, self.noise):
            if v is not None and not (v > 0 and math.isfinite(v)):
                raise FitError(f'--noise {n}={v!r}: need a finite number > 0 in the unit of {n}')
        if not (0 < self.noise_floor < 1):
            raise FitError(f'--noise-floor {self.noise_floor!r}: need a number in (0, 1) '
                           "(a fraction of each state's standard deviation)")

    @property
    def measured(self) -> np.ndarray:
        """Which states are compared (weight > 0)."""
        return np.asarray(self.weights, dtype=float) > 0


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
        m = spec.measured
        if spec.objective == 'cycle':
            m = np.array([False, True, False, False])    # w's features
        have_row = np.isfinite(data.states[:, m]).all(axis=1)
        ok = have_row & (t >= t0 - eps) & (t <= t1 + eps)
        ok[0] = False            # t = 0 is the initial state the model starts from, not data
        self.index = np.flatnonzero(ok)
        if self.index.size < (2 if spec.objective == 'trajectory' else 8):
            have = t[have_row]
            span = f'[{have[0]:g}, {have[-1]:g}] s' if have.size else 'nothing'
            raise FitError(f'--window {t0:g}:{t1:g} s holds {self.index.size} state sample(s) '
                           f'(the run spans {span}); the {spec.objective} objective needs more')
        # the unmeasured states compare as 0 - 0 (weight 0), never as NaN
        self.states = np.where(m, data.states, 0.0)
        x = self.states[self.index]
        with np.errstate(over='ignore', invalid='ignore'):
            scale = x.std(axis=0)
        scale = np.where(scale > 0, scale, np.maximum(np.abs(x).max(axis=0), 1.0))
        if not np.isfinite(scale).all():
            j = int(np.argmin(np.isfinite(scale)))
            raise FitError(f'state {STATE_NAMES[j]}: its samples in the window (up to '
                           f'{np.abs(x[:, j]).max():g}) overflow any residual; not a run of '
                           'the model')
        self.scale = scale
        w = np.asarray(spec.weights, dtype=float)
        self.w = w / np.sqrt(np.mean(w[w > 0] ** 2)) if w.any() else w
        # the noise from the samples in time order (a gap: no difference across it)
        span = self.states[self.index[0]:self.index[-1] + 1]
        self.noise = (estimate_noise(span, scale, spec.noise, spec.noise_floor, m)
                      if spec.objective == 'trajectory' else None)
        self.law = None
        self.plugin = None
        if spec.controller is not None:
            # None: a plugin that is not affine, run point by point (see simulate)
            self.law = _packed_law(spec.controller, spec.gains)
            if self.law is None:
                from ...control import load

                # its class, looked up once: a fresh law per point is then only its
                # construction (the entry-point scan cost more than the point's run)
                self.plugin = load(spec.controller)
        elif data.inputs is None:
            raise FitError(f"{data.source.get('bag', 'the run')}: no command messages, so the "
                           'recorded commands cannot drive the model; give --controller NAME '
                           'to close the loop with a plugin')
        if spec.objective == 'cycle':
            self.features = cycle_features(t[self.index], x[:, 1])
        #: what an open-loop replay's filter is given (NaN: not measured)
        self.follow = np.where(m, self.states, np.nan)

    @property
    def mode(self) -> str:
        """How the model covers the window: 'filter', 'grow' or 'full' (FitSpec.horizon,
        'auto' resolved: filter for an open-loop replay, grow for a closed loop; the cycle
        objective always 'full')."""
        h = self.spec.horizon
        if self.spec.objective == 'cycle':
            return 'full'
        if h == 'auto':
            return 'filter' if self.spec.controller is None else 'grow'
        if h == 'filter' and self.spec.controller is not None:
            raise FitError(f'--horizon {h}: for an open-loop replay; a closed loop '
                           '(--controller) is judged over the whole window as is')
        return h

    # -- evaluation ------------------------------------------------------------------------
    def params_for(self, values: Sequence[float]) -> ModelParameters | None:
        """The model at ``values``, or None where the parameter table refuses them or the
        model's coefficients overflow (legal but extreme values, e.g. V = 1e300 m/s)."""
        from ...coefficients import coefficients

        try:
            p = self.base.replace(**{n: float(v) for n, v in zip(self.spec.names, values)})
            with np.errstate(over='raise', invalid='raise'):
                ok = np.isfinite(coefficients(p).kernel).all()
        except (ParameterError, ArithmeticError, ValueError):
            return None
        return p if ok else None

    def first_horizon(self) -> int:
        """Samples of the first stage: the whole window ('full', or the cycle objective),
        else 1/2^stages of it (at least 20 samples)."""
        m = self.index.size
        if self.mode != 'grow':
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
        if self.mode == 'filter':
            kf = observer.settings(ok, d.control_period, self.scale, self.noise.sigma,
                                   self.spec.measured)
            return observer.run_filter(ok, n, self.hold, d.inputs, self.follow, kf,
                                       initial_state=d.initial_state, duration=d.duration,
                                       threads=threads), valid
        if self.plugin is not None:
            # no compiled form (a law with memory, e.g. fractional_pid): each point through
            # the plant contract with a fresh controller, its command held per period
            spec, plugin = self.spec, self.plugin
            try:
                return run_population_reference(
                    ok, n, self.hold, controller=lambda: plugin(**spec.gains),
                    initial_state=d.initial_state, duration=d.duration), valid
            except Exception as e:      # a plugin's own defect: named, not ours
                raise FitError(f'--controller {spec.controller}: the plugin raised '
                               f'{type(e).__name__} during the run: {e}') from None
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
            if isinstance(res, observer.Filtered):   # the innovations, in the samples' units
                r = res.white[:, sel] * (self.w * self.noise.sigma / self.scale)
            else:
                r = (res.states[:, sel] - self.states[sel][None]) * (self.w / self.scale)
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

    def noise_ratio(self, r: np.ndarray) -> float:
        """T = mean(e^2 / sigma^2) of a trajectory residual row over the measured states
        (:mod:`.noise`): about 1 when the model is right and only the noise is left."""
        m = self.w > 0
        e = r.reshape(-1, 4)[:, m] * (self.scale[m] / (self.w[m] * self.noise.sigma[m]))
        return float(np.mean(e ** 2))

    def judge(self, r: np.ndarray) -> dict[str, Any]:
        """Is the residual row ``r`` the run's? The trajectory objective: the noise test
        (:func:`.noise.judge`, nu = entries - fitted names); the cycle objective: its RMS
        against ``threshold``."""
        res = self.norm(r)
        if self.noise is None:
            return {'residual': res, 'reproduced': bool(res <= self.spec.threshold)}
        T = self.noise_ratio(r)
        nu = r.size // 4 * int((self.w > 0).sum()) - len(self.spec.names)   # compared, free
        ok, crit = judge_noise(T, nu, self.noise)
        m = self.w > 0
        per = (self.w[m] * self.noise.sigma[m] / self.scale[m]) ** 2     # noise in r's units
        return {'residual': res, 'reproduced': ok, 'noise_ratio': math.sqrt(T),
                'noise_bound': math.sqrt(crit), 'nu': nu,
                'bound_residual': math.sqrt(crit * float(np.mean(per)))}

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
    from ...control import UnknownController, make
    from ...models import AffineLaw

    try:
        ctl = make(name, gains)
    except UnknownController as e:
        raise FitError(f'--controller {name}: {e}') from None
    except (ParameterError, TypeError, ValueError) as e:
        raise FitError(f'--gain: {e}') from None
    except Exception as e:          # a plugin's own defect: named, not ours
        raise FitError(f'--controller {name}: the plugin raised {type(e).__name__}: {e}'
                       ) from None
    try:
        law = AffineLaw.from_controller(ctl)
    except Exception as e:
        raise FitError(f'--controller {name}: the plugin raised {type(e).__name__} when '
                       f'asked for its commands: {e}') from None
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
