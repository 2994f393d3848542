"""The launch file, `make demo` and the README's graph walkthrough start the same closed loop,
and it ends on its own with a complete bag.

`launch` is not on PyPI, so the launch file cannot run here: it is compiled, and its structure
read with `ast` (its nodes come from fohssv_sim.closed_loop, the list scripts/demo.py starts;
its arguments are closed_loop()'s with the same defaults; the plant's exit shuts everything
down). The list itself is run for real: the three installed executables with exactly those
parameters (a shorter duration), over DDS, to a complete bag whose plant parameters are the
list's, and whose controller and recorder report the list's parameters as declared. The
README walkthrough is run as written (only its bag path is moved to a temporary folder, and its
run cut to 0.1 s).
"""

from __future__ import annotations

import ast
import importlib.util
import inspect
import os
import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rclpy.parameter import parameter_value_to_python
from test_graph_support import Probe, batch_samples

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim import closed_loop as cl
from fohssv_sim.bag import load_run
from fohssv_sim.bag.check import check
from fohssv_sim.ros.viewer_options import VIEWER_PARAMETERS

import rosproc

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / 'src' / 'fohssv_sim' / 'launch' / 'closed_loop.launch.py'
README = (ROOT / 'README.md').read_text()


def _demo():
    spec = importlib.util.spec_from_file_location('fohssv_demo', ROOT / 'scripts' / 'demo.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _calls(tree: ast.AST, name: str) -> list[ast.Call]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and (
        getattr(n.func, 'id', None) == name or getattr(n.func, 'attr', None) == name)]


def test_launch_file_starts_the_shared_node_list_and_stops_with_the_plant():
    text = LAUNCH.read_text()
    tree = ast.parse(compile(text, str(LAUNCH), 'exec', ast.PyCF_ONLY_AST))
    imports = {(n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
               for a in n.names}
    assert ('fohssv_sim.closed_loop', 'closed_loop') in imports
    # one Node per spec of closed_loop(), every field taken from the spec
    (node,) = _calls(tree, 'Node')
    kw = {k.arg: k.value for k in node.keywords}
    for field in ('package', 'executable', 'name'):
        assert isinstance(kw[field], ast.Attribute) and kw[field].attr == field
    assert ast.unparse(kw['parameters']) == '[s.parameters]'
    (call,) = _calls(tree, 'closed_loop')
    # the launch arguments are closed_loop()'s keyword arguments, with its defaults
    assign = next(n for n in tree.body if isinstance(n, ast.Assign)
                  and getattr(n.targets[0], 'id', None) == 'ARGUMENTS')
    arguments = eval(compile(ast.Expression(assign.value), str(LAUNCH), 'eval'),  # noqa: S307
                     {'DEFAULT_CONTROLLER': cl.DEFAULT_CONTROLLER,
                      'DEFAULT_DURATION': cl.DEFAULT_DURATION, 'str': str, 'float': float,
                      'flag': cl.flag})
    signature = inspect.signature(cl.closed_loop).parameters
    for name, (default, kind, _) in arguments.items():
        assert kind(default) == kind(signature[name].default), name
    assert set(arguments) == {'controller', 'duration', 'bag_path', 'hosted', 'recorder'}
    assert len(_calls(tree, 'DeclareLaunchArgument')) == 1   # in a loop over ARGUMENTS
    # every node's exit goes through the shared exit rule: one handler per node, in the loop
    # over the nodes; the plant's exit 0 shuts the launch down, a non-zero exit raises
    (handler,) = _calls(tree, 'OnProcessExit')
    hk = {k.arg: k.value for k in handler.keywords}
    assert ast.unparse(hk['target_action']) == 'node'
    assert ast.unparse(hk['on_exit']) == '_on_exit(spec.name, node is plant, last)'
    loop = next(n for n in ast.walk(tree) if isinstance(n, ast.For)
                and ast.unparse(n.iter) == 'zip(specs, nodes)')
    assert handler in list(ast.walk(loop))
    plant = next(n for n in ast.walk(tree) if isinstance(n, ast.Assign)
                 and getattr(n.targets[0], 'id', None) == 'plant')
    assert ast.unparse(plant.value) == 'nodes[0]'
    assert cl.closed_loop()[0].executable == 'plant'
    assert _calls(tree, 'RegisterEventHandler')
    on_exit = next(n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)
                   and n.name == 'on_exit')
    body = ast.unparse(on_exit)
    assert 'exit_verdict(name, event.returncode, is_plant' in body
    assert 'raise NodeFailed(verdict.message)' in body     # launch then returns 1
    assert 'Shutdown(' in body
    assert ('fohssv_sim.closed_loop', 'exit_verdict') in imports


