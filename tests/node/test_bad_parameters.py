"""Bad parameters of the plant and the controller node, refused when the node is built in the
test process: the words of each refusal (name, value, allowed range, unit; the close matches
of a misspelt name). That a node's process turns such a refusal into one line and exit 2,
never a traceback, for every node and every kind of refusal (range, type, unknown name,
params files, bad ``--ros-args``), is tests/test_graph_startup.py's."""

from __future__ import annotations

import os

import pytest

from fohssv_sim.control import UnknownController

pytestmark = pytest.mark.node


def _plant_cases(tmp):
    cpu0 = min(os.sched_getaffinity(0))      # the first CPU this process may use
    params_file = tmp / 'params.yaml'        # a file, not a directory
    params_file.write_text('plant:\n  ros__parameters:\n    speed: 80.0\n')
    bag = tmp / 'bag'
    return [
        ({'min_state_subscribers': 1.5},
         'min_state_subscribers=1.5 is not a whole number; allowed: [0, 1000]'),
        ({'mode': 3}, "mode=3 is an integer, not a name; allowed: 'lockstep'"),
        # issue 20: the command lag limit, the hosted controller and its parameters
        ({'max_command_lag': 0.5},
         'max_command_lag=0.5 is outside the allowed range [1, 1e+06] control periods '
         "(realtime mode, external controller: a command's lag"),
        ({'max_command_lag': 'abc'},
         "max_command_lag='abc' is a string, not a number; allowed: [1, 1e+06] control "
         'periods'),
        ({'controller': 3},
         "controller=3 is an integer, not a name; allowed: '' (an external controller node) "
         'or a plugin name of group fohssv.controllers'),
        ({'controller': 'pid'},
         "unknown controller 'pid'; valid controllers (fohssv.controllers entry points): "
         'fractional_pid, lqr, scheduled, state_feedback'),
        ({'controller': 'state_feedback', 'controller.max_cavitator_deflection': 3.0},
         'controller.max_cavitator_deflection=3.0 is outside the allowed range (0, 1.5708] rad'),
        ({'controller': 'lqr', 'controller.depth_weight': 'abc'},
         "controller.depth_weight='abc' is a string, not a number; allowed: [0, 1e+12] 1/m^2"),
        ({'controller': 'state_feedback', 'controller.depth_gian': 3.0},
         "unknown parameter 'controller.depth_gian' (did you mean 'controller.depth_gain'"),
        ({'controller.depth_gain': 1.0}, "unknown parameter 'controller.depth_gain'"),
        # in-plant recording: a bag is never overwritten, and must be creatable
        ({'record': str(tmp)}, f"record='{tmp}' exists already: the plant never overwrites a "
         "bag; allowed: '' (off) or a path that does not exist"),
        ({'record': f'{params_file}/bag'}, f"record='{params_file}/bag' cannot be created: "
         f"{params_file} is not a directory; allowed: '' (off) or a path"),
        ({'record': 3}, "record=3 is an integer, not a name; allowed: '' (off)"),
        ({'record': str(bag), 'record_buffer': 100},
         'record_buffer=100 is outside the allowed range [4096, 1.07374e+09] bytes'),
        # cpu_affinity: CPUs this process may use (none has a CPU 100000)
        ({'cpu_affinity': 100000}, 'cpu_affinity=100000 names CPU 100000, which this process '
         f'may not use (it may use CPU {cpu0}'),
        # cpu_dma_latency: whole microseconds, -1 for no request
        ({'cpu_dma_latency': -5}, 'cpu_dma_latency=-5 is outside the allowed range [-1, 1e+06] '
         'us'),
    ]


def test_bad_plant_parameters_are_refused_naming_them(graph, tmp_path):
    failures = []
    for params, words in _plant_cases(tmp_path):
        try:
            graph.plant(**params)
        except (ValueError, UnknownController) as exc:    # each exits 2 in a process
            if words not in str(exc):
                failures.append(f'{params}: {exc}')
        else:
            failures.append(f'{params}: not refused')
    assert not failures, '\n'.join(failures)
    assert not (tmp_path / 'bag').exists()       # refused before anything was created


def test_bad_controller_parameters_are_refused_naming_them(graph):
    cpu0 = min(os.sched_getaffinity(0))
    cases = [
        ({'max_cavitator_deflection': 3.0},
         'max_cavitator_deflection=3.0 is outside the allowed range (0, 1.5708] rad'),
        ({'depth_gain': 'high'},
         "depth_gain='high' is a string, not a number; allowed: (-inf, inf) rad/m"),
        ({'cpu_affinity': 'first'}, "cpu_affinity='first' is not a CPU number or a list of "
         f'them (this process may use CPU {cpu0}'),
        ({'cpu_affinity': [cpu0, 100000]}, f'cpu_affinity=[{cpu0}, 100000] names CPU 100000,'),
        ({'cpu_dma_latency': 'fast'},
         "cpu_dma_latency='fast' is a string, not a number; allowed: [-1, 1e+06] us"),
        ({'cpu_dma_latency': 5.5}, 'cpu_dma_latency=5.5 is not a whole number'),
        ({'min_command_subscribers': 0},
         'min_command_subscribers=0 is outside the allowed range [1, 1000] (matched '
         'subscriptions of command'),
    ]
    failures = []
    for params, words in cases:
        try:
            graph.controller(**params)
        except ValueError as exc:
            if words not in str(exc):
                failures.append(f'{params}: {exc}')
        else:
            failures.append(f'{params}: not refused')
    assert not failures, '\n'.join(failures)
