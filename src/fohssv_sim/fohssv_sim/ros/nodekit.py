"""What every fohssv node imports: one public module for the shared node plumbing.

A node module (``*_node.py``, here or in another package such as ``fohssv_controller``)
imports its ROS helpers from here and never from another node's module:

* start and end: :func:`run_node` owns ``rclpy.init``, building the node, spinning it, the
  exit code and the tear-down (bad arguments or parameters: one line and exit 2, see
  :mod:`.startup`); every node uses it (plant, controller, recorder, player).
  :func:`error_line` reports a node's failures as one ``NAME: error: ...`` line;
* messages: :func:`array_message`, :class:`ArrayWriter` / :class:`ArrayReader` (serialized
  messages, :mod:`.wire`), :func:`message_class` (the Python class of a contract type);
* QoS: :func:`profile`, :func:`offered_qos` (:mod:`.qos`);
* parameters: :func:`declare`, :func:`install_validation` (from a table, :mod:`.ros_params`),
  :func:`declare_rows` (plain rows: the controller node's plugin name),
  :func:`refuse_unknown`, :func:`destroy_on_error` (:mod:`.startup`);
* spinning: :func:`make_executor`, :func:`spin_until`, :data:`STOP`, :func:`final_log`,
  and for the real-time plant :class:`PausedCollector` (:mod:`.spin`);
* the host: :func:`pin_node`, :func:`hold_latency`, :func:`set_realtime_priority`,
  :func:`tighten_timer_slack` (:mod:`.host`);
* subscription gating: :class:`SubscriptionGate`, :class:`HoldReporter`,
  :class:`SecondPublisherWarning` (:mod:`.matching`);
* counted faults: :class:`LogLimiter` (the first lines one by one, then at most one a
  second: dropped messages, rejected commands, a plugin that raises).
"""

from __future__ import annotations

import sys
import traceback
from collections.abc import Callable, Iterable
from time import monotonic
from typing import Any

import rclpy
import rclpy.logging
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..params import ParameterError, ParameterSpec
from .host import hold_latency, pin_node, set_realtime_priority, tighten_timer_slack
from .matching import HoldReporter, SecondPublisherWarning, SubscriptionGate
from .options import CPU_AFFINITY, CPU_DMA_LATENCY
from .qos import offered_qos, profile
from .ros_params import declare, install_validation
from .spin import STOP, PausedCollector, final_log, make_executor, spin_until
from .startup import (
    EXIT_BAD_PARAMETERS,
    NODE_OPTIONS,
    BadParameters,
    declare_rows,
    destroy_on_error,
    end_process_on_build_error,
    exit_now,
    init,
    refuse_unknown,
    report,
)
from .wire import ArrayReader, ArrayWriter, ClockWriter, array_message, message_class

__all__ = ['run_node', 'spin_node', 'EXIT_OK', 'EXIT_BAD_PARAMETERS', 'NODE_OPTIONS',
           'array_message', 'message_class', 'ArrayReader', 'ArrayWriter', 'ClockWriter',
           'profile', 'offered_qos', 'declare', 'install_validation', 'declare_rows',
           'refuse_unknown', 'error_line', 'destroy_on_error', 'BadParameters', 'make_executor',
           'spin_until', 'STOP', 'final_log', 'SubscriptionGate', 'HoldReporter',
           'SecondPublisherWarning',
           'PausedCollector', 'set_realtime_priority', 'tighten_timer_slack', 'init', 'report',
           'LogLimiter', 'pin_node', 'CPU_AFFINITY', 'CPU_DMA_LATENCY', 'hold_latency',
           'PluginFailed', 'build_plugin', 'reset_plugin', 'PLUGIN_FAULTS']

EXIT_OK = 0


#: What a plugin's call may raise that a node catches as the plugin's failure: any exception,
#: and ``sys.exit()`` and ``KeyboardInterrupt`` from its code (the nodes' signals never raise:
#: they set :data:`STOP`), so a law can neither end the node nor pass for a signal.
PLUGIN_FAULTS = (Exception, SystemExit, KeyboardInterrupt)


class PluginFailed(ValueError):
    """A controller plugin's constructor raised: at start one line and exit 2
    (:func:`run_node`); on a parameter change the change is refused with this reason."""


def build_plugin(cls: Any, parameters: Any) -> Any:
    """``cls(parameters)``, a plugin's own failure as :class:`PluginFailed` naming the plugin,
    the exception and its text (a :class:`~fohssv_sim.params.ParameterError` passes as is)."""
    try:
        return cls(parameters)
    except ParameterError:
        raise
    except Exception as exc:  # noqa: BLE001 - a plugin's bug: one line, not a traceback
        name = getattr(cls, 'name', '') or cls.__name__
        raise PluginFailed(f'controller {name!r} could not be built: its constructor raised '
                           f'{type(exc).__name__}: {exc}') from None


def reset_plugin(name: str, reset: Callable[[], None]) -> str | None:
    """Call a plugin's ``reset``; the reason when it raised (None when it did not). The
    caller refuses the reset with it and stays alive."""
    try:
        reset()
    except PLUGIN_FAULTS as exc:  # a plugin's bug must not end the node
        return f'{name}.reset() raised {type(exc).__name__}: {exc}'
    return None