@pytest.mark.parametrize('name,code,plant,failed,ends', [
    ('plant', 0, True, False, True), ('controller', 0, False, False, False),
    ('recorder', 0, False, False, False), ('controller', 2, False, True, True),
    ('recorder', 2, False, True, True), ('recorder', 6, False, True, True),
    ('plant', 3, True, True, True), ('plant', -9, True, True, True)])
def test_exit_rule(name, code, plant, failed, ends):
    v = cl.exit_verdict(name, code, plant, f'{name}: error: the reason')
    assert (v.failed, v.ends_run) == (failed, ends)
    if failed:
        assert v.message == f'{name} exited with code {code}: {name}: error: the reason'


def test_launch_file_starts_the_viewer_on_request():
    """viewer:=true (default false) adds the Foxglove viewer to the node list, on
    viewer_port at viewer_rate (the viewer's own defaults)."""
    text = LAUNCH.read_text()
    tree = ast.parse(text)
    optional = next(n for n in tree.body if isinstance(n, ast.Assign)
                    and getattr(n.targets[0], 'id', None) == 'OPTIONAL_ARGUMENTS')
    optional = eval(compile(ast.Expression(optional.value), str(LAUNCH), 'eval'),  # noqa: S307
                    {'flag': cl.flag, 'DEFAULT_VIEWER_PORT': cl.DEFAULT_VIEWER_PORT,
                     'str': str, 'int': int, 'float': float})
    assert set(optional) == {'viewer', 'viewer_port', 'viewer_rate'}
    assert optional['viewer'][0] == 'false'
    defaults = {s.name: s.default for s in VIEWER_PARAMETERS}
    assert optional['viewer_port'][1](optional['viewer_port'][0]) == defaults['port']
    assert optional['viewer_rate'][1](optional['viewer_rate'][0]) == defaults['rate']
    assert "if _value(context, 'viewer', OPTIONAL_ARGUMENTS):" in text
    assert ("viewer(_value(context, 'viewer_port', OPTIONAL_ARGUMENTS),\n"
            in text.replace('                                             ', ''))
    assert cl.viewer(9000, 12.5).parameters == {'port': 9000, 'rate': 12.5}
    plant, *rest = cl.watched(cl.closed_loop())     # ... and the plant waits for its readers
    assert plant.parameters['min_view_subscribers'] == 1
    assert tuple(rest) == cl.closed_loop()[1:]


def test_demo_starts_the_launch_files_list_with_its_defaults(tmp_path):
    """The launch file's default run is the demo's: the plant recording its own run and the
    controller node (the demo asks for cpu_dma_latency 0 besides)."""
    demo = _demo()
    args = demo.parser().parse_args(['--pin', 'off', '--cpu-dma-latency', '-1'])
    bag = tmp_path / 'bag'
    plant, ctl = demo.specs(args, bag)
    launched = cl.closed_loop(bag_path=str(bag), plant={'cpu_dma_latency': -1})
    assert (plant, ctl) == launched
    assert demo.specs(demo.parser().parse_args(['--pin', 'off']), bag)[0].parameters[
        'cpu_dma_latency'] == 0
    assert plant.parameters['record'] == str(bag)
    assert plant.parameters['min_state_subscribers'] == 1
    assert 'pace_to_subscribers' not in plant.parameters
    assert plant.parameters['duration'] == 2.0 and plant.parameters['model'] == 'fractional'
    assert ctl.parameters == {'controller': 'state_feedback', 'min_command_subscribers': 1}
    # the recorder node on request, as the launch's recorder:=node
    plant_n, ctl_n, rec = demo.specs(demo.parser().parse_args(
        ['--pin', 'off', '--recorder', 'node', '--cpu-dma-latency', '-1']), bag)
    assert (plant_n, ctl_n, rec) == cl.closed_loop(bag_path=str(bag), recorder='node',
                                                   plant={'cpu_dma_latency': -1})
    assert {'min_state_subscribers:=2', 'pace_to_subscribers:=512',
            'cpu_dma_latency:=-1'} <= set(demo.command(plant_n))
    assert ctl_n.parameters == {'controller': 'state_feedback', 'min_command_subscribers': 2}
    # by default (--pin auto) the same list with the plant and the controller pinned apart
    usable = sorted(os.sched_getaffinity(0))
    pinned = demo.specs(demo.parser().parse_args(['--cpu-dma-latency', '-1']), bag)
    if len(usable) >= 2:
        assert pinned == (replace(plant, parameters={**plant.parameters,
                                                     'cpu_affinity': usable[0]}),
                          replace(ctl, parameters={**ctl.parameters, 'cpu_affinity': usable[1]}))
    else:
        assert pinned == (plant, ctl)
    assert rec.parameters == {'bag_path': str(bag), 'command_publishers': 1}
    # hosted: the plant alone, recording
    (hosted,) = cl.closed_loop(bag_path=str(bag), hosted=True)
    assert hosted.parameters['controller'] == 'state_feedback'
    assert hosted.parameters['record'] == str(bag)
    # no bag_path: runs/<UTC time>, as the recorder node's default
    assert Path(cl.closed_loop()[0].parameters['record']).parent.name == 'runs'
    for spec in (plant, ctl, rec):
        assert Path(demo.command(spec)[0]) == rosproc.executable(spec.package, spec.executable)
    # --viewer [PORT]: the launch file's viewer, on that port (the option is off by default)
    assert args.viewer is None and demo.parser().parse_args(['--viewer']).viewer == 8765
    view = cl.viewer(demo.parser().parse_args(['--viewer', '9000']).viewer)
    assert view == cl.viewer(9000) and demo.command(view)[-2:] == ['-p', 'port:=9000']
    assert Path(demo.command(view)[0]) == rosproc.executable('fohssv_sim', 'viewer')
    assert set(view.parameters) <= {s.name for s in VIEWER_PARAMETERS}


