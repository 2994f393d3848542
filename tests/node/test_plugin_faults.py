"""Plugins with a bug in the test process: a constructor that raises refuses the node with
one reason (no traceback: the exit 2 is the process test's, tests/test_graph_plugin_faults.py),
a reset() that raises is refused by the plant's ``reset`` service (success false, the reason)
and logged by the controller node, and both nodes stay alive."""

from __future__ import annotations

import pytest
from faulty_plugins import register
from std_srvs.srv import Trigger

from fohssv_controller.ros.controller_node import ControllerNode
from fohssv_sim.ros.nodekit import PluginFailed

pytestmark = pytest.mark.node

DURATION = 0.01
N = round(DURATION / 1e-4) + 1


@pytest.fixture
def faulty(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(register(tmp_path)))


def test_a_constructor_that_raises_refuses_the_plant_with_its_reason(graph, faulty):
    with pytest.raises(PluginFailed, match="controller 'bad_init' could not be built: its "
                       'constructor raised RuntimeError: no gains file'):
        graph.plant(controller='bad_init')


def test_a_reset_that_raises_is_refused_and_the_plant_runs_on(graph, faulty, capfd):
    probe = graph.probe()
    plant = graph.plant(controller='bad_reset', duration=DURATION)
    response = plant._on_reset(Trigger.Request(), Trigger.Response())  # the service's callback
    assert not response.success
    assert response.message == ('bad_reset.reset() raised RuntimeError: memory stuck; '
                                'the plant was not reset')
    assert graph.run(plant) == 0
    graph.wait(lambda: len(probe.states) >= N, 20, 'every sample at the probe')
    assert plant.resets == 0
    assert 'reset refused: bad_reset.reset() raised RuntimeError' in capfd.readouterr().err


def test_a_reset_that_raises_leaves_the_controller_node_answering(graph, faulty, capfd):
    import faulty_laws

    probe = graph.probe()
    graph.add(ControllerNode(faulty_laws.BadReset, context=graph.context))
    graph.wait(lambda: probe.node.count_subscribers('state') > 0
               and probe.node.count_publishers('command') > 0, 20, 'the controller')
    for t in (0.0, 0.1, 0.05, 0.2):               # 0.05: time went back, the law resets
        probe.publish_state([t, 0.01, 0.0, 0.0, 0.0])
    graph.wait(lambda: any(c[0] == 0.2 for c in probe.commands), 20, 'the answer at t=0.2')
    assert {c[0] for c in probe.commands} == {0.0, 0.1, 0.05, 0.2}
    assert ('state time went back to t=0.05 s: bad_reset.reset() raised RuntimeError: memory '
            'stuck; answering without a reset') in capfd.readouterr().err


@pytest.mark.parametrize(('law', 'raised'), [('quits', 'SystemExit: 3'),
                                             ('interrupts', 'KeyboardInterrupt: ')])
def test_a_law_that_exits_or_interrupts_is_a_failing_law_call(graph, faulty, capfd, law,
                                                               raised):
    """sys.exit() or KeyboardInterrupt from a hosted law's call neither ends the plant nor
    passes for a signal: counted and held as any exception from the law; the run completes."""
    probe = graph.probe()
    plant = graph.plant(controller=law, duration=DURATION)
    assert graph.run(plant) == 0
    graph.wait(lambda: len(probe.states) >= N, 20, 'every sample at the probe')
    # commands for t = 0 .. 0.0049 (50 samples), none from t = 0.005 on (the last sample
    # gets no command at all)
    assert plant.law_failures == N - 1 - 50
    assert f'{law}.command(t=0.005) raised {raised}' in capfd.readouterr().err


def test_a_law_that_exits_is_a_failing_law_call_in_the_controller_node(graph, faulty, capfd):
    import faulty_laws

    probe = graph.probe()
    ctl = graph.add(ControllerNode(faulty_laws.Quits, context=graph.context))
    graph.wait(lambda: probe.node.count_subscribers('state') > 0
               and probe.node.count_publishers('command') > 0, 20, 'the controller')
    for t in (0.0, 0.01, 0.001):                  # 0.01: sys.exit(3) in the law
        probe.publish_state([t, 0.01, 0.0, 0.0, 0.0])
    graph.wait(lambda: any(c[0] == 0.001 for c in probe.commands), 20, 'the answer at 0.001')
    assert {c[0] for c in probe.commands} == {0.0, 0.001} and ctl.raised == 1
    assert 'quits.command(t=0.01) raised SystemExit: 3; no command sent' in capfd.readouterr().err