class LogLimiter:
    """Log a counted fault: the first ``each`` lines one by one, then at most one line every
    ``period`` s (wall time), which says how many were not logged since the last one.

    rclpy's own ``throttle_duration_sec`` cannot do this from one call site: a call site
    that passes it once with 0 and then with 1.0 raises "Requested logging filters cannot be
    changed between calls" (rclpy keys a filter context by the caller's file and line), which
    killed the controller node at the 21st dropped state. Here the logger is called without
    filters, from one place, and the limiting is plain arithmetic (cheap: one clock read
    per fault).

    Args:
        logger: an rclpy logger (``node.get_logger()``).
        each: lines logged one by one before the limit applies.
        period: the least time between two lines after that (s).
        level: the logger method, ``'error'`` or ``'warning'``.
    """

    def __init__(self, logger: Any, each: int = 20, period: float = 1.0,
                 level: str = 'error') -> None:
        self._log = getattr(logger, level)
        self.each = each
        self.period = period
        self.count = 0           # faults seen
        self.logged = 0          # lines logged
        self._skipped = 0        # faults not logged since the last line
        self._next = 0.0

    def __call__(self, text: str) -> bool:
        """Count one fault; log ``text`` unless the limit holds it back. True when logged."""
        self.count += 1
        if self.count > self.each:
            now = monotonic()
            if now < self._next:
                self._skipped += 1
                return False
            self._next = now + self.period
            if self._skipped:
                text = f'{text} [{self._skipped} similar line(s) not logged in the last ' \
                       f'{self.period:g} s]'
                self._skipped = 0
        elif self.count == self.each:
            text = f'{text} [logged one by one up to here; from now on at most one line ' \
                   f'every {self.period:g} s]'
            self._next = monotonic() + self.period
        self.logged += 1
        try:
            self._log(text)
        except Exception:  # noqa: BLE001 - the context is going down (a signal): say it here
            final_log('fohssv', text)
        return True


def spin_node(node: Node) -> int:
    """The default run of :func:`run_node`: spin ``node`` on the nodes' executor until a
    signal (:data:`STOP`) or shutdown; exit code 0."""
    executor = make_executor()
    executor.add_node(node)
    spin_until(executor)
    return EXIT_OK


def error_line(name: str, expected: tuple[type[BaseException], ...] = (OSError,)
               ) -> Callable[[Exception], int]:
    """An ``on_error`` for :func:`run_node`: one line ``NAME: error: ...`` on stderr and exit
    1, with the text of an ``expected`` exception (a bad bag, an OS error) or the type and
    text of any other (a bug). After a shutdown of the context (a signal during start-up)
    nothing is printed and the code is 0."""

    def on_error(exc: Exception) -> int:
        if isinstance(exc, expected):
            text = str(exc)
        elif rclpy.ok():
            text = f'{type(exc).__name__}: {exc}'
        else:
            return EXIT_OK
        print(f'{name}: error: {text}', file=sys.stderr, flush=True)
        return 1

    return on_error


def run_node(name: str, args: list[str] | None, build: Callable[[], Node],
             run: Callable[[Any], int] = spin_node, *,
             specs: Iterable[ParameterSpec] = (),
             refused: tuple[type[BaseException], ...] = (),
             on_interrupt: Callable[[Any], int] | None = None,
             on_error: Callable[[Exception], int] | None = None,
             on_exit: Callable[[Any], None] | None = None) -> int:
    """Run one node process from start to exit code; every node's ``main`` is this call.

    1. ``rclpy.init`` with rclpy's signal handlers off: SIGINT/SIGTERM only set :data:`STOP`
       and the loop ends between callbacks (see :class:`.spin.StopSignal`). Bad arguments:
       one line, exit :data:`EXIT_BAD_PARAMETERS`.
    2. ``build()`` makes the node. A ``ValueError`` or rclpy ``ParameterException`` (invalid
       parameters) gives one line explained with ``specs`` and exit 2; an exception of
       ``refused`` (e.g. an unknown plugin) or a :class:`PluginFailed` is logged under
       ``name`` and gives exit 2; any other goes to ``on_error(exc)`` for its line and code
       (without one: its traceback and exit 1); a signal during the build exits 0. Each
       ends the process at once (:func:`.startup.exit_now`): the half-built node is never
       torn down (:func:`.startup.destroy_on_error`).
    3. ``run(node)`` spins it (default :func:`spin_node`) and returns the exit code. A
       ``KeyboardInterrupt`` or ``ExternalShutdownException`` ends it; ``on_interrupt(node)``
       then gives the code (default: 0). Any other exception goes to ``on_error(exc)``,
       which reports it and gives the code (default: it propagates).
    4. ``on_exit(node)`` (e.g. a final log line), ``node.destroy_node()``, ``rclpy.shutdown``;
       from then on SIGINT/SIGTERM are ignored (the process only exits).

    Returns:
        The process's exit code (the caller passes it to ``sys.exit``).
    """
    try:
        init(args, signal_handler_options=SignalHandlerOptions.NO)
    except BadParameters as exc:
        return report(name, exc)
    STOP.install()
    end_process_on_build_error()
    code = EXIT_OK
    node = None
    try:
        try:
            node = build()
        except (PluginFailed, *refused) as exc:
            rclpy.logging.get_logger(name).error(str(exc))
            exit_now(EXIT_BAD_PARAMETERS)
        except (ValueError, ParameterException) as exc:   # ParameterError, BadParameters
            report(name, exc, specs)
        except (KeyboardInterrupt, ExternalShutdownException):
            exit_now(EXIT_OK)                 # a signal during start-up: nothing ran
        except SystemExit as exc:             # sys.exit() in a constructor: its code
            exit_now(exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1)
        except Exception as exc:
            if on_error is None:
                traceback.print_exc()
                exit_now(1)
            exit_now(on_error(exc))
        code = run(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        if node is not None and on_interrupt is not None:
            code = on_interrupt(node)
    except Exception as exc:
        if on_error is None:
            raise
        code = on_error(exc)
    finally:
        if node is not None:
            if on_exit is not None:
                on_exit(node)
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
        STOP.exiting()
    return code
