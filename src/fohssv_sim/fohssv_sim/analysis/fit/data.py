"""The data of a fit: the fitted names and their bounds, the run at the control instants
(from a bag or the delayed reference), the errors a fit reports.

Pure: numpy; never imports rclpy or the CLI.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...params import PARAMETER_BY_NAME, PARAMETERS, ModelParameters, ParameterError

OBJECTIVES = ('trajectory', 'cycle')
STATE_NAMES = ('z', 'w', 'theta', 'q')
DEFAULT_THRESHOLD = 0.05
#: Residual of a sample where the simulation failed (or is more than this many scales off).
CLIP = 10.0
#: The most control periods a run to fit may span (its samples are held as an array).
MAX_PERIODS = 10**8
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


#: A default search range spans this factor either side of the parameter's resolved value.
BOUNDS_FACTOR = 2.0
def resolved_value(base: ModelParameters, name: str) -> float:
    """The number ``name`` has in the model ``base`` (a 'consistent' planing offset: R'RV/L
    of its geometry and speed)."""
    v = getattr(base, name)
    if name == 'planing_offset' and v == 'consistent':
        from ...coefficients import coefficients
        return float(coefficients(base).w0)
    return float(v)


def default_bounds(name: str, base: ModelParameters) -> tuple[float, float]:
    """The search range of ``name`` when none is given: the order over its whole range, any
    other parameter a factor :data:`BOUNDS_FACTOR` either side of its resolved value ([-1, 1]
    at 0), clipped to its allowed range; an open end of the allowed range is moved inside (by
    1e-2 of the span for the order, as before, 1e-3 otherwise)."""
    s = PARAMETER_BY_NAME[name]
    if name == 'fractional_order':
        lo, hi = s.low, s.high
    else:
        v = resolved_value(base, name)
        lo, hi = sorted((v / BOUNDS_FACTOR, v * BOUNDS_FACTOR)) if v != 0 else (-1.0, 1.0)
        if s.low is not None:
            lo = max(lo, s.low)
        if s.high is not None:
            hi = min(hi, s.high)
    span = hi - lo
    if s.low is not None and lo == s.low and s.low_open:
        lo += 1e-2 * span if name == 'fractional_order' else 1e-3 * span
    if s.high is not None and hi == s.high and s.high_open:
        hi -= 1e-3 * span
    return float(lo), float(hi)


def resolve_bounds(names: Sequence[str], given: dict[str, tuple[float, float]],
                   base: ModelParameters) -> tuple[tuple[float, float], ...]:
    """The search bounds of each name: ``given`` (checked) or :func:`default_bounds`.

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
            out.append(default_bounds(n, base))
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
        for v in (lo, hi):
            if not model_runs(base, n, v):
                unit = f' {s.unit}' if s.unit and s.unit != '-' else ''
                raise FitError(f'--bounds {n}={lo:g}:{hi:g}: at {n} = {v:g}{unit} the '
                               "model's coefficients overflow or are refused; give a range "
                               "nearer the run's value")
        out.append((float(lo), float(hi)))
    return tuple(out)


def model_runs(base: ModelParameters, name: str, value: float) -> bool:
    """Whether ``base`` with ``name`` = ``value`` is a model with finite coefficients (a
    legal but extreme value, e.g. V = 1e300 m/s, overflows them)."""
    from ...coefficients import coefficients

    try:
        p = base.replace(**{name: float(value)})
        with np.errstate(over='raise', invalid='raise'):
            return bool(np.isfinite(coefficients(p).kernel).all())
    except (ParameterError, ArithmeticError, ValueError):
        return False


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
    from ...bag.loader import locate

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
    from ...params import steps_per_period

    if run.t.size == 0:
        raise FitError(f'{run.path}: no state messages to fit')
    params = run.parameters
    cp = control_period or params.get('control_period')
    if not cp:
        cp = float(np.median(np.diff(run.t))) if run.t.size > 1 else 0.0
    if isinstance(cp, bool) or not isinstance(cp, (int, float)) or not (
            0 < cp < math.inf):
        raise FitError(f'{run.path}: the recorded control_period {cp!r} is not a positive '
                       'number of seconds; give --control-period')
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
    if n > MAX_PERIODS:
        raise FitError(f'{run.path}: a state at t = {run.t.max():g} s is {n} control periods '
                       f'of {cp:g} s from t = 0, more than the {MAX_PERIODS:g} a fit holds '
                       '(give --control-period, or a bag of the run only)')
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
    from ...control import UnknownController, make
    from ...simulate import simulate

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