def _parameters(probe: Probe, node: str, names: list[str]) -> dict:
    from rcl_interfaces.srv import GetParameters

    client = probe.node.create_client(GetParameters, f'/{node}/get_parameters')
    rosproc.wait_for(client.service_is_ready, 10, what=f'/{node}/get_parameters')
    values = probe.result(client.call_async(GetParameters.Request(names=names))).values
    return {n: parameter_value_to_python(v) for n, v in zip(names, values)}


@pytest.mark.graph
def test_the_node_list_runs_to_a_complete_bag_with_its_parameters(tmp_path):
    """The demo's three nodes as the list gives them (duration 0.05 s instead of 2): the
    bag holds every sample, command and view; the plant's recorded parameters, the
    controller's and the recorder's are the list's (an undeclared name would be ignored by
    rclpy and show here as missing)."""
    bag = tmp_path / 'run'
    specs = cl.closed_loop(duration=0.05, bag_path=str(bag), recorder='node')
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    rec, ctl = (rosproc.start(s.package, s.executable, cl.ros_args(s), env=env,
                              log=tmp_path / f'{s.name}.log') for s in reversed(specs[1:]))
    plant = probe = None
    try:
        # the controller's and recorder's parameters while they wait for the plant (the
        # recorder ends by itself with the run)
        probe = Probe(domain, command_publisher=False)
        for spec in specs[1:]:
            got = _parameters(probe, spec.name, list(spec.parameters))
            assert got == spec.parameters, (spec.name, got)
        probe.close()
        probe = None
        plant = rosproc.start(specs[0].package, specs[0].executable, cl.ros_args(specs[0]),
                              env=env, log=tmp_path / f'{specs[0].name}.log')
        assert rosproc.wait_exit(plant, 120) == 0, (tmp_path / 'plant.log').read_text()
        assert rosproc.wait_exit(rec, 60) == 0, (tmp_path / 'recorder.log').read_text()
    finally:
        if probe is not None:
            probe.close()
        rosproc.stop(ctl)
        assert rosproc.stop(rec) == 0, (tmp_path / 'recorder.log').read_text()
    run = load_run(bag)
    assert check(bag).ok and not run.truncated
    recorded = {k: run.parameters[k] for k in specs[0].parameters}
    assert recorded == specs[0].parameters
    # every sample and every command (the answer to the last sample may be recorded too)
    assert len(run.t) == 501 and np.array_equal(run.command_t[:500], run.t[:500])
    assert run.topics['/pose'] == run.topics['/twist'] == 6     # t = 0, 0.01, ..., 0.05


