"""Issue 12, defects 2, 3 and 4, for every node (plant, controller, recorder, player): a
wrong type, a value out of range, an unknown parameter name (on the command line or in a
params file), a missing or malformed params file and bad ``--ros-args`` each give one line
naming what is wrong and exit code 2, never a traceback. Real processes (the installed
executables); every case fails before any DDS traffic, so they all run at once."""

from __future__ import annotations

import pytest

import rosproc

pytestmark = pytest.mark.graph

NODES = {'plant': ('fohssv_sim', 'plant'), 'controller': ('fohssv_controller', 'state_feedback'),
         'recorder': ('fohssv_sim', 'recorder'), 'player': ('fohssv_sim', 'player'),
         'viewer': ('fohssv_sim', 'viewer')}


def bad_parameter_cases(tmp):
    """(node, arguments after --ros-args, words the one line must hold): each kind of refusal
    of a value once per node, each kind of bad argument once (the words of every other bad
    value of the plant and the controller node, refused as each is built:
    tests/node/test_bad_parameters.py)."""
    misspelt = tmp / 'misspelt.yaml'
    misspelt.write_text('plant:\n  ros__parameters:\n    model: delay-free\n    sped: 80.0\n')
    wildcard = tmp / 'wildcard.yaml'
    wildcard.write_text('/**:\n  ros__parameters:\n    depth_gian: 12.0\n')
    broken = tmp / 'broken.yaml'
    broken.write_text('plant:\n  ros__parameters: [speed: 80\n')
    missing = str(tmp / 'no_such_params.yaml')
    # issue 21, class 4: a section for no node of this name, a key twice, a huge file
    foreign = tmp / 'foreign.yaml'
    foreign.write_text('plnat:\n  ros__parameters:\n    speed: 80.0\n')
    twice = tmp / 'twice.yaml'
    twice.write_text('plant:\n  ros__parameters:\n    speed: 80.0\n    speed: 90.0\n')
    huge = tmp / 'huge.yaml'
    huge.write_text('plant:\n  ros__parameters:\n'
                    + ''.join(f'    k{i}: 1.0\n' for i in range(200_000)))
    many = tmp / 'many.yaml'
    many.write_text('plant:\n  ros__parameters:\n'
                    + ''.join(f'    k{i}: 1\n' for i in range(12_000)))
    bag = str(tmp / 'bag')
    kinds = [(['--params-file', missing], 'invalid arguments: '),
             (['--params-file', str(broken)], 'invalid arguments: '),
             (['-p', 'speed'], 'invalid arguments: '),
             (['--', '--speed', '80'], "unexpected argument(s) '--speed 80': the nodes take "
              'only ROS arguments')]
    return [
        # defect 2: out of range, wrong type; one line with name, value, range and unit
        ('plant', ['-p', 'fractional_order:=1.5'],
         'fractional_order=1.5 is outside the allowed range (0, 1] (commensurate Caputo'),
        ('plant', ['-p', 'speed:=abc'],
         "speed='abc' is a string, not a number; allowed: (0, inf) m/s (forward speed)"),
        # outside the descriptor's range too: checked against the table before rclpy declares
        # it; the line names what it is
        ('plant', ['-p', 'clock_period:=2.0'],
         'invalid parameters: clock_period=2.0 is outside the allowed range [0, 1] s '
         '(realtime mode'),
        # issue 20: a hosted controller that is not there (not a ValueError in the node)
        ('plant', ['-p', 'controller:=pid'],
         "unknown controller 'pid'; valid controllers (fohssv.controllers entry points): "
         'fractional_pid, lqr, scheduled, state_feedback'),
        ('controller', ['-p', 'max_cavitator_deflection:=3.0'],
         'max_cavitator_deflection=3.0 is outside the allowed range (0, 1.5708] rad'),
        ('recorder', ['-p', 'flush_period:=abc', '-p', f'bag_path:={bag}'],
         "flush_period='abc' is a string, not a number; allowed: (0, 60] s (wall time"),
        ('recorder', ['-p', 'flush_period:=0.0', '-p', f'bag_path:={bag}'],
         'flush_period=0.0 is outside the allowed range (0, 60] s'),
        ('player', ['-p', f'bag_path:={bag}', '-p', 'rate:=fast'],
         "rate='fast' is a string, not a number; allowed: [0, inf) (republish:"),
        ('player', ['-p', f'bag_path:={bag}', '-p', 'rate:=-1.0'],
         'rate=-1.0 is outside the allowed range [0, inf)'),
        ('viewer', ['-p', 'port:=70000'],
         'port=70000 is outside the allowed range [0, 65535] (TCP port of the Foxglove'),
        ('viewer', ['-p', 'port:=http'],
         "port='http' is a string, not a number; allowed: [0, 65535] (TCP port"),
        ('viewer', ['-p', 'rate:=0.0'],
         'rate=0.0 is outside the allowed range (0, 1000] Hz (most views forwarded'),
        ('viewer', ['-p', 'host:=my host'],
         "host='my host' is not an IP address or host name; allowed: an IP address or host "
         'name (address the Foxglove'),
        # defect 3: unknown names, with the close matches
        ('plant', ['-p', 'sped:=80.0'], "unknown parameter 'sped' (did you mean 'speed'?)"),
        ('plant', ['--params-file', str(misspelt)],
         "unknown parameter 'sped' (did you mean 'speed'?)"),
        ('controller', ['--params-file', str(wildcard)],
         "unknown parameter 'depth_gian' (did you mean 'depth_gain'"),
        ('controller', ['-p', 'pich_gain:=1.0', '-p', 'depth_gian:=2.0'],
         "unknown parameters 'depth_gian' (did you mean 'depth_gain' or 'pitch_gain'?), "
         "'pich_gain' (did you mean 'pitch_gain'"),
        ('recorder', ['-p', 'flush_periode:=0.2', '-p', f'bag_path:={bag}'],
         "unknown parameter 'flush_periode' (did you mean 'flush_period'?)"),
        ('player', ['-p', f'bag_path:={bag}', '-p', 'rat:=0.0'],
         "unknown parameter 'rat' (did you mean 'rate'?)"),
        ('plant', ['--params-file', str(foreign)],
         f"params file {foreign} sets nothing for node '/plant': its sections are 'plnat' "
         "(did you mean 'plant' for 'plnat'?)"),
        ('controller', ['--params-file', str(foreign)],
         "sets nothing for node '/controller': its sections are 'plnat'"),
        ('plant', ['--params-file', str(twice)],
         f"params file {twice} gives 'speed' twice (line 4;"),
        ('plant', ['--params-file', str(huge)],
         f'params file {huge} is {huge.stat().st_size} bytes, more than the 1048576'),
        ('recorder', ['--params-file', str(many)],
         f'params file {many} has more than 10000 keys'),
        ('viewer', ['-p', 'prot:=9000'], "unknown parameter 'prot' (did you mean 'port'?)"),
        # defect 4: a missing or malformed params file, bad --ros-args, and an argument outside
        # --ros-args (after '--' here: rcl ignores it, the node refuses). One code path for
        # every node (nodekit.run_node's init): each kind at least once, each node once
        *[(node, *kinds[i % len(kinds)]) for i, node in enumerate(NODES)],
    ]


