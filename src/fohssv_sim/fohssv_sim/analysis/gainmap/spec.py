"""What a gain map is: its specification, the outcomes and metrics its rows carry."""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from typing import Any

from ...params import ModelParameters, ParameterError
from ..orbits import STEADY_RTOL

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
    from ...control import UnknownController, load
    from ...params import field_specs

    try:
        cls = load(name)
    except UnknownController as e:
        raise GainMapError(str(e)) from None
    return {s.name: s for s in field_specs(cls.Parameters)}


def _controller(law: type, gains: dict[str, Any]) -> Any:
    """The controller class ``law`` built with ``gains`` (GainMapError when they are bad)."""
    try:
        return law(**gains)
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

    @functools.cached_property
    def law(self) -> type:
        """The controller's class, looked up once per spec (each lookup in the plugin registry
        reads every installed distribution's entry points, about 10 ms; a chunk builds a law
        per point)."""
        from ...control import load

        return load(self.controller)

    def controller_for(self, ix: int, iy: int) -> Any:
        return _controller(self.law, self.gains_for(ix, iy))

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
        _controller(self.law, self.gains_for(0, 0))   # the fixed gains as a whole
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
            from ...simulate import steps_per_period

            try:
                steps_per_period(self.control_period, p.step)
            except ValueError as e:
                raise GainMapError(str(e)) from None
