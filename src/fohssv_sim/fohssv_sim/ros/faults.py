"""Fault injection for tests: a plant whose ``state`` publishes DDS "refuses" (a testing aid).

rclpy raises ``RCLError('Failed to publish')`` when rmw_fastrtps's write fails, and the plant
retries such a sample for a second before it ends the run with exit 9 (``plant_node``). No
deterministic way to make a real write fail was found: in Fast DDS 3.2 a keep-last writer
(every publisher of the plant) makes room by dropping its oldest sample whether or not it was
acknowledged, so a stopped reader or a short ``max_blocking_time`` never fails a write (only
an exhausted payload or change pool, or a serialization error, does). So the failure is
injected, at the one place the plant publishes, with the exception rclpy itself raises:

``FOHSSV_FAULT_REFUSE_STATE=N`` (read once, when the plant starts): after the first ``N``
``state`` samples, every publish of ``state`` raises rclpy's ``RCLError``;
``FOHSSV_FAULT_REFUSE_STATE=N:M`` refuses only the next ``M`` publishes, then accepts again
(``M`` below 1000 is a refusal the plant's 1 s of retries, one a millisecond, gets past).

``FOHSSV_FAULT_STALL_STATE=N:S`` (read once, when the plant starts): the publish of ``state``
after the first ``N`` waits ``S`` seconds (asleep, using no CPU) before it publishes: a write
that DDS blocked (Fast DDS checks the shared-memory port of a subscriber's stopped process for
up to 1 s before it gives up on it), or a host that did not run the plant, at a known sample.

Both act on every path a state leaves by, with one count (:class:`StateFault`): the plant's
interpreted publish call (:meth:`StateFault.wrap`) and the compiled fast path's rcl publish
(:meth:`StateFault.sink`, which stands in for ``rcl_publish_serialized_message`` and returns
rcl's error code where rclpy would raise), so the fault tests exercise the path a run takes.

Unset (the default), nothing is wrapped: the plant publishes through rclpy's own call and the
per-sample path costs nothing more. The plant logs a warning when the variable is set.
"""

from __future__ import annotations

import ctypes
import os
import time
from collections.abc import Callable
from typing import Any

from ..params import ParameterError

__all__ = ['REFUSE_STATE_VAR', 'STALL_STATE_VAR', 'StateFault', 'refused_publishes',
           'stalled_publish']

#: The environment variable: ``N`` or ``N:M`` (see the module docstring).
REFUSE_STATE_VAR = 'FOHSSV_FAULT_REFUSE_STATE'
#: The environment variable: ``N:S`` (see the module docstring).
STALL_STATE_VAR = 'FOHSSV_FAULT_STALL_STATE'
_LIMIT = 10**12
#: rcl's generic error (rcl/types.h: RCL_RET_ERROR), what the compiled sink returns.
_RCL_RET_ERROR = 1
_SINK = ctypes.CFUNCTYPE(ctypes.c_int32, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p)


def _fault_text(var: str, environ: dict[str, str] | None) -> str:
    """The value of the fault variable ``var`` ('' when unset)."""
    return (os.environ if environ is None else environ).get(var, '').strip()


def refused_publishes(environ: dict[str, str] | None = None) -> tuple[int, int | None] | None:
    """``(after, count)`` from :data:`REFUSE_STATE_VAR` (``count`` None: every publish after
    ``after``); None when it is unset or empty.

    Raises:
        ParameterError: a value that is not ``N`` or ``N:M`` with whole numbers in range.
    """
    text = _fault_text(REFUSE_STATE_VAR, environ)
    if not text:
        return None
    parts = text.split(':')
    try:
        if len(parts) > 2:
            raise ValueError
        after = int(parts[0])
        count = int(parts[1]) if len(parts) == 2 else None
    except ValueError:
        after = count = -1
    if not 0 <= after <= _LIMIT or (count is not None and not 1 <= count <= _LIMIT):
        raise ParameterError(
            f'{REFUSE_STATE_VAR}={text!r}: expected N or N:M, whole numbers with 0 <= N <= '
            f'1e12 and 1 <= M <= 1e12 (state publishes: refused after the first N, M times or '
            'for good); a testing aid, unset it to run normally')
    return after, count