def test_bad_parameters_and_arguments_give_one_line_and_exit_2(tmp_path):
    cases = bad_parameter_cases(tmp_path)
    env = rosproc.ros_env()
    failures = []
    for start in range(0, len(cases), 10):        # ten at a time: 30 processes importing
        batch = cases[start:start + 10]            # rclpy and numba at once swamp 2 cores
        procs = [rosproc.start(*NODES[node], ['--ros-args', *args], env=env)
                 for node, args, _ in batch]
        failures += _check(batch, procs)
    assert not failures, '\n\n'.join(failures)
    assert not (tmp_path / 'bag').exists()     # the recorder refused before creating it


def _check(cases, procs) -> list[str]:
    failures = []
    for (node, args, words), proc in zip(cases, procs, strict=True):
        try:
            code = rosproc.wait_exit(proc, 60)
        except AssertionError as exc:     # which case hung, and what it said (killed by now)
            failures.append(f'{node} {args}: {exc}, output:\n{rosproc.output(proc)}')
            continue
        # ten processes starting at once in one domain may race for a Fast DDS shared-memory
        # port: the loser logs one line and takes the next port (rosproc.FASTDDS_PORT_RACE)
        out = rosproc.without_port_race(rosproc.output(proc))
        lines = [ln for ln in out.splitlines() if ln.strip()]
        if not (code == 2 and len(lines) == 1 and words in lines[0]
                and 'Traceback' not in out and f'[{node}]' in lines[0]):
            failures.append(f'{node} {args}: exit {code}, output:\n{out}')
    return failures


@pytest.mark.parametrize('node', ['player'])
def test_standard_rclpy_parameters_stay_allowed(tmp_path, node):
    """use_sim_time is rclpy's own parameter: not refused as unknown (the player then fails
    on the missing bag, exit 1)."""
    proc = rosproc.start(*NODES[node], ['--ros-args', '-p', 'use_sim_time:=true', '-p',
                                        f'bag_path:={tmp_path / "none"}'], env=rosproc.ros_env())
    code = rosproc.wait_exit(proc, 60)
    out = rosproc.output(proc)
    assert code == 1 and 'no such file or directory' in out and 'unknown' not in out, out


def test_a_node_that_does_not_exit_in_time_fails_saying_where_its_threads_are():
    """``rosproc.wait_exit`` on a node that never ends by itself (a plant with no controller
    waits for one as long as it takes): the failure carries the Python stacks (faulthandler,
    on SIGABRT) and, where gdb is installed, each thread's native frames, which show the lock
    or wait a node stuck inside rclpy or Fast DDS is in (the Python dump stops at the call)."""
    proc = rosproc.start('fohssv_sim', 'plant', ['--ros-args', '-p', 'duration:=1.0'],
                         env=rosproc.ros_env())
    # the node is up (its first line: what it runs, and that it waits for a controller)
    # before the deadline starts: its stacks are the wait's
    first = proc.stdout.readline()
    assert 'controller external' in first, first
    with pytest.raises(AssertionError) as failure:
        rosproc.wait_exit(proc, 1)
    text = str(failure.value)
    assert proc.poll() is not None
    assert 'did not exit within 1 s (stopped with SIGABRT' in text, text
    assert 'Fatal Python error: Aborted' in text and 'plant_node.py' in text, text
    if _gdb_may_attach():
        native = text.split('its threads in native code (gdb):\n', 1)[1]
        threads = [ln for ln in native.splitlines() if ln.startswith('Thread ')]
        assert len(threads) > 5 and '#0 ' in native, native     # rclpy's and Fast DDS's too
    else:       # no gdb, or ptrace refused: the failure says nothing of native code
        assert 'native code (gdb)' not in text, text


def _gdb_may_attach() -> bool:
    """Whether gdb is installed and may attach to a child of this process here (ptrace
    permitted)."""
    import subprocess

    child = subprocess.Popen(['sleep', '30'])
    try:
        return bool(rosproc.native_stacks(child.pid))
    finally:
        child.kill()
        child.wait()
