"""Compiled drivers over the stepping kernels of :mod:`.kernels`: many steps in one call with
the samples written from compiled code.

**Sampled drivers.** Each ``*_sampled`` function runs ``periods`` control periods of ``hold``
steps in one call with an affine law sampled at the start of each period and held over it
(zero-order hold: what the plant does with a hosted affine controller, one sample per
period). After each period it writes the sample ``[z, w, theta, q, Fp, delta_f, delta_c]`` to a
row of ``out`` and stops early -- returning ``(samples written, status, steps of the last
period)`` -- at a non-finite state (status 1, nothing written for that period), at a sample
outside the physical bounds (status 2) or at a command that is non-finite or beyond the plant's
deflection limits (status 3; its two columns are not written). The caller handles those
samples the slow way, so the results equal one kernel call per period with the law evaluated
in Python (``test/test_kernels.py``).

**Recorded drivers.** Each ``*_recorded`` function runs many steps in one call (the input
held or an affine law at every stage, as ``*_run``) and keeps the state before every
``every``-th step of them: the state, the planing force there (the one the step's first stage
computed) and the input applied from it on, written into preallocated arrays from compiled
code in the same pass, so that keeping every step costs little more than keeping none. It
stops early at a non-finite state (status 1) or at a kept state outside the physical bounds
(status 2). :meth:`fohssv_sim.models.Plant.record` calls it;
:func:`fohssv_sim.simulate.simulate` records a whole run through it.

Compiled on first use and cached on disk, as the kernels (:func:`fohssv_sim.models.warm_up`).
"""

from __future__ import annotations

import math

from .kernels import (
    _abm_f,
    _abm_step_from,
    _clamp,
    _delayed_step,
    _fail,
    _finite4,
    _free_step,
    _input,
    _njit,
    _planing,
    _planing_at_delay,
    delay_free_run,
    delayed_run,
    fom_soe_run,
    unpack_coefficients,
)
from .physics import jitable

__all__ = ['delay_free_sampled', 'delayed_sampled', 'fom_soe_sampled', 'delay_free_recorded',
           'delayed_recorded', 'fom_soe_recorded']


# -- sampled drivers: an affine law at every control instant, held over the period -------------

@jitable
def _sampled_command(law, x, held, fmax, cmax):
    """u = clamp(K x + u0) at a sample into ``held`` (a held-input law); False when it is
    non-finite or beyond the plant's limits. Summed as the eq. 31 controller's ``update``;
    finiteness is checked before the clamp (as :class:`fohssv_sim.ros.loop.HostedLaw` does)."""
    uf = (law[0] * x[0] + law[1] * x[1] + law[2] * x[2] + law[3] * x[3]) + law[8]
    uc = (law[4] * x[0] + law[5] * x[1] + law[6] * x[2] + law[7] * x[3]) + law[9]
    if not (math.isfinite(uf) and math.isfinite(uc)):
        return False
    uf = _clamp(uf, law[10])
    uc = _clamp(uc, law[11])
    if abs(uf) > fmax or abs(uc) > cmax:
        return False
    held[8] = uf
    held[9] = uc
    return True


@jitable
def _in_bounds(x, wmax, pmax):
    return -wmax <= x[1] <= wmax and -pmax <= x[2] <= pmax


@jitable
def _take_sample(out, p, x, fp, law, held, limits):
    """Row ``p`` of ``out`` for the sample ``x`` (and ``fp``), and the law's command for it
    into ``held``: 0, or the status that stops the burst (2 out of bounds, 3 no command)."""
    out[p, 0], out[p, 1], out[p, 2], out[p, 3] = x[0], x[1], x[2], x[3]
    out[p, 4] = fp
    if not _in_bounds(x, limits[2], limits[3]):
        return 2
    if not _sampled_command(law, x, held, limits[0], limits[1]):
        return 3
    out[p, 5], out[p, 6] = held[8], held[9]
    return 0


@_njit
def delay_free_sampled(x, hold, periods, h, cv, smooth, law, held, limits, bad, out):
    """``periods`` periods of :func:`delay_free_run` with ``law`` sampled (module docstring);
    ``held`` is the held-input law array (its u0 = the command in force), ``limits`` =
    [max |delta_f|, max |delta_c|, max |w|, max |theta|]."""
    c = unpack_coefficients(cv)
    for p in range(periods):
        taken = delay_free_run(x, hold, h, cv, smooth, held, False, bad)
        if taken < hold:
            return p, 1, taken
        status = _take_sample(out, p, x, _planing(c, smooth, x[1]), law, held, limits)
        if status:
            return p + 1, status, hold
    return periods, 0, hold


@_njit
def delayed_sampled(x, n, hold, periods, h, cv, hx, hf, lag, tau, x_init, paper, law, held,
                    limits, bad, out):
    """``periods`` periods of :func:`delayed_run` from step ``n`` with ``law`` sampled (see
    :func:`delay_free_sampled`); Fp at a sample from the history, as the model computes it."""
    c = unpack_coefficients(cv)
    for p in range(periods):
        m = n + p * hold
        taken = delayed_run(x, m, hold, h, cv, hx, hf, lag, tau, x_init, paper, held, False,
                            bad)
        if taken < hold:
            return p, 1, taken
        fp = _planing_at_delay(c, paper, hx, hf, m + hold, 0.0, lag, tau, h, x_init, x)
        status = _take_sample(out, p, x, fp, law, held, limits)
        if status:
            return p + 1, status, hold
    return periods, 0, hold


