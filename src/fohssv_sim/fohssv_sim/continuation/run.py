"""``follow_orbits``: a branch of the vehicle's periodic orbits over one model parameter (the
API beside :func:`fohssv_sim.simulate.simulate`; ``fohssv continue`` calls it).

* ``model='fractional'``: harmonic balance (:mod:`.harmonic`) from the Hopf point, which is
  found in the range as the point where the orbit's amplitude goes to zero; stability by one
  simulation per segment between bifurcations (:mod:`.attract`).
* ``model='delay-free'``: shooting (:mod:`.shooting`) from an orbit found by simulating at the
  start of the range; stability from the Floquet multipliers.
* ``model='delayed'``: harmonic balance of the delay-differential equation (the delayed
  states' coefficients rotated by k omega tau, tau = L/V moving with V) from an orbit found by
  simulating at the start of the range; stability from the Floquet multipliers of a
  discretised monodromy operator (:mod:`.monodromy`, 256 RK4 steps per period).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..params import ModelParameters
from .attract import segment_verdicts, simulated_verdict
from .branch import Branch
from .driver import BranchPoint, ContinuationError, Settings, continue_branch
from .harmonic import HarmonicBalance, converge_harmonics, hopf_point, initial_guess
from .shooting import ShootingProblem
from .vehicle import VehicleSystem, W, orbit_measures

__all__ = ['follow_orbits', 'start_orbit', 'MODELS']

#: The models ``follow_orbits`` continues, with their method.
MODELS = {'fractional': 'harmonic balance (AFT), Hopf point by amplitude extrapolation; '
                        'stability by simulation from the orbit, one run per segment',
          'delay-free': 'single shooting, Floquet multipliers from the monodromy matrix',
          'delayed': 'harmonic balance of the delay-differential equation (AFT), from a '
                     'simulated orbit; Floquet multipliers from the monodromy operator '
                     'discretised by RK4 on 256 steps per period'}

Progress = Callable[[str], None]


def _summary(params: ModelParameters, parameter: str, controller: str, harmonics: int) -> str:
    """The figure's second title line: what is held fixed and how the orbits were computed."""
    parts = [f'V = {params.speed:g} m/s'] if parameter != 'speed' else []
    if params.model == 'fractional':
        if parameter != 'fractional_order':
            parts.append(f'α = {params.fractional_order:g}')
        parts.append(f'{harmonics} harmonics')
    else:
        parts.append('DOP853, rtol 1e-9, restarted at contact')
    return ', '.join(parts + [controller])


def follow_orbits(params: ModelParameters, controller: Any, parameter: str, start: float,
                  end: float, *, points: int = 50, harmonics: int = 16,
                  progress: Progress | None = None, checkpoint: Path | None = None,
                  resume: Branch | None = None) -> Branch:
    """The branch of periodic orbits of ``params.model`` under ``controller`` as
    ``parameter`` goes from ``start`` to ``end`` (about ``points`` points; more near folds).

    ``checkpoint``: a ``branch.json`` written after every point; ``resume``: a branch read
    from one (same settings, not complete) to carry on from its last point.

    Raises:
        ParameterError: a parameter that is not numeric, a controller that is not affine.
        ContinuationError: no Hopf point (FOM) or no orbit (delay-free, delayed) at the
            start.
    """
    system = VehicleSystem(params, controller, parameter)
    settings = {'start': start, 'end': end, 'points': points, 'harmonics': harmonics,
                'model_parameters': params.to_dict(),
                'controller': getattr(controller, 'describe', lambda: str(controller))()}
    settings['summary'] = _summary(params, parameter, getattr(controller, 'name', '') or
                                   type(controller).__name__, harmonics)
    branch = Branch(parameter, params.model, MODELS[params.model], settings)
    if resume is not None:
        branch.points, branch.bifurcations = resume.points, resume.bifurcations
        branch.resume = resume.resume
    say = progress or (lambda text: None)
    span = abs(end - start)
    if params.model == 'fractional':
        _fractional(system, branch, start, end, span, points, harmonics, say, checkpoint)
    elif params.model == 'delayed':
        _delayed(system, branch, start, end, span, points, harmonics, say, checkpoint)
    else:
        _delay_free(system, branch, start, end, span, points, say, checkpoint)
    last = branch.points[-1]['value']
    if last not in (start, end):
        say(f'the branch stopped at {parameter} = {last:.6g} before the end of the range (the '
            'step fell below its minimum or the point limit was reached): see the last '
            'points in branch.json')
        branch.settings['stopped_early_at'] = last
    branch.complete = True
    branch.resume = {}
    if checkpoint is not None:
        branch.write(checkpoint)
    return branch