@pytest.mark.graph
def test_the_hosted_node_list_runs_to_a_complete_bag(tmp_path):
    """The hosted variant (``hosted:=true``, ``--hosted``): the plant hosting eq. 31 and the
    recorder, no controller node. The bag is complete by the recorder's run_end check: every
    sample, and one command per sample but the last (t = the answered sample), equal to the
    batch runner's trajectory."""
    bag = tmp_path / 'run'
    specs = cl.closed_loop(duration=0.05, bag_path=str(bag), hosted=True, recorder='node')
    assert [s.executable for s in specs] == ['plant', 'recorder']
    assert specs[0].parameters['controller'] == 'state_feedback'
    env = rosproc.ros_env()
    rec = rosproc.start(specs[1].package, specs[1].executable, cl.ros_args(specs[1]), env=env,
                        log=tmp_path / 'recorder.log')
    plant = rosproc.start(specs[0].package, specs[0].executable, cl.ros_args(specs[0]),
                          env=env, log=tmp_path / 'plant.log')
    try:
        assert rosproc.wait_exit(plant, 120) == 0, (tmp_path / 'plant.log').read_text()
        assert rosproc.wait_exit(rec, 60) == 0, (tmp_path / 'recorder.log').read_text()
    finally:
        rosproc.stop(plant)
        rosproc.stop(rec)
    run = load_run(bag)
    assert check(bag).ok and not run.truncated
    assert len(run.t) == 501 and run.topics['/command'] == 500
    assert np.array_equal(run.command_t, run.t[:500])
    ref, _ = batch_samples('fractional', StateFeedback(), 0.05, fractional_order=0.85,
                           speed=75.0)
    assert np.max(np.abs(run.state - ref[:, 1:])) <= 1e-12


def _walkthrough() -> str:
    block = re.search(r'<!-- tests/test_launch.py runs this block -->\n```bash\n(.*?)```',
                      README, re.S)
    assert block, 'README: no bash block marked for tests/test_launch.py'
    return block.group(1)


