"""The typed views' pure parts: when a view is due (view_period against control_period) and
the cavity the marker draws (eqs. 12-14 at the Table A1 values). The views themselves are
checked against the samples in a recorded bag by tests/test_record_plot.py."""

from __future__ import annotations

import math

import pytest

from fohssv_sim.coefficients import coefficients
from fohssv_sim.params import ModelParameters, ParameterError
from fohssv_sim.ros.options import PlantOptions, view_samples
from fohssv_sim.ros.views import cavity_size


@pytest.mark.parametrize(('view', 'control', 'every'), [
    (0.01, 1e-4, 100), (0.0, 1e-4, 0), (1e-4, 1e-4, 1), (0.01, 0.5, 1), (0.003, 1e-3, 3)])
def test_views_every_whole_number_of_samples(view, control, every):
    assert view_samples(PlantOptions(view_period=view, control_period=control)) == every


def test_a_view_period_between_two_samples_is_refused_with_its_range():
    with pytest.raises(ParameterError, match=r'view_period=0\.0025 s is not 0, at most '
                       r'control_period or a whole multiple'):
        view_samples(PlantOptions(view_period=0.0025, control_period=1e-3))


def test_cavity_size_is_eqs_12_14_at_table_a1():
    p = ModelParameters()
    length, radius = cavity_size(p)
    assert length == pytest.approx(2 * 0.0191 * (1.92 / 0.03 - 3))          # 2.3302 m
    assert radius == pytest.approx(0.0191 * math.sqrt(0.82 * 1.03 / 0.03))  # 0.1013 m
    # the cavity holds the body, and its radius at the transom is the model's Rc
    c = coefficients(p)
    assert length > p.length and radius > c.Rc > p.body_radius