def _recorder(branch: Branch, measure: Callable[[BranchPoint], dict[str, Any]],
              say: Progress, checkpoint: Path | None) -> Callable[[BranchPoint, list], None]:
    """The driver's ``on_point``: measure, record, report, checkpoint."""
    known = len(branch.bifurcations)
    first = [True]

    def on_point(pt: BranchPoint, bifs: list) -> None:
        if first[0] and branch.points:      # a resumed start is the last recorded point
            first[0] = False
        else:
            first[0] = False
            branch.points.append(measure(pt))
        for b in bifs[len(branch.bifurcations) - known:]:
            near = min(branch.points, key=lambda q: abs(q['value'] - b.value))
            branch.bifurcations.append({'kind': b.kind.split(':')[0], 'value': b.value,
                                        'w': near['w_max']})
        # the stretch of branch between bifurcations the point lies on
        branch.points[-1].setdefault('segment', len(branch.bifurcations))
        branch.resume = {'u': pt.u.tolist(), 'p': pt.p, 'tangent': pt.tangent.tolist()}
        q = branch.points[-1]
        stable = {True: 'stable', False: 'unstable', None: 'stability unknown'}[q['stable']]
        say(f"point {len(branch.points)}: {branch.parameter} = {q['value']:.6g}, "
            f"{q['frequency_hz']:.6g} Hz, w amplitude {q['w_amplitude']:.4g} m/s, {stable} "
            f"(range {branch.settings['start']:g} to {branch.settings['end']:g})")
        if checkpoint is not None:
            branch.write(checkpoint)
    return on_point


def _driver_settings(span: float, points: int, scale_p: float) -> Settings:
    ds = span / max(points, 2) / scale_p
    return Settings(ds=0.1 * ds, ds_max=ds, ds_min=1e-6 * ds, max_points=10 * points + 50)


def _resumed(branch: Branch) -> tuple[np.ndarray, float, np.ndarray] | None:
    r = branch.resume
    if not r:
        return None
    return np.asarray(r['u']), float(r['p']), np.asarray(r['tangent'])


def _fractional(system: VehicleSystem, branch: Branch, start: float, end: float, span: float,
                points: int, harmonics: int, say: Progress, checkpoint: Path | None) -> None:
    prob = system.harmonic_balance(harmonics)
    guess_p, eq = _hopf_guess(system, start, end)
    lam, vec = np.linalg.eig(eq.jacobian)
    j = int(np.argmax(lam.imag))
    shape = np.maximum(np.abs(vec[:, j] / vec[1, j]), 1e-3)    # per state, for w = 1 m/s
    alpha = system.order(guess_p)
    amplitude = 1e-3
    u0 = initial_guess(prob, eq.state, eq.jacobian, alpha, amplitude)
    scale_p = span
    scale = prob.scale(shape, float(u0[-1]), scale_p)
    resumed = _resumed(branch)
    if resumed is None:
        say(f'Hopf point near {branch.parameter} = {guess_p:.6g} (equilibrium w = '
            f'{eq.state[1]:.4g} m/s); harmonic balance with H = {harmonics}')
        p_h, u1, p1, u2, p2 = hopf_point(prob, u0, guess_p, amplitude)
        branch.bifurcations.append({'kind': 'hopf', 'value': p_h, 'w': float(eq.state[1])})
        say(f'Hopf point at {branch.parameter} = {p_h:.8g}')
        begin, direction = (u2, p2), np.append(u2 - u1, p2 - p1)
    else:
        begin, direction = (resumed[0], resumed[1]), resumed[2]
        say(f"resuming from point {len(branch.points)} at {branch.parameter} = "
            f"{resumed[1]:.6g}")

    def measure(pt: BranchPoint) -> dict[str, Any]:
        _, c = system.at(pt.p)
        f = prob.frequency_hz(pt.u)
        return {'value': pt.p, 'frequency_hz': f, 'period_s': 1.0 / f, 'stable': None,
                **orbit_measures(prob.signal(pt.u, 1024), c)}

    low, high = min(start, end), max(start, end)
    target = high if direction[-1] >= 0 else low
    pts, bifs = continue_branch(prob, begin, target, scale=scale, direction=direction,
                                limit=low if target == high else high,
                                settings=_driver_settings(span, points, scale_p),
                                on_point=_recorder(branch, measure, say, checkpoint))
    _simulated_stability(system, prob, branch, pts, [b.index for b in bifs], say)
    last = pts[-1]
    fine, _, history = converge_harmonics(prob, last.u, last.p, start=harmonics, rtol=1e-4)
    branch.settings['harmonic_check'] = {
        'value': last.p, 'history': [{'harmonics': h, 'frequency_hz': f} for h, f in history],
        'rule': 'frequency change below 1e-4 relative when the harmonic count doubles'}
    if fine.harmonics > harmonics:
        say(f'warning: at {branch.parameter} = {last.p:.6g} the frequency needs '
            f'{fine.harmonics} harmonics (rerun with --harmonics {fine.harmonics})')
        branch.settings['harmonics_needed'] = fine.harmonics


