"""The controller contract and the controller plugin registry (pure: no rclpy).

This is the interface half of the controllers, in the core as in ros2_control: the built-in
laws (``fohssv_controller``: state_feedback, lqr, fractional_pid) and any third-party package
implement :class:`Controller` and register it under the entry-point group :data:`GROUP`;
the core (simulation, analysis, CLI, docs) finds them through :func:`load` and never imports
an implementation package.

A controller maps the plant's state to the two deflections, in rad::

    class MyController(Controller):
        name = 'my_controller'
        Parameters = MyParameters            # a frozen dataclass (see below)

        def update(self, t, state):          # state = [z, w, theta, q]
            return delta_f, delta_c

Rules for implementers:

* ``update(t, state)`` returns ``(delta_f, delta_c)`` in rad and does no I/O. It is called at
  every control sample (zero-order hold, as through ROS) or, in continuous mode, at every
  solver stage; a controller with internal memory must set ``stateless = False`` so that
  continuous mode, which calls it at intermediate stage times, refuses it.
* ``reset()`` clears internal memory (called when the plant resets).
* ``scheduling`` maps controller parameters that must follow a model parameter (the speed of a
  gain-scheduled law) to that model parameter; the analysis sets them per scenario.
* ``Parameters`` is a frozen dataclass whose fields are built with
  :func:`fohssv_sim.params.spec_field` and validated by
  :func:`fohssv_sim.params.validate_fields` in ``__post_init__``: each field has a name,
  unit, range and description, which the ROS node turns into declared parameters and the
  README into a table. Unknown or invalid values raise
  :class:`fohssv_sim.params.ParameterError`.
* The outputs are clamped to the deflection limits the parameters give, if they have
  ``max_fin_deflection`` / ``max_cavitator_deflection`` fields (done by :meth:`command`).
  A non-finite output is never clamped (``clamp(nan)`` would give the full limit):
  :meth:`command` raises :class:`NonFiniteCommand` (a ``FloatingPointError``), so the batch
  runner stops with it and the controller node sends no command for that state.

Nothing here imports rclpy: controllers are usable in notebooks, sweeps and the batch runner.

Plugins: setuptools entry points in the group ``fohssv.controllers``. A package registers a
controller class under a name in its ``setup.py``::

    entry_points={'fohssv.controllers': ['my_law = my_pkg.my_module:MyController']}

:func:`available` lists the names; :func:`load` returns the class; :func:`make` instantiates
it with parameter overrides. A plugin that fails to import, or is not a Controller, is
reported naming it (ros2cli's rule), so one broken package cannot hide the others.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from importlib.metadata import EntryPoint, entry_points
from typing import Any, ClassVar

from .params import ParameterError, ParameterSpec

__all__ = ['Controller', 'ParameterError', 'NonFiniteCommand', 'clamp', 'DEFLECTION_LIMIT',
           'deflection_limit', 'GROUP', 'UnknownController', 'available', 'load', 'make',
           'as_law', 'per_sample_command']

#: The entry-point group of controller plugins.
GROUP = 'fohssv.controllers'

#: Default deflection limit (rad): generous, so clamping does not bind in the reference loops
#: (test_models.test_deflection_limit_default_does_not_bind_in_the_reference_loops).
DEFLECTION_LIMIT = 0.5


def deflection_limit(name: str, text: str) -> ParameterSpec:
    """The spec of a ``max_fin_deflection`` / ``max_cavitator_deflection`` parameter, which
    :meth:`Controller.command` clamps to."""
    return ParameterSpec(name, '-', DEFLECTION_LIMIT, 'rad', text, low=0.0, high=1.5708,
                         high_open=False, needs_reset=False)


class NonFiniteCommand(FloatingPointError):
    """A control law returned a non-finite deflection; nothing may be commanded from it.
    The message names the controller, the time, the outputs and the state."""


def clamp(value: float, limit: float) -> float:
    """``value`` limited to [-limit, limit]."""
    return max(-limit, min(limit, value))


class Controller(ABC):
    """Base class of every controller; see the module docstring for the rules."""

    #: Registered name (the entry point name in group ``fohssv.controllers``).
    name: ClassVar[str] = ''
    #: The parameter dataclass of this controller.
    Parameters: ClassVar[type]
    #: False when ``update`` keeps memory between calls (continuous mode is then refused).
    stateless: ClassVar[bool] = True
    #: Controller parameters that follow the plant: {controller parameter: model parameter}.
    #: The analysis (``fohssv tune``, ``fohssv gainmap``) sets each from the scenario's model
    #: parameters, e.g. a gain-scheduled law's ``speed`` input (``scheduled``); on a graph the
    #: user sets it as a node parameter.
    scheduling: ClassVar[dict[str, str]] = {}

    def __init__(self, params: Any = None, **overrides: Any) -> None:
        if params is None:
            valid = {f.name for f in dataclasses.fields(self.Parameters)}
            unknown = sorted(set(overrides) - valid)
            if unknown:
                raise ParameterError(
                    f"{self.name}: unknown parameter(s) {', '.join(unknown)}; valid names: "
                    f"{', '.join(sorted(valid))}")
            params = self.Parameters(**overrides)
        elif overrides:
            params = dataclasses.replace(params, **overrides)
        self.params = params
        self.reset()

    def reset(self) -> None:  # noqa: B027 - optional hook, empty by design
        """Clear internal memory (none by default)."""

    @abstractmethod
    def update(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        """Return ``(delta_f, delta_c)`` in rad for time ``t`` (s) and ``state``
        [z, w, theta, q]."""

    def affine(self) -> tuple[Any, Any] | None:
        """``(K, u0)`` with K of shape (2, 4) and u0 of shape (2,) when the law is
        ``u = K x + u0`` (before clamping), else None. Batched sweeps need it."""
        return None

    def command(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        """:meth:`update`, clamped to the parameters' deflection limits.

        Raises:
            NonFiniteCommand: the law's output is NaN or infinite (e.g. gains so large that
                a product overflows); clamping it would command a full deflection.
        """
        df, dc = self.update(t, state)
        df = float(df)
        dc = float(dc)
        if not (df - df == 0.0 and dc - dc == 0.0):   # False for NaN and +-inf
            raise NonFiniteCommand(
                f'{self.name or type(self).__name__}: non-finite output at t={t!r} s: '
                f'delta_f={df!r}, delta_c={dc!r} rad from [z, w, theta, q] = '
                f'{[float(v) for v in state]}')
        p = self.params
        lf = getattr(p, 'max_fin_deflection', math.inf)
        lc = getattr(p, 'max_cavitator_deflection', math.inf)
        return clamp(df, lf), clamp(dc, lc)

    __call__ = command

    def describe(self) -> str:
        fields = ', '.join(f'{k}={v:g}' if isinstance(v, float) else f'{k}={v}'
                           for k, v in dataclasses.asdict(self.params).items())
        return f'{self.name}({fields})'


def as_law(controller: Any) -> tuple[Callable[[float, Sequence[float]], Sequence[float]], str]:
    """``(law, name)`` for what the simulation and analysis functions accept as a controller:
    ``None`` (open loop, zero deflections), a :class:`Controller` (its clamped
    :meth:`~Controller.command`) or a callable ``(t, state) -> (delta_f, delta_c)``.

    Raises:
        ValueError: ``controller`` is none of these.
    """
    if controller is None:
        return (lambda t, x: (0.0, 0.0)), 'none'
    if hasattr(controller, 'command'):
        describe = getattr(controller, 'describe', None)
        return controller.command, describe() if describe else type(controller).__name__
    if callable(controller):
        return controller, getattr(controller, '__name__', 'callable')
    raise ValueError(f'controller={controller!r} is neither a Controller nor a callable')


def per_sample_command(controller: Controller
                       ) -> Callable[[float, Sequence[float]], tuple[float, float]]:
    """The controller's clamped :meth:`Controller.command` as a per-sample path calls it (the
    hosted law in the plant, the controller node): for a law that says it is affine
    (:meth:`Controller.affine`, e.g. eq. 31, the LQR) the same u = clamp(K x + u0, limit) as
    one scalar expression of its gains, summed in the order of the compiled kernels' input
    and of eq. 31's ``update`` (about 0.3 us instead of 1 us through ``update``, ``float``
    and ``clamp``); any other controller's own ``command``. Build it again after the
    controller's parameters change.

    The affine form raises :class:`NonFiniteCommand` as ``command`` does.
    """
    law = controller.affine()
    if law is None:
        return controller.command
    name = controller.name or type(controller).__name__
    (a0, a1, a2, a3), (b0, b1, b2, b3) = ([float(v) for v in row] for row in law[0])
    u0, u1 = (float(v) for v in law[1])
    p = controller.params
    lf = float(getattr(p, 'max_fin_deflection', math.inf))
    lc = float(getattr(p, 'max_cavitator_deflection', math.inf))

    def command(t: float, x: Sequence[float]) -> tuple[float, float]:
        z, w, th, q = x
        uf = (a0 * z + a1 * w + a2 * th + a3 * q) + u0
        uc = (b0 * z + b1 * w + b2 * th + b3 * q) + u1
        if uf - uf == 0.0 and uc - uc == 0.0:      # False for NaN and +-inf
            return max(-lf, min(lf, uf)), max(-lc, min(lc, uc))
        raise NonFiniteCommand(
            f'{name}: non-finite output at t={t!r} s: delta_f={uf!r}, delta_c={uc!r} rad from '
            f'[z, w, theta, q] = {[float(v) for v in x]}')

    return command


# -- the plugin registry ----------------------------------------------------------------------
class UnknownController(LookupError):
    """No controller plugin of that name; the message lists the valid ones."""


def _entry_points() -> dict[str, EntryPoint]:
    found: dict[str, EntryPoint] = {}
    for ep in entry_points(group=GROUP):
        found.setdefault(ep.name, ep)   # the first distribution on sys.path wins
    return found


def available() -> list[str]:
    """Names of the registered controllers, sorted."""
    return sorted(_entry_points())


def load(name: str) -> type[Controller]:
    """The controller class registered as ``name``.

    Raises:
        UnknownController: no such name (lists the valid ones) or the plugin is broken (says
            why).
    """
    eps = _entry_points()
    ep = eps.get(name)
    if ep is None:
        raise UnknownController(
            f"unknown controller {name!r}; valid controllers ({GROUP} entry points): "
            f"{', '.join(sorted(eps)) or 'none installed'}")
    try:
        cls = ep.load()
    except Exception as exc:  # a broken plugin: say which and why
        raise UnknownController(f'controller {name!r} ({ep.value}) failed to load: '
                                f'{type(exc).__name__}: {exc}') from exc
    if not (isinstance(cls, type) and issubclass(cls, Controller)):
        raise UnknownController(f'controller {name!r} ({ep.value}) is not a subclass of '
                                'fohssv_sim.control.Controller')
    return cls


def make(name: str, gains: dict[str, Any] | None = None) -> Controller:
    """The controller plugin ``name`` built with the parameter overrides ``gains``.

    Raises:
        UnknownController: no such plugin, or a broken one (the message lists the valid names).
        ParameterError: an unknown parameter name or an invalid value.
    """
    return load(name)(**(gains or {}))
