"""A run recorded by the real recorder (a process) from the plant and controller nodes (built in
the test process), over DDS: the bag holds the batch runner's trajectory sample for sample,
and `fohssv plot` on it summarises what an independent in-process run gives. The same bag
holds the typed views (pose, twist, planing_wrench, vehicle_marker) every view_period, equal
to the state and Fp samples at the same t to rounding, and every topic and field the
Foxglove layout (docs/foxglove/fohssv_layout.json) names."""

from __future__ import annotations

import json
import math
import re
import signal
from pathlib import Path

import numpy as np
import pytest
from inprocess import Graph
from test_graph_support import bag_messages, batch_samples, stamp_ns, stop_all

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim import contract
from fohssv_sim.bag import load_run
from fohssv_sim.bag.check import check

import rosproc

pytestmark = pytest.mark.graph

DURATION = 0.3
ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / 'docs' / 'foxglove' / 'fohssv_layout.json'


def _assert_views_equal_the_samples(run, msgs: dict[str, list]) -> None:
    """pose, twist, planing_wrench every 100th sample (view_period 0.01 s at 1e-4 s), equal
    to state and Fp at the same t: exact negations, theta from the quaternion to rounding."""
    row = {round(t * 1e9): i for i, t in enumerate(run.t)}
    due = [round(t * 1e9) for t in run.t[::100]]          # t = 0, 0.01, ..., 0.3
    assert len(due) == 31
    for name in ('/pose', '/twist', '/planing_wrench'):
        assert [stamp_ns(m.header.stamp) for m in msgs[name]] == due, name
    for m in msgs['/pose']:
        z, w, theta, q = run.state[row[stamp_ns(m.header.stamp)]]
        assert m.header.frame_id == contract.VIEW_WORLD_FRAME
        p, o = m.pose.position, m.pose.orientation
        assert (p.x, p.y, p.z) == (0.0, 0.0, -z)
        assert o.x == o.z == 0.0 and abs(o.y ** 2 + o.w ** 2 - 1.0) <= 1e-15
        assert abs(-2.0 * math.atan2(o.y, o.w) - theta) <= 1e-15 + 1e-12 * abs(theta)
    for m in msgs['/twist']:
        z, w, theta, q = run.state[row[stamp_ns(m.header.stamp)]]
        assert m.header.frame_id == contract.VIEW_BODY_FRAME
        lin, ang = m.twist.linear, m.twist.angular
        assert (lin.x, lin.y, lin.z) == (75.0, 0.0, -w)
        assert (ang.x, ang.y, ang.z) == (0.0, -q, 0.0)
    fp_at = {round(t * 1e9): f for t, f in zip(run.planing_force_t, run.planing_force)}
    for m in msgs['/planing_wrench']:
        assert m.header.frame_id == contract.VIEW_BODY_FRAME
        f, tq = m.wrench.force, m.wrench.torque
        assert (f.x, f.y, f.z) == (0.0, 0.0, -fp_at[stamp_ns(m.header.stamp)])
        assert (tq.x, tq.y, tq.z) == (0.0, 0.0, 0.0)
    assert any(m.wrench.force.z != 0.0 for m in msgs['/planing_wrench'])   # it planes
    markers = msgs['/vehicle_marker']
    assert [m.id for m in markers] == [0, 1] * 31
    assert [stamp_ns(m.header.stamp) for m in markers[::2]] == due
    for body, pose in zip(markers[::2], msgs['/pose']):
        assert body.pose.orientation == pose.pose.orientation
        assert body.scale.x == 1.8 and body.scale.y == body.scale.z == 2 * 0.0508
        assert body.header.frame_id == contract.VIEW_WORLD_FRAME


def _field(msg, path: list):
    for part in path:
        msg = msg[part] if isinstance(part, int) else getattr(msg, part)
    return msg


