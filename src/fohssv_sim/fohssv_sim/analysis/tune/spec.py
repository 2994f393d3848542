"""What a tuning search is: its bounds, objectives and specification."""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ...params import ModelParameters, ParameterError
from ..gainmap.evaluate import scheduled_gains
from ..gainmap.spec import controller_parameters
from ..orbits import STEADY_RTOL

#: ``--objective`` names and the row column each takes the worst (largest) of.
OBJECTIVES = {'peak-fp': 'peak_fp', 'settle': 'settle_time', 'effort': 'effort_rms'}
OBJECTIVE_TEXT = {'peak-fp': 'peak |Fp| (m²/s²)', 'settle': 'time to settle (s)',
                  'effort': 'RMS of δc (rad)'}
#: differential_evolution needs at least 5 members in a given initial population.
MIN_POPULATION = 5
def metric_column(spec: TuneSpec) -> str:
    """The row column the objective takes the worst of: ``peak_fp_window`` (after the
    transient) for peak-fp with ``peak_after_transient``, else :data:`OBJECTIVES`'."""
    if spec.objective == 'peak-fp' and spec.peak_after_transient:
        return 'peak_fp_window'
    return OBJECTIVES[spec.objective]


#: The step check flags a scenario whose objective metric moves by more than this (relative)
#: at half the step, as well as one whose outcome changes.
CHECK_RTOL = 0.01

ROW_FIELDS = ('point', 'candidate', 'scenario', 'alpha', 'speed', 'outcome', 'label', 'kind',
              'period', 'k01', 'amplitude', 'failed', 'peak_fp', 'peak_fp_window',
              'settle_time', 'effort_rms', 'alpha_c', 'eq_w', 'eq_dc', 'step', 'path')
_INT = ('point', 'candidate', 'scenario', 'period')
_STR = ('outcome', 'label', 'kind', 'path')

SCORE_TEXT = ('lexicographic worst case over the envelope: (1) worst outcome, then the number '
              'of scenarios not steady; (2) affine laws: shortfall of min(alpha_c - alpha) '
              'below min_margin; (3) the worst objective metric. score = 4 * level1 + '
              '(2 + s/(1+s) if the shortfall s > 0 else m/(1+m)), m the metric')


class TuneError(ValueError):
    """A search that cannot run as specified (the message names the value and what is
    allowed)."""


@dataclass(frozen=True)
class Bound:
    """A tuned parameter: ``name`` searched in [``low``, ``high``] (in log10 when ``log``)."""

    name: str
    low: float
    high: float
    log: bool = False

    def search(self) -> tuple[float, float]:
        """The interval the optimiser searches."""
        return (math.log10(self.low), math.log10(self.high)) if self.log else (
            self.low, self.high)

    def value(self, x: float) -> float:
        """The parameter value of search coordinate ``x``."""
        return float(10.0 ** x) if self.log else float(x)

    def text(self) -> str:
        return f"{self.name}={self.low:g}:{self.high:g}{':log' if self.log else ''}"


