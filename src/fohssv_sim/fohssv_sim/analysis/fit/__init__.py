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

The *residual* is the RMS of r (dimensionless: standard deviations, or relative errors). The
run is *reproduced* (trajectory) when the residual in units of the measurement noise passes the
test of :mod:`.noise` (the noise estimated from the data or given per state; an F test at
99 %), or (cycle) when the residual is at most ``threshold`` (default 0.05): over the whole
window for a closed loop (``controller``), over the last reproduced horizon for an open-loop
replay (see below: a replay departs from the run from any error, a fitted closed loop only by
misfit). States of weight 0 are not measured: never compared, never read.

**Open-loop replays diverge.** The vehicle is open-loop unstable (eigenvalue +15.5 1/s at
V = 75, far faster through planing contacts): replaying recorded commands through a model
whose parameters differ by 1e-6 departs from the data within tens of milliseconds. So an
open-loop replay is fitted over the whole window through an extended Kalman filter of the
model (``horizon='auto'`` or ``'filter'``, :mod:`.observer`: the residual is the filter's
prediction errors, each sample against the model's one-period prediction, white noise when
the model is right; the model's fractional memory is that of the filtered trajectory from
t = 0). ``horizon='grow'`` (the default of a
closed loop) instead grows the horizon: stage 0 fits the first 1/2^S of the window (halved
while even that is not reproduced, down to 20 samples), each later stage doubles it,
warm-started from the previous stage, and bisects back towards the last reproduced horizon
where a stage is not reproduced (a horizon not reproduced is not tried again from the same
warm start, to 1e-3 of the bounds: bisected towards instead); it reports the last reproduced
horizon with its fit (``horizon_end``). ``horizon='full'`` fits the whole window with one
trajectory. A closed loop is judged over the whole window (``window_residual``).

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
cov = s^2 (J^T J)^-1 n / n_eff, s^2 = sum r^2 / (N - p), n_eff / n = (1 - rho) / (1 + rho) for
residuals of lag-1 autocorrelation rho (:func:`.noise.effective_fraction`); and a profile of
the objective over alpha (or the first name): a global one over the whole bounds with the other
names at the estimate, refined around its lowest local minima (their number is reported), and a
fine one around the estimate with the other names re-optimised. The interval of alpha is the
hull of every profile point with SSR(alpha) <= SSR_min + (SSR_min / n_eff) chi2_1(0.95) (the
noise-equivalent of the best) and the Jacobian interval; of the others, the Jacobian interval.
A name is *identifiable* when the residual depends on it and its interval is narrower than
half its bounds. With a model that cannot reproduce the run the intervals are not confidence
intervals and the result says so (``reproduces`` false).

The package: :mod:`.data` (names, default bounds, the run), :mod:`.noise` (the noise and the
test), :mod:`.problem` (the objective), :mod:`.observer` (the Kalman filter of an open-loop
replay), :mod:`.search` (populations, the local stage), :mod:`.run` (:func:`run_fit`),
:mod:`.result` (what it found, the verdict), :mod:`.report` (files and figures).

Pure: numpy, scipy, dask, matplotlib (Agg); never imports rclpy or the CLI.
"""

from .data import (
    DEFAULT_THRESHOLD,
    OBJECTIVES,
    STATE_NAMES,
    FitData,
    FitError,
    bag_sha256,
    base_from_run,
    check_names,
    data_from_run,
    data_from_simulation,
    fittable_names,
    reference_data,
    resolve_bounds,
)
from .problem import FitSpec, Problem, cycle_features, cycle_residual
from .report import (
    alpha_tau_figure,
    params_yaml,
    plot_alpha_tau,
    write_outputs,
    write_reference,
)
from .result import FitResult, summary_line
from .run import run_fit

__all__ = ['FitError', 'FitSpec', 'FitData', 'FitResult', 'OBJECTIVES', 'fittable_names',
           'check_names', 'resolve_bounds', 'data_from_run', 'data_from_simulation',
           'base_from_run', 'run_fit', 'write_outputs', 'params_yaml', 'bag_sha256',
           'DEFAULT_THRESHOLD', 'STATE_NAMES', 'summary_line', 'reference_data',
           'write_reference', 'Problem', 'cycle_features', 'cycle_residual',
           'alpha_tau_figure', 'plot_alpha_tau']