def _assert_layout_names_what_the_bag_has(msgs: dict[str, list]) -> None:
    """Every topic the layout's 3D panel shows and every message path its plots draw exists
    in the bag, and the path resolves to a number in a recorded message."""
    layout = json.loads(LAYOUT.read_text())
    topics, paths = set(), []
    for panel_id, config in layout['configById'].items():
        topics |= set(config.get('topics', {}))
        paths += [p['value'] for p in config.get('paths', [])]
        if 'xAxisPath' in config:
            paths.append(config['xAxisPath']['value'])
        if panel_id.startswith('3D!'):
            assert config['followTf'] == contract.VIEW_WORLD_FRAME
    assert {'/pose', '/vehicle_marker'} <= topics and '/state.data[2]' in paths
    # panels are named by foxglovePanelTitle (Plot's own `title` is deprecated in PlotConfig);
    # the depth-and-pitch panel plots both
    plots = {k: c for k, c in layout['configById'].items() if k.startswith('Plot!')}
    for panel_id, config in plots.items():
        assert 'title' not in config and config['foxglovePanelTitle'], panel_id
    (depth,) = [c for c in plots.values() if 'depth' in c['foxglovePanelTitle']]
    assert 'pitch' in depth['foxglovePanelTitle']
    assert {p['value'] for p in depth['paths'] if p['enabled']} == {
        '/pose.pose.position.z', '/state.data[3]'}      # -z (up) and theta (nose up)
    panels = re.findall(r'"((?:Plot|3D)![\w]+)"', json.dumps(layout['layout']))
    assert sorted(panels) == sorted(layout['configById'])   # every panel is placed
    for topic in topics:
        assert msgs.get(topic), f'the layout shows {topic}, which the bag lacks'
    for path in paths:
        m = re.fullmatch(r'(/[\w/]+?)((?:\.\w+|\[\d+\])+)', path)
        assert m, path
        topic = m.group(1)
        assert msgs.get(topic), f'the layout plots {path}: {topic} is not in the bag'
        parts = [int(x[1:-1]) if x.startswith('[') else x[1:]
                 for x in re.findall(r'\.\w+|\[\d+\]', m.group(2))]
        value = _field(msgs[topic][-1], parts)
        assert isinstance(value, float), (path, value)


def test_recorded_closed_loop_equals_batch_run_and_plots(tmp_path, capfd):
    """The recorder is the process under test; the plant and eq. 31's node, whose runs over
    DDS between processes are other tests' (test_graph_lockstep, test_launch), are built in
    the test process."""
    graph = Graph()
    bag = tmp_path / 'run'
    log = tmp_path / 'recorder.log'
    rec = rosproc.start_recorder(rosproc.ros_env(graph.domain), log, f'bag_path:={bag}',
                                 'command_publishers:=1')
    try:
        graph.controller(min_command_subscribers=2)
        plant = graph.plant(model='delay-free', mode='lockstep', duration=DURATION,
                            min_state_subscribers=2, pace_to_subscribers=512)
        assert graph.run(plant, 120) == 0
        # the nodes spin on as the plant's process does after its run (it lingers, answering
        # the recorder's request for its parameters, which under load may come after the
        # run's end): the recorder's last flush period, the signal, and its exit
        graph.spin_for(0.5)
        rec.send_signal(signal.SIGINT)
        graph.wait(lambda: rec.poll() is not None, 30, 'the recorder to exit')
        assert rec.returncode == 0, log.read_text()
    finally:
        stop_all(rec)
        graph.close()

    ref, fref = batch_samples('delay-free', StateFeedback(), DURATION)
    run = load_run(bag)
    assert not run.truncated
    assert np.array_equal(run.t, ref[:, 0])                    # exact simulation times
    assert np.max(np.abs(run.state - ref[:, 1:])) <= 1e-12      # sample for sample
    assert np.array_equal(run.planing_force_t, fref[:, 0])
    assert np.array_equal(run.command_t[:len(ref) - 1], ref[:-1, 0])   # every command
    assert np.array_equal(run.log_time['state'], np.round(ref[:, 0] * 1e9).astype(np.int64))
    assert run.parameters.get('model') == 'delay-free', log.read_text()
    assert run.parameters['control_period'] == 1e-4
    assert check(bag).ok
    msgs = bag_messages(bag)
    _assert_views_equal_the_samples(run, msgs)
    _assert_layout_names_what_the_bag_has(msgs)

    # `fohssv plot` in-process (cli.main: the parser and command the installed script calls;
    # test_cli_plot runs the script itself)
    from fohssv_sim.cli import main

    capfd.readouterr()
    code = main(['plot', str(bag), '--out', str(tmp_path / 'fig')])
    assert code == 0, capfd.readouterr().err
    s = json.loads((tmp_path / 'fig' / 'run_summary.json').read_text())[str(bag)]
    half = ref[:, 0] >= DURATION / 2
    assert s['samples'] == len(ref)
    assert abs(s['w_peak_to_peak'] - np.ptp(ref[half, 2])) <= 1e-12
    assert abs(s['peak_abs_planing_force'] - np.abs(fref[:, 1]).max()) <= 1e-9
    assert (tmp_path / 'fig' / 'run_time.png').stat().st_size > 10_000
