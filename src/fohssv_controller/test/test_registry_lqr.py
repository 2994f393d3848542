"""Pure tests of the controller plugins (no ROS): the registry and the LQR design."""

from __future__ import annotations

import numpy as np
import pytest

from fohssv_controller.lqr import LQR, LQRParameters, design
from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim import control as registry
from fohssv_sim.equilibria import find_equilibria
from fohssv_sim.params import ModelParameters, ParameterError
from fohssv_sim.simulate import simulate


def test_builtins_are_registered():
    assert {'state_feedback', 'lqr'} <= set(registry.available())
    assert registry.load('lqr') is LQR
    assert registry.load('state_feedback') is StateFeedback


def test_unknown_name_lists_the_valid_ones():
    with pytest.raises(registry.UnknownController, match=r"unknown controller 'pid'; valid "
                       r'controllers \(fohssv.controllers entry points\): .*lqr, scheduled, '
                       r'state_feedback'):
        registry.load('pid')


def test_lqr_operating_point_is_the_eq31_equilibrium_and_the_loop_is_stable():
    d = design(LQRParameters())
    eq = find_equilibria(ModelParameters(model='delay-free', planing_form='smooth'),
                         StateFeedback())[0]
    np.testing.assert_allclose(d.state, eq.state, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(d.inputs, eq.inputs, rtol=1e-9, atol=1e-12)
    assert np.all(d.closed_loop_eigenvalues.real < 0)
    # at the operating point the law returns the trim input
    assert LQR().update(0.0, d.state) == pytest.approx(tuple(d.inputs), abs=1e-15)


def test_lqr_regulates_the_delay_free_plant_to_the_operating_point():
    d = design(LQRParameters())
    r = simulate(ModelParameters(model='delay-free'), LQR(), 0.5, control_period=1e-4,
                 sample_every=100)
    np.testing.assert_allclose(r.state[-1], d.state, atol=1e-4)


def test_lqr_rejects_bad_weights():
    with pytest.raises(ParameterError, match='cavitator_weight=-1'):
        LQR(cavitator_weight=-1.0)
