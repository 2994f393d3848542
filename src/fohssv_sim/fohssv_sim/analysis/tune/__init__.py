"""Robust controller synthesis over a V-alpha envelope: ``fohssv tune`` (issue 24;
docs/tune.md).

A global search over numeric parameters of a controller plugin (each between bounds, linear
or log-scaled) for the best **worst case over an envelope** of scenarios (the grid of V and
alpha). The optimiser is :func:`scipy.optimize.differential_evolution` (already a pinned
dependency; why it and not CMA-ES: docs/tune.md), run with ``vectorized=True,
updating='deferred'``: it asks for a whole generation at once, and each generation runs as one
chunked Dask job of batched solver calls (the gain map's evaluation,
:func:`..gainmap.evaluate_points`, through the sweeps' chunk machinery,
:func:`..sweep.run_chunks`: chunk files, resume, progress per point).

A candidate's **score** is lexicographic over its scenarios (:func:`score`):

1. every scenario steady first: the worst outcome (steady < drifting < periodic < chaotic <
   diverged), then the number of scenarios that are not steady;
2. then, for affine laws (the linearised closed loop is the 4-state commensurate system of
   eq. 30), the Matignon margin ``min(alpha_c(V) - alpha)`` over the envelope, as its
   shortfall below ``min_margin`` (a margin at or above it ties);
3. then the objective: the worst ``peak_fp``, ``settle_time`` or ``effort_rms`` over the
   envelope (``peak-fp`` / ``settle`` / ``effort``).

The optimiser needs one number: :func:`score` maps the three levels to a scalar that orders
exactly as the tuple does (integer level x 4 plus a fraction in [0, 3)).

**Resume**: the search is deterministic for a seed (a Latin-hypercube first generation from
the seed, DE's own generator from it too), and each generation's rows are kept in
``OUT/generations/gen_NNNN/``; a rerun replays the search, reading back the generations that
are done (their scores come from the same CSV rows either way), so an interrupted search ends
with the same winner as an uninterrupted one. The budget is not part of a search's identity
(:meth:`TuneSpec.identity`): a rerun with a larger budget continues the same search.

**Step check** (``check_step``): the winner is re-run at half the step in every scenario;
scenarios whose outcome changes, or whose objective metric moves by more than
:data:`CHECK_RTOL`, are flagged as not converged and left out of the winner's reported score
(listed, not scored).

Pure: numpy, scipy, dask, matplotlib (Agg); never imports rclpy or the CLI.
"""

from .report import describe_score, plot_envelope, plot_history, summary_lines
from .search import TuneResult, load_tune, run_candidates, run_tune, score, step_flags
from .spec import CHECK_RTOL, MIN_POPULATION, OBJECTIVES, ROW_FIELDS, Bound, TuneError, TuneSpec

__all__ = ['OBJECTIVES', 'Bound', 'TuneSpec', 'TuneError', 'TuneResult', 'score',
           'run_tune', 'run_candidates', 'load_tune', 'plot_envelope', 'plot_history',
           'summary_lines', 'describe_score', 'step_flags', 'ROW_FIELDS', 'MIN_POPULATION',
           'CHECK_RTOL']