@pytest.mark.graph
def test_readme_walkthrough_ends_on_its_own_with_a_complete_bag(tmp_path):
    script = _walkthrough()
    for needed in ('command_publishers:=1', 'min_state_subscribers:=2',
                   'min_command_subscribers:=2', 'runs/mine'):
        assert needed in script, needed
    assert re.search(r'duration:=[\d.]+ ', script)
    # the run cut to 0.1 s of simulated time (what is tested does not depend on its length)
    duration = 0.1
    script = re.sub(r'duration:=[\d.]+ ', f'duration:={duration} ', script)
    script = script.replace('runs/mine', str(tmp_path / 'mine'))
    out = subprocess.run(['bash', '-c', script], cwd=ROOT, env=rosproc.ros_env(),
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    run = load_run(tmp_path / 'mine')
    assert check(tmp_path / 'mine').ok and not run.truncated
    n = round(duration / 1e-4)
    assert len(run.t) == n + 1                                  # every sample
    assert np.array_equal(run.command_t[:n], run.t[:n])         # and every command
    assert run.parameters['model'] == 'fractional'
    ref, _ = batch_samples('fractional', StateFeedback(), duration)
    assert np.max(np.abs(run.state - ref[:, 1:])) <= 1e-12
    assert run.topics['/pose'] == round(duration / 0.01) + 1
    assert list((tmp_path / 'mine-plots').glob('*.png')), out.stdout


@pytest.mark.graph
@pytest.mark.parametrize('args,node,words', [
    (['--controller', 'nope'], 'controller', "'nope'"),
    (['--alpha', '5'], 'plant', 'fractional_order=5.0')])
def test_demo_ends_when_a_node_fails_at_start(tmp_path, args, node, words):
    """The exit rule as a process: scripts/demo.py with a node that exits 2 at start ends by
    itself (no waiting for a node that never comes), with that node's line and its exit
    code, and leaves no empty bag behind."""
    bag = tmp_path / 'runs' / 'demo'
    domain = rosproc.unique_domain_id()
    out = subprocess.run([sys.executable, str(ROOT / 'scripts' / 'demo.py'), *args,
                          '--duration', '0.05', '--bag', str(bag), '--timeout', '120'],
                         cwd=tmp_path, env=rosproc.ros_env(domain), capture_output=True,
                         text=True, timeout=180)
    assert out.returncode == 2, out.stdout + out.stderr
    assert f'ROS_DOMAIN_ID={domain}' in out.stdout           # the exported domain is honoured
    line = next(x for x in out.stderr.splitlines() if x.startswith('demo: ') and 'exited' in x)
    assert line.startswith(f'demo: {node} exited with code 2: ') and words in line, line
    assert 'Traceback' not in out.stdout + out.stderr
    # in-plant recording: the plant's writer creates the bag only for a run that starts (or
    # the demo removes the empty one it left)
    assert not bag.exists()
    assert list((tmp_path / 'runs').iterdir()) == []


def test_the_reason_line_is_the_last_error_else_the_last_line():
    assert cl.reason_line(['[INFO] a', '[ERROR] [plant]: 2 publishers of /state ...',
                           '[INFO] [plant]: summary: {...}', '']) == (
        '[ERROR] [plant]: 2 publishers of /state ...')
    assert cl.reason_line(['x', 'recorder: error: 3 message(s) lost', 'closed x']) == (
        'recorder: error: 3 message(s) lost')
    assert cl.reason_line(['started', 'stopping cleanly  ', '']) == 'stopping cleanly'
    assert cl.reason_line([]) == ''


@pytest.mark.graph
@pytest.mark.parametrize('executable', [('fohssv_sim', 'plant'), ('fohssv_controller',
                                                                  'controller')])
def test_a_signal_while_a_node_still_imports_ends_it_quietly(tmp_path, executable):
    """What a launch shutting down at start does to a node that is still importing rclpy and
    numba (the other node failed first): SIGINT ends it with exit 0 and no traceback."""
    import signal

    proc = rosproc.start(*executable, ['--ros-args', '-p', 'duration:=0.01']
                         if executable[1] == 'plant' else [], env=rosproc.ros_env(),
                         fork=False)     # the imports are what this is about
    maps = Path(f'/proc/{proc.pid}/maps')
    # rclpy's extension is loaded by the node's module, which the entry point imports: the
    # imports are under way (numba, the node's modules) when it appears
    rosproc.wait_for(lambda: '_rclpy_pybind11' in maps.read_text(), 60, interval=0.005,
                     what='rclpy being imported')
    proc.send_signal(signal.SIGINT)
    code = rosproc.wait_exit(proc, 30)
    out = rosproc.output(proc)
    assert code == 0 and 'Traceback' not in out and 'KeyboardInterrupt' not in out, out


def test_the_loop_is_pinned_to_the_first_two_usable_cpus_and_nothing_else_is():
    assert cl.loop_cpus([0, 1]) == (0, 1)
    assert cl.loop_cpus({7, 2, 5}) == (2, 5)
    assert cl.loop_cpus([3]) is None and cl.loop_cpus([]) is None
    plant, ctl, rec = cl.closed_loop(recorder='node')
    assert cl.pinned((plant, ctl, rec), None) == (plant, ctl, rec)
    got = cl.pinned(cl.watched((plant, ctl, rec)) + (cl.viewer(),), (2, 5))
    assert [s.parameters.get('cpu_affinity') for s in got] == [2, 5, None, None]
    assert got[1].parameters == {**ctl.parameters, 'cpu_affinity': 5}
    # a hosted plant has no controller node to keep apart from: left alone
    hosted = cl.closed_loop(hosted=True, recorder='node')
    assert cl.pinned(hosted, (0, 1)) == hosted


def test_demo_domain_honours_ros_domain_id_then_its_own_variable():
    demo = _demo()
    assert demo.demo_domain({'ROS_DOMAIN_ID': '115', 'FOHSSV_DEMO_DOMAIN': '7'}) == 115
    assert demo.demo_domain({'ROS_DOMAIN_ID': ' ', 'FOHSSV_DEMO_DOMAIN': '7'}) == 7
    assert 1 <= demo.demo_domain({}) <= 200
    with pytest.raises(ValueError, match="ROS_DOMAIN_ID='abc' is not a ROS domain"):
        demo.demo_domain({'ROS_DOMAIN_ID': 'abc'})


def test_demo_domains_stay_in_the_range_a_user_gives():
    demo = _demo()
    assert demo.domain_range({}) == (1, 200)
    assert demo.domain_range({'FOHSSV_DOMAIN_RANGE': ' 120-139 '}) == (120, 139)
    assert 120 <= demo.demo_domain({'FOHSSV_DOMAIN_RANGE': '120-139'}) <= 139
    assert demo.demo_domain({'FOHSSV_DOMAIN_RANGE': '77-77'}) == 77
    for bad in ('139-120', '5', 'a-b', '0-233'):
        with pytest.raises(ValueError, match=f"FOHSSV_DOMAIN_RANGE='{bad}' is not a range"):
            demo.demo_domain({'FOHSSV_DOMAIN_RANGE': bad})
    assert 'FOHSSV_DOMAIN_RANGE=LO-HI' in demo.parser().format_help()


def test_the_plants_end_names_no_node_that_may_not_be_there():
    """A hosted launch has no controller node (and by default no recorder node): the line
    that ends the run names none."""
    message = cl.exit_verdict('plant', 0, True).message
    assert 'controller' not in message and 'recorder' not in message
