"""Model parameters of the FO-HSSV: one table, one immutable dataclass.

The table :data:`PARAMETERS` is the single source of truth for every model parameter and
option: its name, paper symbol, default, unit, allowed range and description. The
:class:`ModelParameters` dataclass, the plant node's ROS parameter declarations and the README
table are all generated from it.

Physics defaults are Table A1 of Doan et al., "Stability Analysis of a Fractional-Order
High-Speed Supercavitating Vehicle Model with Delay", Machines 2021, 9(7), 129, with the
resolutions of docs/model.md §9 (notably L = 1.8 m, not the printed 1.18 m).
Every alternative reading of the paper stays reachable as a named option; the preset
``'paper-literal'`` selects all of them at once.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from .solvers import SOLVERS
from .solvers import SOLVERS_BY_MODEL as _SOLVERS_BY_MODEL

__all__ = [
    'MODELS',
    'SOLVERS_BY_MODEL',
    'PARAMETERS',
    'PRESETS',
    'DEFAULT_STEPS',
    'ParameterError',
    'steps_per_period',
    'ParameterSpec',
    'ModelParameters',
    'spec_field',
    'validate_fields',
    'field_specs',
]

#: The three models of the paper: eq. 17 (delay-free), eqs. 22-25 (delayed), eqs. 26-30 (FOM).
MODELS = ('fractional', 'delay-free', 'delayed')

#: Solvers each model accepts (from the one solver table). 'auto' picks the first one listed.
SOLVERS_BY_MODEL = _SOLVERS_BY_MODEL

#: Default integration steps (s), chosen by the step-halving study in
#: ``bench/bench_convergence.py`` (``make bench``): halving them changes the last 0.5 s of the
#: V = 75 closed loop by less than the tolerance stated there.
DEFAULT_STEPS = {
    'fractional': 2e-5,
    'delay-free': 1e-5,
    'delayed': 1e-5,
}


class ParameterError(ValueError):
    """A model parameter or option is invalid. The message names the parameter, its value,
    the allowed range or choices, and the unit."""


@dataclass(frozen=True)
class ParameterSpec:
    """One row of the parameter table.

    ``low``/``high`` bound numeric values (``None`` = unbounded); ``low_open``/``high_open``
    say whether the bound itself is excluded. ``choices`` lists named values; a parameter
    with both ``choices`` and numeric bounds accepts either a name or a number.
    """

    name: str
    symbol: str
    default: Any
    unit: str
    description: str
    low: float | None = None
    high: float | None = None
    low_open: bool = True
    high_open: bool = True
    choices: tuple[str, ...] = ()
    numeric: bool = True
    reference: str = ''
    #: True when changing it on a running plant requires a reset (the plant refuses it live).
    needs_reset: bool = True

    def range_text(self) -> str:
        """The allowed values as text, e.g. ``(0, 1]`` or ``'smooth' | 'exact'``."""
        parts = []
        if self.choices:
            parts.append(' | '.join(repr(c) for c in self.choices))
        if self.numeric:
            lo = '-inf' if self.low is None else _fmt(self.low)
            hi = 'inf' if self.high is None else _fmt(self.high)
            lb = '(' if (self.low is None or self.low_open) else '['
            hb = ')' if (self.high is None or self.high_open) else ']'
            parts.append(f'{lb}{lo}, {hi}{hb}')
        return ' or '.join(parts)

    def allowed_text(self) -> str:
        """``allowed: <range> <unit> (<description>)``: how a refusal of this row ends."""
        unit = f' {self.unit}' if self.unit and self.unit != '-' else ''
        return f'allowed: {self.range_text()}{unit} ({self.description})'

    def refuse(self, value: Any, what: str) -> ParameterError:
        """The error for ``value`` in the table's words, for a rule a range cannot say:
        ``<name>=<value> <what>; allowed: <range> <unit> (<description>)``."""
        return ParameterError(f'{self.name}={value!r} {what}; {self.allowed_text()}')

    def validate(self, value: Any) -> Any:
        """Return the value normalised (names lower-case, numbers as float).

        Raises:
            ParameterError: the value is of the wrong kind or out of range.
        """
        unit = f' {self.unit}' if self.unit and self.unit != '-' else ''
        if isinstance(value, str):
            v = value.strip().lower()
            if v in self.choices:
                return v
            if not self.numeric:
                raise ParameterError(
                    f'{self.name}={value!r} is not valid; choose one of {self.range_text()}'
                )
            try:
                value = float(v)
            except ValueError:
                raise ParameterError(
                    f'{self.name}={value!r} is not valid; allowed: {self.range_text()}{unit}'
                ) from None
        if not self.numeric or isinstance(value, bool):
            raise ParameterError(
                f'{self.name}={value!r} is not valid; allowed: {self.range_text()}{unit}'
            )
        try:
            x = float(value)
        except (TypeError, ValueError):
            raise ParameterError(
                f'{self.name}={value!r} is not a number; allowed: {self.range_text()}{unit}'
            ) from None
        ok = math.isfinite(x)
        if ok and self.low is not None:
            ok = x > self.low if self.low_open else x >= self.low
        if ok and self.high is not None:
            ok = x < self.high if self.high_open else x <= self.high
        if not ok:
            raise ParameterError(
                f'{self.name}={value!r} is outside the allowed range {self.range_text()}{unit} '
                f'({self.description})'
            )
        return x


def _fmt(x: float) -> str:
    return f'{x:g}'


_P = ParameterSpec

#: The parameter table. Order is the order of the README table and the ROS declarations.
PARAMETERS: tuple[ParameterSpec, ...] = (
    # -- model and solver selection -------------------------------------------------------
    _P('model', '-', 'fractional', '-', 'which model: FOM eqs. 26-30, delay-free eq. 17, '
       'or delayed eqs. 22-25', choices=MODELS, numeric=False),
    _P('solver', '-', 'auto', '-', "integrator: 'rk4' for the integer models; 'soe' (bounded "
       "cost per step, compiled), 'abm' (exact predictor-corrector) or 'abm-fft' (exact, "
       "offline) for the FOM; 'auto' = the first of these for the model",
       choices=('auto', *SOLVERS), numeric=False),
    _P('step', 'h', 'auto', 's', "integration step; 'auto' = the model's converged default "
       f"({', '.join(f'{k}: {v:g}' for k, v in DEFAULT_STEPS.items())})",
       low=0.0, high=0.01, high_open=False, choices=('auto',)),
    _P('fractional_order', 'alpha', 0.85, '-', 'commensurate Caputo order of the FOM',
       low=0.0, high=1.0, high_open=False, reference='eq. 26'),
    # -- Table A1 ---------------------------------------------------------------------------
    _P('speed', 'V', 75.0, 'm/s', 'forward speed', low=0.0, reference='Table A1'),
    _P('length', 'L', 1.8, 'm', 'body length (Table A1 prints 1.18)', low=0.0,
       reference='Table A1, docs/model.md §9.1'),
    _P('body_radius', 'R', 0.0508, 'm', 'body radius', low=0.0, reference='Table A1'),
    _P('cavitator_radius', 'Rn', 0.0191, 'm', 'cavitator radius', low=0.0,
       reference='Table A1'),
    _P('density_ratio', 'm', 2.0, '-', 'vehicle density / water density', low=0.0,
       reference='Table A1'),
    _P('fin_effectiveness', 'n', 0.5, '-', 'fin lift relative to the cavitator', low=0.0,
       low_open=False, reference='Table A1'),
    _P('cavitator_drag_coefficient', 'Cx0', 0.82, '-', 'cavitator drag coefficient at '
       'sigma = 0', low=0.0, reference='Table A1'),
    _P('cavitation_number', 'sigma', 0.03, '-', 'cavitation number (the cavity formulas '
       'need 1.92/sigma > 3)', low=0.0, high=0.64, reference='Table A1, eqs. 12-14'),
    _P('gravity', 'g', 9.81, 'm/s^2', 'gravitational acceleration', low=0.0, low_open=False,
       reference='Table A1'),
    _P('tanh_sharpness', 'k', 300.0, 's/m', 'sharpness of the smooth planing switch',
       low=0.0, reference='eqs. 28-29'),
    # -- the paper's ambiguities (docs/model.md §9) ------------------------------------------
    _P('planing_offset', 'w0', 'consistent', 'm/s', "contact velocity of the smooth planing "
       "form; 'consistent' = R'RV/L (docs/model.md §9.7), the paper prints 2.8",
       low=0.0, choices=('consistent',), reference='eq. 28'),
    _P('advection_delay', 'tau', 'consistent', 's', "advection delay of the delayed model; "
       "'consistent' = L/V (docs/model.md §9.8); 0 gives the delay-free model",
       low=0.0, low_open=False, high=1.0, choices=('consistent',), reference='eq. 22'),
    _P('immersion_form', '-', 'paper', '-', "delayed immersion depth: 'paper' = eq. 25 as "
       "printed, 'geometric' = [z - z_tau + L theta]/R (docs/model.md §9.9)",
       choices=('paper', 'geometric'), numeric=False, reference='eq. 25'),
    _P('planing_form', '-', 'auto', '-', "planing force of the delay-free and fractional "
       "models: 'smooth' tanh form (eqs. 28-29) or 'exact' switching (eqs. 10, 12-14); "
       "'auto' = smooth for the FOM, exact for the delay-free model",
       choices=('auto', 'smooth', 'exact'), numeric=False, reference='eqs. 10-14, 28-29'),
    # -- fast-solver settings -----------------------------------------------------------------
    _P('soe_tolerance', '-', 1e-10, '-', "relative kernel tolerance of the 'soe' solver",
       low=0.0, high=1e-3, high_open=False),
    _P('soe_horizon_steps', '-', 'auto', 'steps', "steps over which the 'soe' kernel meets "
       "its tolerance; 'auto' = the run's length (at least 1e8 steps; 1e12 when the run is "
       "open-ended)", low=1e3, low_open=False, high=1e15, high_open=False, choices=('auto',)),
)

PARAMETER_BY_NAME: dict[str, ParameterSpec] = {p.name: p for p in PARAMETERS}

#: Named presets: the resolutions of docs/model.md §9 (default) and the paper's literal reading.
PRESETS: dict[str, dict[str, Any]] = {
    'resolved': {},
    # Table A1 as printed: L = 1.18, w0 = 2.8, and the text's tau = 0.02069 s.
    'paper-literal': {'length': 1.18, 'planing_offset': 2.8, 'advection_delay': 0.02069},
}


def spec_field(spec: ParameterSpec) -> Any:
    """A dataclass field whose default and validation come from ``spec`` (see
    :func:`validate_fields`). Used by controller parameter dataclasses too."""
    return field(default=spec.default, metadata={'spec': spec})


def validate_fields(obj: Any) -> None:
    """Validate and normalise every field of a frozen dataclass built with :func:`spec_field`.

    Raises:
        ParameterError: naming the field, its value, the allowed range and unit.
    """
    for f in dataclasses.fields(obj):
        spec = f.metadata.get('spec')
        if spec is not None:
            object.__setattr__(obj, f.name, spec.validate(getattr(obj, f.name)))


def field_specs(cls: Any) -> tuple[ParameterSpec, ...]:
    """The :class:`ParameterSpec` of every spec field of a dataclass (class or instance)."""
    return tuple(f.metadata['spec'] for f in dataclasses.fields(cls) if 'spec' in f.metadata)


@dataclass(frozen=True)
class ModelParameters:
    """All parameters and options of one HSSV model instance (immutable, validated).

    Construct with keywords named as in :data:`PARAMETERS`; anything invalid raises
    :class:`ParameterError` naming the parameter, value, allowed range and unit. Named
    options are normalised to lower case; ``'auto'`` values are resolved on construction
    (``solver``, ``step``, ``planing_form``), so a constructed instance always holds
    concrete values. Use :meth:`replace` to derive a changed copy (validated again) and
    :meth:`preset` for the paper's literal reading.

    Raises:
        ParameterError: an invalid value, an unknown option, or an inconsistent combination
            (a solver the model does not support, a cavity that does not enclose the body).
    """

    model: str = spec_field(PARAMETER_BY_NAME['model'])
    solver: str = spec_field(PARAMETER_BY_NAME['solver'])
    step: Any = spec_field(PARAMETER_BY_NAME['step'])
    fractional_order: float = spec_field(PARAMETER_BY_NAME['fractional_order'])
    speed: float = spec_field(PARAMETER_BY_NAME['speed'])
    length: float = spec_field(PARAMETER_BY_NAME['length'])
    body_radius: float = spec_field(PARAMETER_BY_NAME['body_radius'])
    cavitator_radius: float = spec_field(PARAMETER_BY_NAME['cavitator_radius'])
    density_ratio: float = spec_field(PARAMETER_BY_NAME['density_ratio'])
    fin_effectiveness: float = spec_field(PARAMETER_BY_NAME['fin_effectiveness'])
    cavitator_drag_coefficient: float = spec_field(
        PARAMETER_BY_NAME['cavitator_drag_coefficient'])
    cavitation_number: float = spec_field(PARAMETER_BY_NAME['cavitation_number'])
    gravity: float = spec_field(PARAMETER_BY_NAME['gravity'])
    tanh_sharpness: float = spec_field(PARAMETER_BY_NAME['tanh_sharpness'])
    planing_offset: Any = spec_field(PARAMETER_BY_NAME['planing_offset'])
    advection_delay: Any = spec_field(PARAMETER_BY_NAME['advection_delay'])
    immersion_form: str = spec_field(PARAMETER_BY_NAME['immersion_form'])
    planing_form: str = spec_field(PARAMETER_BY_NAME['planing_form'])
    soe_tolerance: float = spec_field(PARAMETER_BY_NAME['soe_tolerance'])
    soe_horizon_steps: float = spec_field(PARAMETER_BY_NAME['soe_horizon_steps'])

    def __post_init__(self) -> None:
        validate_fields(self)
        allowed = SOLVERS_BY_MODEL[self.model]
        if self.solver == 'auto':
            object.__setattr__(self, 'solver', allowed[0])
        elif self.solver not in allowed:
            raise ParameterError(
                f"solver={self.solver!r} does not fit model={self.model!r}; choose one of "
                f"{' | '.join(repr(s) for s in allowed)}"
            )
        if self.step == 'auto':
            object.__setattr__(self, 'step', DEFAULT_STEPS[self.model])
        if self.planing_form == 'auto':
            form = 'smooth' if self.model == 'fractional' else 'exact'
            object.__setattr__(self, 'planing_form', form)
        elif self.model == 'delayed' and self.planing_form != 'exact':
            raise ParameterError(
                f"planing_form={self.planing_form!r} does not fit model='delayed', whose "
                "planing force is the switching form of eqs. 22-25; use 'exact' or 'auto'"
            )
        if self.model == 'delayed':
            tau = self.delay
            if 0.0 < tau < self.step:
                raise ParameterError(
                    f'advection_delay={tau:g} s is shorter than step={self.step:g} s; use 0 '
                    '(the delay-free limit) or a delay of at least one step'
                )
        self._check_cavity()

    def _check_cavity(self) -> None:
        sigma = self.cavitation_number
        k1 = self.length / (self.cavitator_radius * (1.92 / sigma - 3.0)) - 1.0
        if k1 < 0.0:
            raise ParameterError(
                f'length={self.length:g} m is shorter than the cavity-closure scale '
                f'Rn (1.92/sigma - 3) = {self.cavitator_radius * (1.92 / sigma - 3.0):g} m for '
                f'cavitator_radius={self.cavitator_radius:g} m and cavitation_number={sigma:g}; '
                'eq. 12 (K1 >= 0) needs a longer body or a larger sigma'
            )
        arg = 1.0 - (1.0 - 4.5 * sigma / (1.0 + sigma)) * k1 ** (40.0 / 17.0)
        if arg <= 0.0:
            raise ParameterError(
                f'cavitation_number={sigma:g} with length={self.length:g} m puts the transom '
                'beyond the cavity closure (eq. 13, K2 is not real); shorten the body or '
                'raise sigma'
            )
        rc = self.cavitator_radius * math.sqrt(0.82 * (1 + sigma) / sigma) * math.sqrt(arg)
        if rc <= self.body_radius:
            raise ParameterError(
                f'body_radius={self.body_radius:g} m does not fit in the cavity (radius '
                f'{rc:g} m at the transom, eq. 14); the vehicle would be fully wetted'
            )

    # -- derived ------------------------------------------------------------------------------
    @property
    def delay(self) -> float:
        """The advection delay tau in s (L/V unless set)."""
        if self.advection_delay == 'consistent':
            return self.length / self.speed
        return float(self.advection_delay)

    def to_dict(self) -> dict[str, Any]:
        """All parameters as a plain dict (JSON/YAML friendly), resolved values."""
        return {spec.name: getattr(self, spec.name) for spec in PARAMETERS}

    def replace(self, **changes: Any) -> ModelParameters:
        """A copy with ``changes`` applied and validated.

        ``step``, ``solver`` and ``planing_form`` were resolved from ``'auto'`` for the
        current model; when ``model`` changes and they are not given, they are re-resolved.

        Raises:
            ParameterError: an unknown name or an invalid value.
        """
        _check_names(changes)
        if 'model' in changes and changes['model'] != self.model:
            for name in ('solver', 'step', 'planing_form'):
                changes.setdefault(name, 'auto')
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> ModelParameters:
        """Build from a mapping (e.g. a YAML file), rejecting unknown names.

        Raises:
            ParameterError: an unknown name or an invalid value.
        """
        _check_names(values)
        return cls(**dict(values))

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> ModelParameters:
        """A named reading of the paper: ``'resolved'`` (spec, the default) or
        ``'paper-literal'`` (L = 1.18 m, w0 = 2.8 m/s, tau = 0.02069 s as printed).

        Raises:
            ParameterError: an unknown preset name or an invalid override.
        """
        if name not in PRESETS:
            raise ParameterError(
                f"preset={name!r} is unknown; choose one of {' | '.join(map(repr, PRESETS))}"
            )
        values = dict(PRESETS[name])
        values.update(overrides)
        return cls.from_dict(values)


def _check_names(values: Mapping[str, Any]) -> None:
    unknown = sorted(set(values) - set(PARAMETER_BY_NAME))
    if unknown:
        raise ParameterError(
            f"unknown parameter(s) {', '.join(unknown)}; valid names: "
            f"{', '.join(PARAMETER_BY_NAME)}"
        )


def steps_per_period(period: float, step: float, name: str = 'control_period') -> int:
    """The whole number of integration steps in ``period``.

    Raises:
        ValueError: ``period`` is not a positive whole multiple of ``step`` (to 1e-9).
    """
    if not (math.isfinite(period) and period > 0):
        raise ValueError(f'{name}={period!r} s must be a positive number of seconds')
    k = round(period / step)
    if k < 1 or abs(k * step - period) > 1e-9 * period:
        raise ValueError(f'{name}={period:g} s must be a whole multiple of the integration '
                         f'step {step:g} s (nearest: {max(k, 1) * step:g} s)')
    return int(k)
