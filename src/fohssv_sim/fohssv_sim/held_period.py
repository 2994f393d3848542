"""One held-input control period of the FOM written out before the model's bookkeeping: the
lockstep plant's short path (:class:`HeldPeriod`)."""

from __future__ import annotations

from typing import Any

from . import kernels
from .bounds import MAX_PITCH, check_state

__all__ = ['HeldPeriod']


class HeldPeriod:
    """One control period of a :class:`~fohssv_sim.models.FractionalModel` with a held input
    whose new sample is written out before the model's own bookkeeping: for a loop whose
    round trip waits for the sample (the lockstep plant publishes it, then lets the model catch up).

    :meth:`run` ``(delta_f, delta_c)`` advances ``steps`` steps in the held-input kernel
    call (:class:`fohssv_sim.kernels.FomHeldCall`, the one :meth:`Plant.advance` makes for
    a held input) and, when the state is finite and within |w| <= V, |theta| <= pi/2, writes
    ``[t, z, w, theta, q]`` into ``out[0:5]`` and returns True; the caller must then call
    :meth:`settle` before anything else uses the model. After both, the model is exactly
    where ``advance((delta_f, delta_c), steps)`` leaves it (state, time, history, planing
    force: the same compiled call on the same arrays). A period that turns non-finite or
    leaves the bounds is settled at once and raises what :meth:`Plant.advance` and
    :func:`check_state` raise. :meth:`run` returns False, having done nothing, when the
    kernel call is not bound to the model's current arrays (before the model's first held
    advance, after a reset, without the C entry point): the caller advances as usual.
    """

    def __init__(self, model: Any, steps: int, out: Any) -> None:
        self._model = model
        self._steps = steps
        self._out = out
        self._v = model.params.speed
        self._x: list[float] = []       # the state run() left, for settle()

    def run(self, delta_f: float, delta_c: float) -> bool:
        model = self._model
        held = model._held_call
        if not held or model.status == 'failed' or held.x is not model._stepper.live_state():
            return False
        law = held.law
        law[8] = delta_f
        law[9] = delta_c
        taken = held.call(model._stepper.n, self._steps)
        return self.finish(taken, delta_f, delta_c)

    @property
    def steps(self) -> int:
        """Steps per period."""
        return self._steps

    def bound(self) -> tuple[kernels.FomHeldCall, int, int] | None:
        """For a caller that makes :meth:`run`'s kernel call itself (the plant's compiled
        sample): the bound kernel call with the step index it is called with and the model's
        step count (the sample's time is ``(count + steps) * h``), or None when :meth:`run`
        would return False."""
        model = self._model
        held = model._held_call
        if not held or model.status == 'failed' or held.x is not model._stepper.live_state():
            return None
        return held, model._stepper.n, model.n

    def finish(self, taken: int, delta_f: float, delta_c: float) -> bool:
        """What :meth:`run` does after its kernel call, which took ``taken`` steps with the
        input (``delta_f``, ``delta_c``): writes the sample and returns True (call
        :meth:`settle` next), or settles the period and raises as :meth:`run` does. For a
        caller that made the call itself (:meth:`bound`)."""
        model = self._model
        held = model._held_call
        steps = self._steps
        x = self._x = held.x.tolist()
        z, w, theta, q = x
        v = self._v
        if taken == steps and -v <= w <= v and -MAX_PITCH <= theta <= MAX_PITCH:
            out = self._out
            out[0] = (model.n + steps) * model.h
            out[1] = z
            out[2] = w
            out[3] = theta
            out[4] = q
            return True
        self._settle(held, taken)
        if taken < steps:
            model._failed(model._bad.tolist(), repr((delta_f, delta_c)))
        check_state(model)
        return True                      # not reached: beyond the bounds raises

    def published(self) -> None:
        """What :meth:`finish` keeps for :meth:`settle`, for a caller whose own compiled call
        (:meth:`bound`) took all the period's steps, found the state finite and within the
        bounds and wrote the sample itself (the plant's compiled sample): call
        :meth:`settle` next."""
        self._x = self._model._held_call.x.tolist()

    def settle(self) -> float:
        """The model's bookkeeping of the period :meth:`run` wrote out; returns the planing
        force at the new state."""
        held = self._model._held_call
        self._settle(held, self._steps)
        return held.values[held.FP]

    def _settle(self, held: kernels.FomHeldCall, taken: int) -> None:
        model = self._model
        model._stepped(taken, failed=taken < self._steps)
        model._fp_value = held.values[held.FP]
        model._fp_at = model._stepper.n
        model._x = tuple(self._x)
        model.n += taken
        model.status = 'running'