def stalled_publish(environ: dict[str, str] | None = None) -> tuple[int, float] | None:
    """``(after, seconds)`` from :data:`STALL_STATE_VAR`; None when it is unset or empty.

    Raises:
        ParameterError: a value that is not ``N:S`` with a whole ``N`` and ``S`` in range.
    """
    text = _fault_text(STALL_STATE_VAR, environ)
    if not text:
        return None
    try:
        n, sec = text.split(':')
        after, seconds = int(n), float(sec)
    except ValueError:
        after, seconds = -1, -1.0
    if not (0 <= after <= _LIMIT and 0.0 < seconds <= 3600.0):
        raise ParameterError(
            f'{STALL_STATE_VAR}={text!r}: expected N:S, a whole number 0 <= N <= 1e12 and '
            '0 < S <= 3600 s (the state publish after the first N waits S seconds); a testing '
            'aid, unset it to run normally')
    return after, seconds


class StateFault:
    """The injected faults of the state's publishes (module docstring), counted once for
    every path: a stall of the publish after the first ``stall[0]`` calls, for ``stall[1]``
    s, once; refusals after the first ``refuse[0]`` successful publishes, ``refuse[1]`` times
    or for good (None)."""

    def __init__(self, refuse: tuple[int, int | None] | None,
                 stall: tuple[int, float] | None) -> None:
        self.refuse = refuse
        self.stall = stall
        self.calls = 0
        self.sent = 0
        self.refused = 0
        self._sinks: list[Any] = []      # the C callbacks handed out, kept alive

    @classmethod
    def from_environment(cls, environ: dict[str, str] | None = None) -> StateFault | None:
        """The faults the environment asks for; None when neither variable is set.

        Raises:
            ParameterError: a bad value (:func:`refused_publishes`, :func:`stalled_publish`).
        """
        refuse, stall = refused_publishes(environ), stalled_publish(environ)
        return None if refuse is None and stall is None else cls(refuse, stall)

    def warnings(self) -> list[str]:
        """One line per fault asked for, for the plant's log."""
        lines = []
        if self.refuse is not None:
            after, count = self.refuse
            lines.append(f'{REFUSE_STATE_VAR}: state publishes after the first {after} are '
                         'refused ' + ('for good' if count is None else f'{count} time(s)')
                         + ' (fault injection, a testing aid: unset it to run normally)')
        if self.stall is not None:
            lines.append(f'{STALL_STATE_VAR}: the state publish after the first '
                         f'{self.stall[0]} waits {self.stall[1]:g} s (fault injection, a '
                         'testing aid: unset it to run normally)')
        return lines

    def _refuses(self) -> bool:
        """Before a publish: the stall when due, then whether this publish is refused."""
        if self.stall is not None and self.calls == self.stall[0]:
            time.sleep(self.stall[1])
        self.calls += 1
        if self.refuse is None:
            return False
        after, count = self.refuse
        if self.sent >= after and (count is None or self.refused < count):
            self.refused += 1
            return True
        return False

    def wrap(self, send: Callable[[Any], Any]) -> Callable[[Any], Any]:
        """``send`` (the state's publish call) with the faults: a refused publish raises
        rclpy's ``RCLError``, as rclpy does when rcl refuses."""
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        error = _rclpy.RCLError

        def publish(payload: Any) -> Any:
            if self._refuses():
                raise error(f'Failed to publish: refused by {REFUSE_STATE_VAR} (testing aid)')
            result = send(payload)
            self.sent += 1
            return result

        return publish

    def sink(self, publish: int, state_publisher: int) -> int:
        """The address of a C function that stands in for rcl's publish at ``publish``
        (``int32 (publisher, message, allocation)``) for the compiled fast path: the faults
        apply to the state's publisher at ``state_publisher`` (a refusal returns rcl's
        generic error), every other publish goes through unchanged."""
        rcl_publish = _SINK(publish)

        def sink(publisher: int | None, message: int | None, allocation: int | None) -> int:
            if publisher == state_publisher:
                if self._refuses():
                    return _RCL_RET_ERROR
                ret = rcl_publish(publisher, message, allocation)
                if ret == 0:
                    self.sent += 1
                return ret
            return rcl_publish(publisher, message, allocation)

        callback = _SINK(sink)
        self._sinks.append(callback)
        return ctypes.cast(callback, ctypes.c_void_p).value
