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

Unset (the default), nothing is wrapped: the plant publishes through rclpy's own call and the
per-sample path costs nothing more. The plant logs a warning when the variable is set.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

from ..params import ParameterError

__all__ = ['REFUSE_STATE_VAR', 'STALL_STATE_VAR', 'refused_publishes', 'refusing',
           'stalled_publish', 'stalling']

#: The environment variable: ``N`` or ``N:M`` (see the module docstring).
REFUSE_STATE_VAR = 'FOHSSV_FAULT_REFUSE_STATE'
#: The environment variable: ``N:S`` (see the module docstring).
STALL_STATE_VAR = 'FOHSSV_FAULT_STALL_STATE'
_LIMIT = 10**12


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


def refusing(send: Callable[[Any], Any], after: int, count: int | None) -> Callable[[Any], Any]:
    """``send`` (a publish call) that raises rclpy's ``RCLError`` for the calls after the
    first ``after`` successful ones: ``count`` times, or for good when ``count`` is None."""
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    error = _rclpy.RCLError
    state = {'sent': 0, 'refused': 0}

    def publish(payload: Any) -> Any:
        if state['sent'] >= after and (count is None or state['refused'] < count):
            state['refused'] += 1
            raise error(f'Failed to publish: refused by {REFUSE_STATE_VAR} (testing aid)')
        result = send(payload)
        state['sent'] += 1
        return result

    return publish


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


def stalling(send: Callable[[Any], Any], after: int, seconds: float) -> Callable[[Any], Any]:
    """``send`` (a publish call) whose call after the first ``after`` sleeps ``seconds``
    first, once."""
    state = {'sent': 0}

    def publish(payload: Any) -> Any:
        if state['sent'] == after:
            time.sleep(seconds)
        state['sent'] += 1
        return send(payload)

    return publish
