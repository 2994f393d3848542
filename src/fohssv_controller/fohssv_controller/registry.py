"""Controller plugins: setuptools entry points in the group ``fohssv.controllers``.

A package registers a controller class (a :class:`fohssv_controller.base.Controller`) under a
name in its ``setup.py``::

    entry_points={'fohssv.controllers': ['my_law = my_pkg.my_module:MyController']}

:func:`available` lists the names; :func:`load` returns the class. A plugin that fails to
import, or is not a Controller, is skipped with a warning naming it (ros2cli's rule), so one
broken package cannot hide the others. Pure: no rclpy.
"""

from __future__ import annotations

import logging
from importlib.metadata import EntryPoint, entry_points

from .base import Controller

__all__ = ['GROUP', 'UnknownController', 'available', 'load']

#: The entry-point group of controller plugins.
GROUP = 'fohssv.controllers'

_log = logging.getLogger(__name__)


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
                                'fohssv_controller.base.Controller')
    return cls
