"""What a fit found (:class:`FitResult`, fit.json) and its verdict in one sentence
(:func:`summary_line`).

Pure: numpy; never imports rclpy or the CLI.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...params import ModelParameters
from .data import STATE_NAMES
from .problem import FitSpec


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
    #: per name: whether the data fix it (its interval narrower than half its bounds, and
    #: the residual depends on it)
    identifiable: dict[str, bool] = field(default_factory=dict)

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
                'cycle': self.cycle, 'identifiable': self.identifiable,
                'spec': self.spec.to_dict()}


def judged(verdict: dict[str, Any], noise: dict[str, Any] | None, threshold: float) -> str:
    """How a residual was judged: against the noise (the trajectory objective: T's root, its
    99 % bound and the noise per measured state) or against ``threshold`` (cycle)."""
    res = verdict['residual']
    if 'noise_ratio' not in verdict:
        rel = '<=' if verdict['reproduced'] else '>'
        return f'residual {res:.3g} {rel} threshold {threshold:g}'
    rel = '<=' if verdict['reproduced'] else '>'
    sig = ', '.join(f'{n} {v:.3g}{" (floor)" if floor else ""}'
                    for n, v, floor, w in zip(STATE_NAMES, noise['sigma'], noise['at_floor'],
                                              noise['measured']) if w)
    where = (': at the noise floor' if verdict['reproduced'] else
             ': more than the noise explains')
    at = f" at half the step, h = {verdict['step']:g} s," if 'step' in verdict else ''
    return (f"residual{at} {res:.3g} std = {verdict['noise_ratio']:.3g} x the noise {rel} its "
            f"99 % bound {verdict['noise_bound']:.3g}{where} (noise {sig})")


def summary_line(result: FitResult) -> str:
    """One sentence: the estimate with its interval and how its residual was judged, or that
    nothing fits; the parameters the data cannot fix named."""
    s = result.spec
    st = result.settings
    vals = ', '.join(f'{n} = {result.values[n]:.6g} [{result.intervals[n][0]:.6g}, '
                     f'{result.intervals[n][1]:.6g}]' for n in s.names)
    w0, w1 = result.window
    closed = s.controller is not None           # judged over the whole window
    span = f'[{w0:g}, {w1 if closed else result.horizon_end:g}] s'
    how = judged(st['verdict'], st['noise'], s.threshold)
    blind = [n for n, ok in result.identifiable.items() if not ok]
    why = st.get('blind_reason') or ('the interval spans the bounds or the residual does not '
                                      'depend on it')
    blind_text = (f"; {' and '.join(blind)} not identifiable from these data ({why})"
                  if blind else '')
    if not result.reproduces:
        names = ' and '.join(s.names)
        rng = ' x '.join(f'[{lo:g}, {hi:g}]' for lo, hi in s.bounds)
        one = 'value' if len(s.names) == 1 else 'values'
        vals = ', '.join(f'{n} = {result.values[n]:.6g}' for n in s.names)
        follows = ''
        hv = st.get('horizon_verdict', {})
        if closed and result.horizon_end < w1 - 1e-12 and hv.get('reproduced'):
            follows = (f'; its closed loop follows the run (residual '
                       f'{result.horizon_residual:.3g}) only up to t = {result.horizon_end:g} '
                       's and then departs from it')
        return (f'no {one} of {names} in {rng} reproduces this run: the best, {vals}, leaves '
                f'a {how} over {span}{follows} ({s.objective} objective){blind_text}')
    tail = ''
    if not closed and result.horizon_end < w1 - 1e-12:
        tail = (f' of the window [{w0:g}, {w1:g}] s (beyond it the fitted model departs from '
                f'the run: an open-loop replay of an unstable vehicle diverges from any error; '
                f'--controller NAME or --objective cycle fit longer runs)')
    return (f'{vals} reproduces this run: {how} over {span}{tail} ({s.objective} objective)'
            f'{blind_text}')


def acceptance(result: FitResult) -> tuple[float, str]:
    """The residual (RMS, the objective's units) up to which the run counts as reproduced,
    and its name: the noise's 99 % bound (trajectory) or the threshold (cycle)."""
    v = result.settings['verdict']
    if 'bound_residual' in v:
        return v['bound_residual'], "the noise's 99 % bound"
    return result.spec.threshold, f'threshold {result.spec.threshold:g}'