@dataclass(frozen=True)
class TuneSpec:
    """Everything that defines a search's numbers (recorded in ``tune.json``).

    ``bounds``: the tuned parameters; ``gains``: the controller's other parameters (defaults
    otherwise); ``base``: model parameters shared by every scenario, without fractional_order
    and speed; the scenarios are ``envelope_speeds`` x ``envelope_alphas``. ``budget``:
    candidate evaluations at most (``population`` per generation; 0 = automatic, see
    :attr:`population_size`). Run settings as :class:`..gainmap.GainMapSpec`.
    """

    controller: str
    bounds: tuple[Bound, ...]
    envelope_speeds: tuple[float, ...]
    envelope_alphas: tuple[float, ...]
    gains: dict[str, Any] = field(default_factory=dict)
    base: dict[str, Any] = field(default_factory=dict)
    objective: str = 'peak-fp'
    budget: int = 60
    population: int = 0
    seed: int = 1
    min_margin: float = 0.02
    duration: float = 2.0
    transient: float = 1.5
    #: the peak-fp objective over the window after ``transient`` only (default: the whole
    #: run, start-up transient included)
    peak_after_transient: bool = False
    control_period: float | None = 1e-4
    sample_every: int = 0
    settle_band: float = 0.02
    chunk_size: int = 128
    check_step: bool = False
    steady_rtol: float = STEADY_RTOL
    rel_tol: float = 1e-3
    mutation: tuple[float, float] = (0.5, 1.0)
    recombination: float = 0.7

    # -- the search --------------------------------------------------------------------
    @property
    def population_size(self) -> int:
        """``population``, or 5 per tuned parameter, at most a quarter of the budget (so
        at least four generations run), at least :data:`MIN_POPULATION`."""
        if self.population:
            return self.population
        return max(MIN_POPULATION, min(5 * len(self.bounds), self.budget // 4))

    @property
    def generations(self) -> int:
        """Generations the budget allows (the first is the initial population)."""
        return self.budget // self.population_size

    def scenarios(self) -> list[tuple[float, float]]:
        """(alpha, V) of each scenario, V outer."""
        return [(a, v) for v in self.envelope_speeds for a in self.envelope_alphas]

    def params_for(self, alpha: float, speed: float, step_factor: float = 1.0
                   ) -> ModelParameters:
        p = ModelParameters.from_dict({**self.base, 'fractional_order': alpha,
                                       'speed': speed})
        return p if step_factor == 1.0 else p.replace(step=p.step * step_factor)

    def every(self, step: float) -> int:
        if self.sample_every:
            return self.sample_every
        if self.control_period is None:
            return 5
        return max(1, round(self.control_period / step))

    def values(self, x: Sequence[float]) -> dict[str, float]:
        """The tuned parameters' values at search point ``x``."""
        return {b.name: b.value(xi) for b, xi in zip(self.bounds, x)}

    def gains_for(self, values: dict[str, float], params: ModelParameters) -> dict[str, Any]:
        """All overrides of one candidate in one scenario (scheduling parameters set)."""
        return scheduled_gains(self.law, {**self.gains, **values}, params)

    @functools.cached_property
    def law(self) -> type:
        """The controller's class, looked up once per spec (each lookup in the plugin registry
        reads every installed distribution's entry points, about 10 ms; a generation builds a
        law per candidate and scenario)."""
        from ...control import load

        return load(self.controller)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d['bounds'] = [dataclasses.asdict(b) for b in self.bounds]
        for k in ('envelope_speeds', 'envelope_alphas', 'mutation'):
            d[k] = list(d[k])
        return d

    def identity(self) -> dict[str, Any]:
        """What defines the search's sequence of generations: everything but the budget
        (with the population made explicit), so a rerun with a larger budget continues the
        same search from its recorded generations, and but ``check_step`` (it only re-runs
        the winner after the search), so a rerun with ``--check-step`` checks the winner of
        the search already run instead of being refused or starting another."""
        d = self.to_dict()
        d.pop('budget')
        d.pop('check_step')
        if not self.peak_after_transient:      # the searches run before the option
            d.pop('peak_after_transient')
        d['population'] = self.population_size
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TuneSpec:
        d = dict(d)
        d['bounds'] = tuple(Bound(**b) for b in d['bounds'])
        for k in ('envelope_speeds', 'envelope_alphas', 'mutation'):
            d[k] = tuple(d[k])
        return cls(**d)

    # -- validation --------------------------------------------------------------------
    def validate(self) -> None:
        """Check names, bounds, the envelope and the budget before anything runs.

        Raises:
            TuneError: unknown controller or parameter (lists the controller's parameters),
                a bound outside the parameter's range (name, value, range, unit), an empty
                envelope, a budget below one population, bad run settings.
        """
        from ..gainmap.spec import GainMapError

        try:
            specs = controller_parameters(self.controller)
        except GainMapError as e:
            raise TuneError(str(e)) from None
        self._validate_bounds(specs)
        self._validate_envelope()
        self._validate_search()
        self._validate_run()

    def _validate_bounds(self, specs: dict[str, Any]) -> None:
        names = ', '.join(sorted(specs))
        follow = getattr(self.law, 'scheduling', {})
        if not self.bounds:
            raise TuneError('nothing to tune: give --tune NAME=LOW:HIGH')
        seen: set[str] = set()
        for b in self.bounds:
            if b.name not in specs:
                raise TuneError(f'{self.controller} has no parameter {b.name!r}; its '
                                f'parameters: {names}')
            s = specs[b.name]
            if not s.numeric:
                raise TuneError(f'{self.controller} parameter {b.name!r} is not numeric')
            if b.name in follow:
                raise TuneError(f'{self.controller} parameter {b.name!r} follows the model '
                                f'parameter {follow[b.name]!r} in each scenario; it cannot '
                                'be tuned')
            if b.name in seen:
                raise TuneError(f'{b.name} is given twice in --tune')
            if b.name in self.gains:
                raise TuneError(f'{b.name!r} is tuned; do not also fix it with --gain')
            seen.add(b.name)
            if not (math.isfinite(b.low) and math.isfinite(b.high) and b.low < b.high):
                raise TuneError(f'{b.text()}: need finite bounds LOW < HIGH')
            if b.log and not b.low > 0:
                raise TuneError(f'{b.text()}: a log-scaled bound needs LOW > 0')
            for v in (b.low, b.high):
                try:
                    s.validate(v)
                except ParameterError:
                    unit = '' if s.unit in ('', '-') else f' {s.unit}'
                    raise TuneError(
                        f'{self.controller} parameter {b.name}={v:g} is outside its allowed '
                        f'range {s.range_text()}{unit}') from None
        for name in self.gains:
            if name not in specs:
                raise TuneError(f'{self.controller} has no parameter {name!r}; its '
                                f'parameters: {names}')

    def _validate_envelope(self) -> None:
        if not self.envelope_speeds or not self.envelope_alphas:
            raise TuneError('the envelope is empty: give at least one value to each of '
                            '--envelope-speeds (m/s) and --envelope-alphas')
        for a in self.envelope_alphas:
            if not 0 < a <= 1:
                raise TuneError(f'envelope alpha={a:g} is outside (0, 1]')
        for v in self.envelope_speeds:
            if not v > 0:
                raise TuneError(f'envelope speed V={v:g} m/s must be > 0')
        try:
            for a, v in self.scenarios():
                self.params_for(a, v)
        except ParameterError as e:
            raise TuneError(str(e)) from None

    def _validate_search(self) -> None:
        if self.objective not in OBJECTIVES:
            raise TuneError(f'objective {self.objective!r} is not one of '
                            f"{', '.join(OBJECTIVES)}")
        if self.budget < 1:
            raise TuneError(f'budget={self.budget} must be >= 1 (candidate evaluations)')
        if self.population and self.population < MIN_POPULATION:
            raise TuneError(f'population={self.population} must be >= {MIN_POPULATION}')
        if self.budget < self.population_size:
            raise TuneError(f'budget={self.budget} is below one generation of '
                            f'{self.population_size} candidates (the population)')
        if not (math.isfinite(self.min_margin) and self.min_margin >= 0):
            raise TuneError(f'min_margin={self.min_margin:g} must be >= 0')
        if self.chunk_size < 1:
            raise TuneError(f'chunk_size={self.chunk_size} must be >= 1')

    def _validate_run(self) -> None:
        if not (self.duration > 0 and 0 <= self.transient < self.duration):
            raise TuneError(f'need duration > transient >= 0 (got duration '
                            f'{self.duration:g} s, transient {self.transient:g} s)')
        if not self.settle_band > 0:
            raise TuneError(f'settle_band={self.settle_band:g} must be > 0')
        p = self.params_for(*self.scenarios()[0])
        mid = {b.name: b.value(sum(b.search()) / 2) for b in self.bounds}
        try:
            ctl = _controller(self, mid, p)
        except TuneError as e:
            raise TuneError(f'the fixed parameters do not build the controller: {e}') from None
        if self.control_period is None:
            if not getattr(ctl, 'stateless', True):
                raise TuneError(f'{self.controller} keeps internal state: give a control '
                                'period')
        else:
            from ...simulate import steps_per_period

            try:
                steps_per_period(self.control_period, p.step)
            except ValueError as e:
                raise TuneError(str(e)) from None


def _controller(spec: TuneSpec, values: dict[str, float], params: ModelParameters) -> Any:
    try:
        return spec.law(**spec.gains_for(values, params))
    except (ParameterError, TypeError, ValueError) as e:
        raise TuneError(str(e)) from None