def _simulated_stability(system: VehicleSystem, prob: HarmonicBalance, branch: Branch,
                         pts: list[BranchPoint], cuts: list[int], say: Progress) -> None:
    """``stable`` of the FOM's points, one simulation per segment between bifurcations
    (:mod:`.attract`), given to every point of that segment (``segment``: the count of
    bifurcations before the point); the runs are listed in the settings
    (``stability_runs``)."""
    offset = len(branch.points) - len(pts)
    runs = segment_verdicts(pts, cuts,
                            lambda pt: simulated_verdict(system, prob, pt.u, pt.p))
    for run in runs:
        segment = branch.points[offset + run['tested']].get('segment')
        for q in branch.points:            # a resumed branch's earlier points too
            if q.get('segment') == segment:
                q['stable'] = run['stable']
        run['value'] = pts[run['tested']].p
        say(f"stability by simulation at {branch.parameter} = {run['value']:.6g}: w amplitude "
            f"{run['simulated_amplitude']:.4g} m/s after 2 s against the orbit's "
            f"{run['orbit_amplitude']:.4g}: {'stable' if run['stable'] else 'unstable'} "
            f"(points {offset + run['first'] + 1} to {offset + run['last'] + 1})")
    branch.settings['stability_runs'] = [
        {k: r[k] for k in ('value', 'stable', 'orbit_amplitude', 'simulated_amplitude')}
        for r in runs]
    branch.settings['stability_method'] = (
        'one simulation per segment between bifurcations, from the orbit kicked 2 %, '
        'stable when w\'s half range after 2 s is within 10 % of the orbit\'s')


def _hopf_guess(system: VehicleSystem, start: float, end: float) -> tuple[float, Any]:
    """Where the equilibrium loses Matignon stability in [start, end] (a guess that harmonic
    balance then corrects) and the equilibrium there."""
    grid = np.linspace(start, end, 9)

    def margin(p: float) -> tuple[float, Any]:
        eq = system.equilibrium(p)
        if eq is None:
            return math.nan, None
        return system.order(p) - eq.critical_order, eq

    values = [margin(p) for p in grid]
    for (a, ea), (b, eb), pa, pb in zip(values, values[1:], grid, grid[1:]):
        if ea is not None and eb is not None and (a < 0.0) != (b < 0.0):
            guess = pa + a / (a - b) * (pb - pa)
            return float(guess), system.equilibrium(guess) or ea
    shown = ', '.join(f'{p:g}: {v:+.3g}' for p, (v, _) in zip(grid[::4], values[::4]))
    raise ContinuationError(f'no Hopf point of the equilibrium between {start:g} and {end:g} '
                            f'(alpha - alpha_c at {shown}): choose a range where the '
                            'equilibrium loses stability')


def start_orbit(system: VehicleSystem, p: float, settle: float = 1.0,
                window: float = 0.5, samples: int = 0) -> Any:
    """u = (x0, T) of the orbit a simulation at ``p`` settles on: x0 at the last maximum of w
    (sampled every 10 steps), T the mean time between upward crossings of w through its
    mean; with ``samples``, instead ``(x, T)``: the last period at that many equally spaced
    times (4, samples) and its length.

    Raises:
        ContinuationError: the simulation settles to an equilibrium (no orbit to start from).
    """
    from ..simulate import simulate

    mp, _ = system.at(p)
    r = simulate(mp, system.law(p)[0], settle + window, sample_every=10)
    keep = r.t >= settle
    t, x = r.t[keep], r.state[keep]
    w = x[:, 1]
    if w.max() - w.min() < 1e-6 * max(1.0, abs(w.mean())):
        raise ContinuationError(f'no periodic orbit at {system.parameter} = {p:g}: the '
                                'simulation settles to an equilibrium; start where the orbit '
                                'diagram of fohssv sweep shows one')
    up = np.where((w[:-1] < w.mean()) & (w[1:] >= w.mean()))[0]
    if up.size < 3:
        raise ContinuationError(f'no periodic orbit at {system.parameter} = {p:g}: w crosses '
                                f'its mean fewer than 3 times in {window:g} s')
    frac = (w.mean() - w[up]) / (w[up + 1] - w[up])
    crossings = t[up] + frac * (t[up + 1] - t[up])
    last = slice(up[-2], up[-1] + 1)               # the last whole period
    x0 = x[last][int(np.argmax(w[last]))]
    if samples:
        T = crossings[-1] - crossings[-2]
        grid = crossings[-2] + T * np.arange(samples) / samples
        return np.array([np.interp(grid, t, x[:, j]) for j in range(4)]), T
    return np.append(x0, float(np.mean(np.diff(crossings))))


