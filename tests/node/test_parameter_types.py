"""Issue 51.11: a parameter of the wrong type is refused in the project's words, at start and
on set: one line naming the parameter, the value, what it is and what the row allows, never
rclpy's "Wrong parameter type, expected '3' got '4'" (its enum numbers: 3 is double, 4 is
string). The descriptor keeps the row's type after a refused change, and a change of the right
type is still taken. In-process nodes (the plant and the controller node)."""

from __future__ import annotations

import pytest
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter

from fohssv_sim.params import ParameterError

pytestmark = pytest.mark.node

# (row, a value of the wrong type, the row's ROS type, words the refusal must hold); the
# plant's rows a run may change are doubles and a double array (the others are read-only)
WRONG = [
    ('watchdog_timeout', 'long', ParameterType.PARAMETER_DOUBLE,
     "watchdog_timeout='long' is a string, not a number"),
    ('max_command_lag', True, ParameterType.PARAMETER_DOUBLE, 'max_command_lag=True is a bool'),
    ('initial_state', 'rest', ParameterType.PARAMETER_DOUBLE_ARRAY,
     "initial_state='rest' is a string, not a list of numbers"),
]


def _rclpy_words(reason: str) -> bool:
    return 'Wrong parameter type' in reason or "expected '" in reason


@pytest.mark.parametrize(('name', 'value', 'kind', 'words'), WRONG,
                         ids=[f'{w[0]}-{type(w[1]).__name__}' for w in WRONG])
def test_a_change_of_the_wrong_type_is_refused_in_one_line(graph, name, value, kind, words):
    plant = graph.plant(model='delay-free', duration=0.01)
    before = plant.get_parameter(name).value
    result, = plant.set_parameters([Parameter(name, value=value)])
    assert not result.successful
    assert words in result.reason, result.reason
    assert 'allowed:' in result.reason and '\n' not in result.reason, result.reason
    assert not _rclpy_words(result.reason), result.reason
    assert plant.describe_parameter(name).type == kind        # not the refused value's type
    assert plant.get_parameter(name).value == before


def test_a_change_of_the_right_type_is_taken_after_a_refused_one(graph):
    plant = graph.plant(model='delay-free', duration=0.01)
    assert not plant.set_parameters([Parameter('watchdog_timeout', value='long')])[0].successful
    assert plant.set_parameters([Parameter('watchdog_timeout', value=0.5)])[0].successful
    assert plant.set_parameters([Parameter('watchdog_timeout', value=2)])[0].successful  # -> 2.0
    assert plant.get_parameter('watchdog_timeout').value == 2.0
    assert plant.describe_parameter('watchdog_timeout').type == ParameterType.PARAMETER_DOUBLE


@pytest.mark.parametrize(('name', 'value', 'words'), [
    ('pace_to_subscribers', 'yes', "pace_to_subscribers='yes' is a string, not a number"),
    ('min_view_subscribers', 1.5, 'min_view_subscribers=1.5 is not a whole number'),
    ('controller', 3.0, 'controller=3.0 is a double, not a name'),
    ('max_command_lag', 'far', "max_command_lag='far' is a string, not a number"),
    ('initial_state', True, 'initial_state=True is a bool, not a list of numbers'),
])
def test_a_wrong_type_at_start_is_refused_in_one_line(graph, name, value, words):
    with pytest.raises(ParameterError) as err:
        graph.plant(model='delay-free', duration=0.01, **{name: value})
    text = str(err.value)
    assert words in text and 'allowed:' in text, text
    assert not _rclpy_words(text), text


def test_the_controller_node_refuses_a_gain_of_the_wrong_type(graph):
    node = graph.controller()
    gains = [n for n in node.list_parameters([], 0).names
             if node.describe_parameter(n).type == ParameterType.PARAMETER_DOUBLE]
    assert gains
    result, = node.set_parameters([Parameter(gains[0], value='high')])
    assert not result.successful
    assert f"{gains[0]}='high' is a string, not a number" in result.reason, result.reason
    assert not _rclpy_words(result.reason), result.reason
    assert node.describe_parameter(gains[0]).type == ParameterType.PARAMETER_DOUBLE