@_njit
def fom_soe_sampled(x, x0, n, hold, periods, cv, smooth, law, held, limits, H, W, fill, eps_k,
                    ET, a0_coef, a0_small, alpha, cp, cc, last_f, bad, out):
    """``periods`` periods of :func:`fom_soe_run` from step ``n`` with ``law`` sampled (see
    :func:`delay_free_sampled`)."""
    c = unpack_coefficients(cv)
    for p in range(periods):
        taken = fom_soe_run(x, x0, n + p * hold, hold, cv, smooth, held, False, H, W, fill,
                            eps_k, ET, a0_coef, a0_small, alpha, cp, cc, last_f, bad)
        if taken < hold:
            return p, 1, taken
        status = _take_sample(out, p, x, _planing(c, smooth, x[1]), law, held, limits)
        if status:
            return p + 1, status, hold
    return periods, 0, hold


# -- recorded drivers: many steps in one call, every kept sample written from compiled code ----

@jitable
def _kept(done, first, every, row, xs_out, fp_out, u_out, x, fp, law, continuous, wmax, pmax):
    """Step ``done`` of a recorded call, at the state ``x`` (Fp there ``fp``, from the step's
    first stage): when it is the kept one (``first``), row ``row`` of the kept samples (the
    state, Fp and the input applied from ``x`` on: the held u0 or the law's value there).
    Returns (the next kept step, the next free row, False when ``x`` was kept beyond
    |w| <= ``wmax``, |theta| <= ``pmax``)."""
    if done != first:
        return first, row, True
    uf, uc = _input(law, continuous, x[0], x[1], x[2], x[3])
    xs_out[row, 0], xs_out[row, 1], xs_out[row, 2], xs_out[row, 3] = x[0], x[1], x[2], x[3]
    fp_out[row] = fp
    u_out[row, 0], u_out[row, 1] = uf, uc
    return first + every, row + 1, _in_bounds(x, wmax, pmax)


@_njit
def delay_free_recorded(x, nsteps, first, every, h, cv, smooth, law, continuous, bad, xs_out,
                        fp_out, u_out, row, wmax, pmax):
    """:func:`delay_free_run` that keeps the state before step ``first``, ``first + every``,
    ... of the call as row ``row``, ``row + 1``, ... of ``xs_out`` (states), ``fp_out`` (Fp)
    and ``u_out`` (inputs) (:func:`_kept`). Returns (the next free row, steps taken,
    status): status 0, or 1 when a state turned non-finite (``bad``), 2 when a kept state
    is beyond the bounds (the run stops there)."""
    c = unpack_coefficients(cv)
    xs = (x[0], x[1], x[2], x[3])
    hh = 0.5 * h
    done = status = 0
    while done < nsteps:
        xn, fp = _free_step(c, smooth, law, continuous, xs, h, hh)
        first, row, ok = _kept(done, first, every, row, xs_out, fp_out, u_out, xs, fp, law,
                               continuous, wmax, pmax)
        if not ok:
            status = 2
            break
        if not _finite4(xn[0], xn[1], xn[2], xn[3]):
            _fail(bad, xn[0], xn[1], xn[2], xn[3])
            status = 1
            break
        xs = xn
        done += 1
    x[0], x[1], x[2], x[3] = xs
    return row, done, status


@_njit
def delayed_recorded(x, n, nsteps, first, every, h, cv, hx, hf, lag, tau, x_init, paper, law,
                     continuous, bad, xs_out, fp_out, u_out, row, wmax, pmax):
    """:func:`delay_free_recorded` for :func:`delayed_run` from step ``n`` (Fp at a kept state
    from the history, as the model computes it)."""
    c = unpack_coefficients(cv)
    xs = (x[0], x[1], x[2], x[3])
    hh = 0.5 * h
    done = status = 0
    while done < nsteps:
        xn, fp = _delayed_step(c, paper, hx, hf, n + done, lag, tau, h, hh, x_init, law,
                               continuous, xs)
        first, row, ok = _kept(done, first, every, row, xs_out, fp_out, u_out, xs, fp, law,
                               continuous, wmax, pmax)
        if not ok:
            status = 2
            break
        if not _finite4(xn[0], xn[1], xn[2], xn[3]):
            _fail(bad, xn[0], xn[1], xn[2], xn[3])
            status = 1
            break
        xs = xn
        done += 1
    x[0], x[1], x[2], x[3] = xs
    return row, done, status


@_njit
def fom_soe_recorded(x, x0, n, nsteps, first, every, cv, smooth, law, continuous, H, W, fill,
                     eps_k, ET, a0_coef, a0_small, alpha, cp, cc, last_f, bad, xs_out, fp_out,
                     u_out, row, wmax, pmax):
    """:func:`delay_free_recorded` for :func:`fom_soe_run` from step ``n``."""
    c = unpack_coefficients(cv)
    done = status = 0
    while done < nsteps:
        f, fp = _abm_f(x, c, smooth, law, continuous)
        first, row, ok = _kept(done, first, every, row, xs_out, fp_out, u_out, x, fp, law,
                               continuous, wmax, pmax)
        if not ok:
            status = 2
            break
        if not _abm_step_from(f, x, x0, n + done, c, smooth, law, continuous, H, W, fill,
                              eps_k, ET, a0_coef, a0_small, alpha, cp, cc, last_f, bad):
            status = 1
            break
        done += 1
    return row, done, status