def _guess_from_simulation(system: VehicleSystem, prob: HarmonicBalance, p: float
                           ) -> np.ndarray:
    """Harmonic-balance unknowns of the orbit a simulation at ``p`` settles on (its last
    period's Fourier coefficients, phase turned so that w's first sine coefficient is 0)."""
    H, N = prob.harmonics, 8 * prob.harmonics + 8
    x, T = start_orbit(system, p, samples=N)
    spec = np.fft.rfft(x, axis=1)[:, :H + 1] / N
    c = np.zeros((4, 2 * H + 1))
    c[:, 0] = spec[:, 0].real
    c[:, 1::2] = 2.0 * spec[:, 1:].real
    c[:, 2::2] = -2.0 * spec[:, 1:].imag
    phi = np.arctan2(c[W, 2], c[W, 1])
    k = np.arange(1, H + 1)
    a, b = c[:, 1::2].copy(), c[:, 2::2].copy()
    c[:, 1::2] = a * np.cos(k * phi) + b * np.sin(k * phi)
    c[:, 2::2] = b * np.cos(k * phi) - a * np.sin(k * phi)
    return prob.pack(c, 2.0 * np.pi / T)


def _delay_free(system: VehicleSystem, branch: Branch, start: float, end: float, span: float,
                points: int, say: Progress, checkpoint: Path | None) -> None:
    prob = ShootingProblem(system.field(), rtol=1e-9, extremum_of=W)   # x0 at w's top
    resumed = _resumed(branch)
    if resumed is None:
        say(f'starting orbit: simulating at {branch.parameter} = {start:g}')
        u0 = start_orbit(system, start)
        begin, direction = (u0, start), None
    else:
        begin, direction = (resumed[0], resumed[1]), resumed[2]
    orbit = prob.samples(begin[0], begin[1], 200)   # each state by its swing or its level
    size = np.maximum(orbit.max(axis=0) - orbit.min(axis=0), np.abs(orbit.mean(axis=0)))
    scale = np.concatenate([np.maximum(size, 1e-6), [abs(begin[0][-1]), span]])

    def measure(pt: BranchPoint) -> dict[str, Any]:
        _, c = system.at(pt.p)
        mu = prob.multipliers(pt.u, pt.p)
        T = float(pt.u[-1])
        return {'value': pt.p, 'frequency_hz': 1.0 / T, 'period_s': T,
                'stable': bool(np.max(np.abs(mu[1:])) < 1.0),
                'multipliers': [[float(m.real), float(m.imag)] for m in mu],
                **orbit_measures(prob.samples(pt.u, pt.p, 400).T, c)}

    continue_branch(prob, begin, end, scale=scale,
                    direction=direction,
                    limit=start, settings=_driver_settings(span, points, span),
                    on_point=_recorder(branch, measure, say, checkpoint))


def _delayed(system: VehicleSystem, branch: Branch, start: float, end: float, span: float,
             points: int, harmonics: int, say: Progress, checkpoint: Path | None) -> None:
    prob = system.harmonic_balance_delayed(harmonics)
    resumed = _resumed(branch)
    if resumed is None:
        say(f'starting orbit: simulating at {branch.parameter} = {start:g}')
        begin, direction = (_guess_from_simulation(system, prob, start), start), None
    else:
        begin, direction = (resumed[0], resumed[1]), resumed[2]
    x = prob.signal(begin[0], 64)
    size = np.maximum(x.max(axis=1) - x.min(axis=1), np.abs(x.mean(axis=1)))
    scale = prob.scale(np.maximum(size, 1e-6), float(begin[0][-1]), span)

    def measure(pt: BranchPoint) -> dict[str, Any]:
        _, c = system.at(pt.p)
        f = prob.frequency_hz(pt.u)
        stable, mu = prob.stability(pt.u, pt.p)
        return {'value': pt.p, 'frequency_hz': f, 'period_s': 1.0 / f, 'stable': stable,
                'multipliers': [[float(m.real), float(m.imag)] for m in mu[:6]],
                **orbit_measures(prob.signal(pt.u, 1024), c)}

    continue_branch(prob, begin, end, scale=scale, direction=direction, limit=start,
                    settings=_driver_settings(span, points, span),
                    on_point=_recorder(branch, measure, say, checkpoint))
