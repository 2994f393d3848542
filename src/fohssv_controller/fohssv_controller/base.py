"""Backwards-compatible names: the controller contract lives in :mod:`fohssv_sim.control`
(the core), so that the core never imports this package."""

from fohssv_sim.control import (
    DEFLECTION_LIMIT,
    Controller,
    NonFiniteCommand,
    ParameterError,
    clamp,
    deflection_limit,
)

__all__ = ['Controller', 'ParameterError', 'NonFiniteCommand', 'clamp', 'DEFLECTION_LIMIT',
           'deflection_limit']
