"""Gain maps: two gains of a controller swept over a grid, each closed loop classified and
scored, with the linearisation's Matignon boundary (issue 15; docs/gainmap.md).

A map is a grid of gain pairs (``gain_x`` x ``gain_y``, every other controller parameter
fixed) run over one scenario (model, alpha, V), or over an envelope of scenarios (a grid of V
and alpha) for the worst case. Each (pair, scenario) is a point; points are split into chunks
that run as Dask tasks through the sweeps' machinery (:func:`..sweep.run_chunks`: chunk CSV
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

* ``outcome``: the classifier of :mod:`..orbits` on w after ``transient``, grouped as
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

from .evaluate import evaluate_points, run_points, scheduled_gains
from .figures import plot_gain_map
from .result import GainMapResult, load_gain_map, run_gain_map, summary_lines
from .spec import (
    METRICS,
    OUTCOME_RANK,
    OUTCOMES,
    ROW_FIELDS,
    GainMapError,
    GainMapSpec,
    controller_parameters,
    outcome,
)

__all__ = ['GainMapSpec', 'GainMapResult', 'GainMapError', 'OUTCOMES', 'OUTCOME_RANK',
           'outcome', 'controller_parameters', 'run_gain_map', 'summary_lines', 'run_points',
           'load_gain_map', 'plot_gain_map', 'METRICS', 'ROW_FIELDS', 'evaluate_points',
           'scheduled_gains']
