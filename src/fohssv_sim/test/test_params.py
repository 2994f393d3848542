"""Parameter validation: every invalid value names the parameter, value, range and unit."""

import math

import pytest

from fohssv_sim.params import PARAMETERS, ModelParameters, ParameterError


@pytest.mark.parametrize(('name', 'value', 'expect'), [
    ('fractional_order', 0.0, ['fractional_order=0.0', '(0, 1]']),
    ('fractional_order', 1.2, ['fractional_order=1.2', '(0, 1]']),
    ('speed', -75.0, ['speed=-75.0', '(0, inf)', 'm/s']),
    ('speed', math.inf, ['speed=inf', 'm/s']),
    ('length', 0.0, ['length=0.0', 'm']),
    ('body_radius', -0.05, ['body_radius=-0.05', 'm']),
    ('cavitator_radius', math.nan, ['cavitator_radius=nan', 'm']),
    ('cavitation_number', 0.0, ['cavitation_number=0.0', '(0, 0.64)']),
    ('tanh_sharpness', -1.0, ['tanh_sharpness=-1.0', 's/m']),
    ('step', 0.0, ['step=0.0', "'auto'", 's']),
    ('step', -1e-5, ['step=-1e-05', 's']),
    ('density_ratio', 'heavy', ["density_ratio='heavy'", '(0, inf)']),
    ('planing_offset', -2.8, ['planing_offset=-2.8', "'consistent'", 'm/s']),
    ('advection_delay', -0.01, ['advection_delay=-0.01', 's']),
    ('soe_tolerance', 0.1, ['soe_tolerance=0.1']),
])
def test_invalid_value_names_parameter_range_and_unit(name, value, expect):
    with pytest.raises(ParameterError) as err:
        ModelParameters(**{name: value})
    for text in expect:
        assert text in str(err.value)


@pytest.mark.parametrize(('name', 'value', 'choices'), [
    ('model', 'chaotic', ["'fractional'", "'delay-free'", "'delayed'"]),
    ('immersion_form', 'literal', ["'paper'", "'geometric'"]),
    ('planing_form', 'sharp', ["'smooth'", "'exact'"]),
    ('solver', 'euler', ["'abm'", "'soe'", "'rk4'"]),
])
def test_unknown_option_lists_valid_ones(name, value, choices):
    with pytest.raises(ParameterError) as err:
        ModelParameters(**{name: value})
    for c in choices:
        assert c in str(err.value)


def test_solver_must_fit_model():
    with pytest.raises(ParameterError, match="solver='rk4' does not fit model='fractional'"):
        ModelParameters(model='fractional', solver='rk4')
    with pytest.raises(ParameterError, match="'abm' does not fit model='delayed'"):
        ModelParameters(model='delayed', solver='abm')


def test_delayed_model_rejects_smooth_planing_and_sub_step_delay():
    with pytest.raises(ParameterError, match='planing_form'):
        ModelParameters(model='delayed', planing_form='smooth')
    with pytest.raises(ParameterError, match='advection_delay=5e-06 s is shorter than step'):
        ModelParameters(model='delayed', advection_delay=5e-6)


def test_geometry_that_breaks_the_cavity_is_rejected():
    with pytest.raises(ParameterError, match='length=0.5 m is shorter than the cavity-closure'):
        ModelParameters(length=0.5)
    with pytest.raises(ParameterError, match='body_radius=0.1 m does not fit in the cavity'):
        ModelParameters(body_radius=0.1)


def test_unknown_names_are_rejected_with_the_valid_list():
    with pytest.raises(ParameterError, match='unknown parameter.*sped.*valid names: model'):
        ModelParameters.from_dict({'sped': 80.0})
    with pytest.raises(ParameterError, match='unknown parameter'):
        ModelParameters().replace(alpha=0.9)
    with pytest.raises(ParameterError, match="preset='nope'.*'paper-literal'"):
        ModelParameters.preset('nope')


def test_defaults_are_table_a1_with_the_spec_resolutions():
    p = ModelParameters()
    assert (p.speed, p.length, p.body_radius, p.cavitator_radius) == (75.0, 1.8, 0.0508, 0.0191)
    assert (p.density_ratio, p.fin_effectiveness, p.cavitation_number) == (2.0, 0.5, 0.03)
    assert (p.cavitator_drag_coefficient, p.gravity, p.tanh_sharpness) == (0.82, 9.81, 300.0)
    assert p.model == 'fractional' and p.solver == 'soe' and p.planing_form == 'smooth'
    assert p.delay == pytest.approx(0.024)   # L / V at 75 m/s (docs/model.md §6)
    assert ModelParameters(model='delay-free').planing_form == 'exact'


def test_paper_literal_preset_and_numeric_options():
    p = ModelParameters.preset('paper-literal')
    assert p.length == 1.18 and p.planing_offset == 2.8 and p.delay == 0.02069
    q = ModelParameters(model='delayed', advection_delay=0.03, step='auto')
    assert q.delay == 0.03 and q.step == 1e-5
    # strings from YAML / ROS are accepted for numeric parameters
    assert ModelParameters(speed='84.5').speed == 84.5


def test_replace_revalidates_and_reresolves_auto_values():
    p = ModelParameters()
    q = p.replace(model='delay-free')
    assert q.solver == 'rk4' and q.planing_form == 'exact' and q.step == 1e-5
    with pytest.raises(ParameterError, match='speed=0'):
        p.replace(speed=0)
    assert p.speed == 75.0   # unchanged


def test_every_parameter_has_unit_description_and_valid_default():
    for spec in PARAMETERS:
        assert spec.unit and spec.description
        spec.validate(spec.default)
