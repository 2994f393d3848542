"""How the fohssv nodes spin: one executor choice and one loop, shared by every node.

``rclpy.experimental.EventsExecutor`` is the default (1 kHz publishing and a lockstep round
trip hold with it on a 2-core machine, where the default executor falls behind). Its blocking
``spin()`` is not used: in rclpy 9.1.2 (Kilted) it keeps a core busy and ignores SIGINT.
:func:`spin_until` instead calls ``spin_once`` with a timeout, which does neither.
``FOHSSV_EXECUTOR=single`` selects rclpy's ``SingleThreadedExecutor`` instead.
"""

from __future__ import annotations

import os

import rclpy
from rclpy.executors import Executor
from rclpy.task import Future

__all__ = ['make_executor', 'spin_until', 'final_log']


def make_executor() -> Executor:
    """The executor the nodes use (see the module docstring)."""
    if os.environ.get('FOHSSV_EXECUTOR', 'events') != 'single':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # pragma: no cover - rclpy without it
            pass
        else:
            return EventsExecutor()
    return rclpy.executors.SingleThreadedExecutor()


def spin_until(executor: Executor, future: Future | None = None, poll: float = 0.1) -> None:
    """Process callbacks until ``future`` is done (or forever when ``None``) or the context
    shuts down. Raises KeyboardInterrupt / ExternalShutdownException on SIGINT."""
    while rclpy.ok() and (future is None or not future.done()):
        executor.spin_once(timeout_sec=poll)


def final_log(name: str, text: str) -> None:
    """Log ``text`` after SIGINT shut the context down (the node's logger would fail to
    publish to /rosout then): to stderr, in the console format."""
    import sys
    import time

    print(f'[INFO] [{time.time():.9f}] [{name}]: {text}', file=sys.stderr, flush=True)
