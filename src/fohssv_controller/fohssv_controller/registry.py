"""Backwards-compatible names: the controller plugin registry lives in
:mod:`fohssv_sim.control` (the core finds the plugins through entry points)."""

from fohssv_sim.control import GROUP, UnknownController, available, load

__all__ = ['GROUP', 'UnknownController', 'available', 'load']
