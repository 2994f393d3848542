"""Fault-and-bad-input suite (issue 12): bad inputs and faults against the installed nodes and
the ``fohssv`` CLI, as real processes over real DDS with real bags in a temporary folder.

Categories (each case on a ROS_DOMAIN_ID of its own, from ``tests/rosproc.py``):

* parameters: every node (plant, the controllers, recorder, player) with a value out of range,
  a wrong type, an unknown (misspelt) name, a missing or malformed ``--params-file``, bad
  ``--ros-args`` (the catalogue of ``tests/test_graph_startup.py`` and a few more): exit 2
  with one line naming what is wrong;
* commands: non-finite, out-of-range, wrong-length and wrong-time commands to a lockstep
  plant, commands from the future and stale ones to a real-time plant (an in-process probe
  is the controller): each rejected and logged, the plant finishes its run (exit 0); bad
  states to a controller node (the probe is the plant): dropped, the good ones answered;
* bags: ``fohssv check|plot|repair`` and the player on a missing path, a file that is not a
  bag, a folder without one, a truncated MCAP, invalid or wrong-shaped ``metadata.yaml``, a
  file path escaping the bag folder, ``--out`` an existing file: the documented exit code,
  one line, nothing in the folder modified;
* faults: a second plant on the domain (exit 5), a recorder killed mid-run (the bag is
  readable after ``fohssv repair``), a controller killed mid-lockstep (the plant ends with
  exit 3 naming it), SIGINT to each node during a run (exit 0, no traceback);
* reliability (issue 21): the graph tests of each class it fixed, run as cases: 40 bad states
  and 40 withheld (non-finite) commands to a controller (alive; 20 lines, then one a
  second), a plugin that raises, a hosted law failing every sample, a realtime ``/reset``
  (the summary counts the whole run), one recorder
  for two namespaced vehicles, two publishers of one topic (both run_ends: exit 0; one:
  exit 7, unchecked),
  publishers gone without run_end (exit 7), SIGINT to a recorded lockstep plant (bag, run_end
  and summary agree), recorder and player started together, a full filesystem (one line,
  exit 1, the bag repairs; needs root), a plant's UDP sockets on loopback only, state
  publishes DDS refuses (injected, ``FOHSSV_FAULT_REFUSE_STATE``; external and hosted
  controller: exit 9, one line, the bag and run_end agree);
* loss: a lockstep closed loop recorded with the demo's settings, and a rate-0 ``player``
  replay into a recorder, each also with two busy processes (``yes > /dev/null``) on the
  machine. After the plant (player) has finished, the recorder gets ``STOP_GRACE`` s to stop
  by itself at the run's ``run_end`` (exit 0; 6 names a shortfall), then SIGINT; the bag's
  messages are counted against what was published (the plant's summary, the source bag):
  messages lost.

A case's outcome is classified automatically: *handled* (the exit code the node's or the
CLI's docstring documents, taken from their ``EXIT_*`` constants; one clear line; no
traceback), *survived* (the node kept running or finished as documented), *lost N*. Prints a
table per category and every failing case (command and output), writes the JSON to
``--out``; exits 1 if a case failed or a message was lost. About 3 min (``--quick``: 21
cases, under 1 min).

    python bench/bench_faults.py [--out bench/results/faults.json] [--quick] [--jobs 4]
                                 [--only CATEGORY,...] [--match TEXT]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tests'))

from test_graph_startup import NODES, bad_parameter_cases  # noqa: E402

sys.path.insert(0, str(ROOT / 'src' / 'fohssv_sim' / 'test'))
from test_cli_bad_input import catalogue as cli_catalogue  # noqa: E402
from test_graph_support import Probe, plant_args  # noqa: E402

from fohssv_sim.bag import BagError, load_run  # noqa: E402
from fohssv_sim.bag.synthetic import edit_metadata, write_bag  # noqa: E402
from fohssv_sim.cli import common as cli_codes  # noqa: E402
from fohssv_sim.closed_loop import closed_loop, ros_args  # noqa: E402
from fohssv_sim.ros import plant_node, player_node  # noqa: E402
from fohssv_sim.ros.startup import EXIT_BAD_PARAMETERS  # noqa: E402

import rosproc  # noqa: E402

#: Words that must never appear in a node's or the CLI's output.
CRASH = ('Traceback', 'Exception in', '[FATAL]', 'Segmentation fault')
#: Wall seconds the recorder gets after the run to stop by itself before SIGINT.
STOP_GRACE = 15.0
ALONE = {'min_state_subscribers': 0, 'min_command_publishers': 0}
#: A real-time closed loop that stays in bounds on a busy machine: at 0.1 x real time a
#: command 10 ms late in wall time is 1 ms late in simulated time (at 1 x the delay-free
#: loop left |w| <= V within a second when cases ran side by side; open loop it stays in
#: for 0.25 s of simulated time, 2.5 s of wall time).
REALTIME = {'model': 'delay-free', 'mode': 'realtime', 'control_period': 1e-3,
            'real_time_factor': 0.1}
CATEGORIES = ('parameters', 'commands', 'bags', 'faults', 'loss', 'reliability')
#: Probe nodes live in this process: one at a time.
_PROBE_LOCK = threading.Lock()


@dataclass
class Outcome:
    """What a case did: ``kind`` handled | survived | lost; ``ok`` whether as expected."""

    kind: str
    ok: bool
    detail: str = ''
    lost: int = 0
    output: str = ''


@dataclass
class Case:
    category: str
    name: str
    run: Callable[[Path], Outcome]
    quick: bool = False
    loaded: bool = False          # runs with two busy processes on the machine
    result: dict = field(default_factory=dict)


# -- helpers -------------------------------------------------------------------------------

class Procs:
    """Processes of one case, output to log files in the case's folder; all stopped at the
    end (SIGINT, then SIGKILL) by :meth:`close`."""

    def __init__(self, tmp: Path, domain: int | None = None) -> None:
        self.tmp = tmp
        self.domain = domain if domain is not None else rosproc.unique_domain_id()
        self.env = rosproc.ros_env(self.domain)
        self.procs: list[tuple[str, subprocess.Popen, Path]] = []

    def start(self, label: str, package: str, exe: str, args: list[str]) -> subprocess.Popen:
        log = self.tmp / f'{label}.log'
        proc = rosproc.start(package, exe, args, env=self.env, log=log)
        self.procs.append((label, proc, log))
        return proc

    def log(self, label: str) -> str:
        for name, _, log in self.procs:
            if name == label:
                return log.read_text(errors='replace')
        return ''

    def wait_line(self, label: str, words: str, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if words in self.log(label):
                return True
            time.sleep(0.05)
        return False

    def outputs(self) -> str:
        return '\n'.join(f'--- {name} (exit {p.returncode}): {shlex.join(map(str, p.args))}\n'
                         f'{log.read_text(errors="replace")[-3000:]}'
                         for name, p, log in self.procs)

    def close(self) -> None:
        for _, proc, _ in self.procs:
            rosproc.stop(proc, timeout=10)


def wait(proc: subprocess.Popen, timeout: float) -> int | None:
    """The exit code, or None (and the process killed) after ``timeout``."""
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=10)
        return None


def lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def crashed(text: str) -> str | None:
    return next((w for w in CRASH if w in text), None)


def handled(code: int | None, text: str, expect: int, words: str = '',
            nlines: int | None = 1) -> Outcome:
    """The *handled* verdict: exit ``expect``, ``nlines`` non-empty lines (None: any), the
    last error line holding ``words``, no traceback."""
    out = lines(text)
    bad = crashed(text)
    if code is None:
        why = 'did not exit (killed)'
    elif code != expect:
        why = f'exit {code}, expected {expect}'
    elif bad:
        why = f'{bad!r} in the output'
    elif nlines is not None and len(out) != nlines:
        why = f'{len(out)} lines of output, expected {nlines}'
    elif words and not any(words in ln for ln in out):
        why = f'no line holds {words!r}'
    else:
        return Outcome('handled', True, out[-1][:200] if out else '')
    return Outcome('handled', False, why, output=text)


def summary(text: str) -> dict:
    found = [ln for ln in text.splitlines() if 'summary: {' in ln]
    return json.loads(found[-1].split('summary: ', 1)[1]) if found else {}


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every file and folder below ``root`` with its bytes (None for a folder)."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob('*')) if not p.name.endswith('.log')}


def cli(args: list[str], tmp: Path) -> tuple[int | None, str]:
    """``fohssv ARGS`` (the installed CLI), stdout and stderr together."""
    proc = subprocess.Popen([str(rosproc.executable('fohssv_sim', 'fohssv')), *args], cwd=tmp,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        return None, out
    return proc.returncode, out


def params(**values) -> list[str]:
    """``-p k:=v`` for each value (after a ``--ros-args``)."""
    return plant_args(**values)[1:]


# -- parameters ----------------------------------------------------------------------------

#: More than the start-up test's catalogue: the other controller executables, the generic
#: one with an unknown law, a bag_path that exists, a missing bag_path, a stray argument.
EXTRA_NODES = {'lqr': ('fohssv_controller', 'lqr'),
               'fractional_pid': ('fohssv_controller', 'fractional_pid'),
               'generic controller': ('fohssv_controller', 'controller')}


def parameter_cases(tmp: Path) -> list[Case]:
    tmp.mkdir(parents=True, exist_ok=True)
    (tmp / 'existing_bag').mkdir(exist_ok=True)
    catalogue = [(node, ['--ros-args', *args], words)
                 for node, args, words in bad_parameter_cases(tmp)]
    catalogue += [
        ('lqr', ['--ros-args', '-p', 'max_cavitator_deflection:=3.0'],
         'max_cavitator_deflection=3.0 is outside the allowed range'),
        ('fractional_pid', ['--ros-args', '-p', 'derivative_order:=abc'], 'derivative_order'),
        ('fractional_pid', ['--ros-args', '-p', 'depth_kpp:=1.0'],
         "unknown parameter 'depth_kpp'"),
        ('generic controller', ['--ros-args', '-p', 'controller:=nope'],
         "unknown controller 'nope'"),
        ('recorder', ['--ros-args', '-p', f'bag_path:={tmp / "existing_bag"}'],
         'exists already'),
        ('recorder', ['--ros-args', '-p', 'topics:=[speed]'], "'speed' is not a contract topic"),
        ('player', [], 'bag_path is required'),
        ('player', ['--ros-args', '-p', f'bag_path:={tmp}', '-p', 'mode:=rewind'], 'mode'),
        ('plant', ['--ros-args', '--remap'], 'invalid arguments'),
        ('plant', ['--speed', '80', '--ros-args', '-p', 'start_timeout:=3.0'], '--speed'),
    ]
    quick_nodes: set[str] = set()
    cases = []
    for i, (node, args, words) in enumerate(catalogue):
        package, exe = {**NODES, **EXTRA_NODES}[node]
        first = node not in quick_nodes
        quick_nodes.add(node)
        cases.append(Case('parameters', f'{node} {" ".join(args)}',
                          _parameter_run(package, exe, args, words, i), quick=first))
    return cases


def cli_parameter_cases(tmp: Path) -> list[Case]:
    """The CLI's start-up catalogue (src/fohssv_sim/test/test_cli_bad_input.py): every bad
    option of every subcommand, through the installed ``fohssv`` (one line, exit 2; 1 for
    a missing bag). The first row of each subcommand is in --quick."""
    tmp.mkdir(parents=True, exist_ok=True)
    seen: set[str] = set()
    cases = []
    for argv, code, words in cli_catalogue(tmp):
        command = argv[0] if argv else ''
        cases.append(Case('parameters', f'fohssv {" ".join(argv)}'[:160],
                          _cli_run(argv, code, words), quick=command not in seen))
        seen.add(command)
    return cases


def _cli_run(argv: list[str], code: int, words: str) -> Callable[[Path], Outcome]:
    def run(tmp: Path) -> Outcome:
        got, out = cli(argv, tmp)
        result = handled(got, out, code, words)
        if result.ok and (tmp / 'reports').exists():
            return Outcome('handled', False, 'reports/ written for a refused command',
                           output=out)
        return result
    return run


def _parameter_run(package, exe, args, words, i) -> Callable[[Path], Outcome]:
    def run(tmp: Path) -> Outcome:
        procs = Procs(tmp)
        try:
            proc = procs.start(f'node{i}', package, exe, args)
            code = wait(proc, 30)
            return handled(code, procs.log(f'node{i}'), EXIT_BAD_PARAMETERS, words)
        finally:
            procs.close()
    return run


# -- commands to a running plant -----------------------------------------------------------

def _command_case(plant: dict, answer_for: Callable, expect: dict) -> Callable[[Path], Outcome]:
    """A plant run whose controller is a probe answering with ``answer_for(probe)(t, x)``;
    the plant must finish (exit 0, summary t = duration) with the counts in ``expect``. In
    real time a starved probe (a loaded machine) may instead make the plant stop with the
    command-lag exit 6 and its line, as documented, before the late commands lose the
    vehicle: that is handled too; a divergence (exit 1) is a failure."""
    def run(tmp: Path) -> Outcome:
        with _PROBE_LOCK:
            procs = Procs(tmp)
            probe = Probe(procs.domain)
            probe.answer = answer_for(probe)
            try:
                proc = procs.start('plant', 'fohssv_sim', 'plant', plant_args(**plant))
                code = wait(proc, 60)
            finally:
                procs.close()
                probe.close()
        out = procs.log('plant')
        s = summary(out)
        got = {k: s.get(k) for k in expect}
        if (plant.get('mode') == 'realtime' and code == plant_node.EXIT_COMMAND_LAG
                and 'command lag: ' in out and not crashed(out)):
            return Outcome('handled', True, f"exit {code} (the probe was starved: command lag) "
                           f"at t={s.get('t')} s, {got}")
        ok = (code == 0 and not crashed(out) and got == expect
              and math.isclose(s.get('t', -1), plant['duration'], rel_tol=1e-9))
        return Outcome('survived', ok, f"exit {code}, ran to t={s.get('t')} s, {got}",
                       output='' if ok else out)
    return run


def _bad_states_to_a_controller(tmp: Path) -> Outcome:
    """A probe plays the plant for the eq. 31 controller node: good states, then a NaN, an
    infinite and a wrong-length one (dropped and logged), a good one, one whose time goes
    back (a reset: answered), a good one. The controller answers exactly the good ones and
    stops cleanly on SIGINT."""
    nan, inf = math.nan, math.inf
    states = [(0.0, 0, 0, 0, 0), (1e-4, nan, 0, 0, 0), (1e-4, 0, inf, 0, 0), (1e-4, 1.0, 2.0),
              (2e-4, 0, 0.1, 0, 0), (1e-4, 0, 0, 0, 0), (3e-4, 0, 0.1, 0.01, 0)]
    good = [0.0, 2e-4, 1e-4, 3e-4]
    with _PROBE_LOCK:
        procs = Procs(tmp)
        probe = Probe(procs.domain, command_publisher=False)
        try:
            ctl = procs.start('controller', 'fohssv_controller', 'state_feedback', [])
            for data in states:         # state is transient-local: kept for a late reader
                probe.publish_state(data)
            deadline = time.monotonic() + 30
            while len(probe.commands) < len(good) and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(0.3)             # nothing more may come
            running = ctl.poll() is None
            code = rosproc.stop(ctl)
        finally:
            procs.close()
            probe.close()
    out = procs.log('controller')
    got = [c[0] for c in probe.commands]
    ok = (running and code == 0 and got == good and not crashed(out)
          and out.count('dropped a state message') == 3)
    return Outcome('survived', ok, f'answered t={got}, {out.count("dropped a state")} '
                   f'dropped, exit {code}', output='' if ok else out)


def command_cases() -> list[Case]:
    T = 1e-4

    def lockstep(bad: dict):
        def answer_for(probe):
            def answer(t, x):
                k = round(t / T)
                return bad[k](t, probe) if k in bad else [t, 0.0, 0.0]
            return answer
        return answer_for

    def wrong_time(t, probe):
        probe.publish([t + 1.0, 0.0, 0.0])    # ignored: not the time the plant waits for
        return [t, 0.0, 0.0]

    def realtime(bad: dict):
        from fohssv_controller.state_feedback import StateFeedback
        law = StateFeedback()

        def answer_for(probe):
            def answer(t, x):
                k = round(t / 1e-3)
                return [bad[k](t) if k in bad else t, *law.command(t, x)]
            return answer
        return answer_for

    ls = {'model': 'delay-free', 'duration': 0.02, **ALONE}
    # max_command_lag 5 periods (5 ms of simulated time): a starved probe stops the run
    # (exit 6) before its late answers lose the vehicle (at the default 20 they did, exit 1)
    rt = {**REALTIME, 'duration': 0.3, 'max_command_age': 0.5, 'max_command_lag': 5}
    return [
        Case('commands', 'lockstep: NaN, +inf and -inf deflections', _command_case(
            ls, lockstep({3: lambda t, p: [t, math.nan, 0.0], 4: lambda t, p: [t, 0.0, math.inf],
                          5: lambda t, p: [t, -math.inf, 0.0]}),
            {'rejected_commands': 3}), quick=True),
        Case('commands', 'lockstep: out of range (0.9 rad, -2 rad) and wrong length (2, 4)',
             _command_case(ls, lockstep({3: lambda t, p: [t, 0.0, 0.9],
                                         4: lambda t, p: [t, -2.0, 0.0],
                                         5: lambda t, p: [t, 0.0],
                                         6: lambda t, p: [t, 0.0, 0.0, 0.0]}),
                           {'rejected_commands': 4})),
        Case('commands', 'lockstep: a command for the wrong time', _command_case(
            ls, lockstep({3: wrong_time, 4: wrong_time}), {'ignored_commands': 2})),
        Case('commands', 'realtime: future, stale and t=-1e300 commands', _command_case(
            rt, realtime({3: lambda t: t + 1.0, 4: lambda t: t - 1.0, 5: lambda t: -1e300}),
            {'stale_commands': 3, 'rejected_commands': 3}), quick=True),
        Case('commands', 'controller: NaN, infinite, wrong-length states, time going back',
             _bad_states_to_a_controller),
    ]


# -- bad bags ------------------------------------------------------------------------------

def _bad_bag(kind: str, root: Path) -> Path:
    """Make the bad input ``kind`` under ``root``; returns the path given to the command."""
    if kind == 'missing path':
        return root / 'nope'
    if kind == 'text file, not a bag':
        (root / 'text.mcap').write_text('hello, not a bag\n')
        return root / 'text.mcap'
    if kind == 'folder without a bag':
        (root / 'notes').mkdir()
        (root / 'notes' / 'notes.txt').write_text('x')
        return root / 'notes'
    write_bag(root / 'bag', 200, close=kind != 'cut bag (killed recorder)')
    bag = root / 'bag'
    data = (bag / 'bag.mcap').read_bytes()
    if kind == 'MCAP cut in its header':
        (bag / 'bag.mcap').write_bytes(data[:5])
    elif kind == 'MCAP cut in its first chunk':
        (bag / 'bag.mcap').write_bytes(data[:300])
    elif kind == 'metadata.yaml not YAML':
        (bag / 'metadata.yaml').write_text('rosbag2_bagfile_information: [\n')
    elif kind == 'metadata.yaml custom_data: [1, 2]':
        edit_metadata(bag, custom_data=[1, 2])
    elif kind == 'metadata.yaml relative_file_paths: 5':
        edit_metadata(bag, relative_file_paths=5)
    elif kind == 'metadata.yaml a folder':
        (bag / 'metadata.yaml').unlink()
        (bag / 'metadata.yaml').mkdir()
    elif kind == 'file path escaping the bag folder':
        write_bag(root / 'victim', 40, close=False)
        edit_metadata(bag, relative_file_paths=['../victim/victim.mcap'])
        (bag / 'bag.mcap').unlink()
    return bag


#: bad input -> the words its error line must hold (every command)
BAD_BAGS = {
    'missing path': 'no such file',
    'text file, not a bag': 'not an MCAP file',
    'folder without a bag': 'not a bag',
    'MCAP cut in its header': 'truncated',
    'MCAP cut in its first chunk': 'nothing to recover',
    'metadata.yaml not YAML': 'not valid YAML',
    'metadata.yaml custom_data: [1, 2]': 'custom_data is [1, 2]',
    'metadata.yaml relative_file_paths: 5': 'relative_file_paths is 5',
    'metadata.yaml a folder': 'metadata.yaml',
    'file path escaping the bag folder': 'outside the bag folder',
}
QUICK_BAGS = {'missing path', 'MCAP cut in its first chunk', 'file path escaping the bag folder'}


def _bag_case(kind: str, command: str, words: str) -> Callable[[Path], Outcome]:
    def run(tmp: Path) -> Outcome:
        root = tmp / 'data'
        root.mkdir()
        path = _bad_bag(kind, root)
        before = snapshot(root)
        if command == 'player':
            procs = Procs(tmp)
            try:
                proc = procs.start('player', 'fohssv_sim', 'player', [
                    '--ros-args', *params(bag_path=path, rate=0.0, start_timeout=5.0)])
                code = wait(proc, 60)
            finally:
                procs.close()
            code, out = code, procs.log('player')
        else:
            extra = ['--out', str(tmp / 'figures')] if command == 'plot' else []
            code, out = cli([command, str(path), *extra], tmp)
        # check lists the problems of a file it could read, the verdict last
        listed = command == 'check' and 'problem(s)' in out
        expect = player_node.EXIT_ERROR if command == 'player' else cli_codes.EXIT_BAD_BAG
        result = handled(code, out, expect, '' if listed else words, None if listed else 1)
        if result.ok and snapshot(root) != before:
            return Outcome('handled', False, 'the bad bag folder was modified', output=out)
        if result.ok and (tmp / 'figures').exists():
            return Outcome('handled', False, '--out folder created for a bad bag', output=out)
        return result
    return run


def _out_exists(command: str) -> Callable[[Path], Outcome]:
    def run(tmp: Path) -> Outcome:
        write_bag(tmp / 'bag', 100)
        (tmp / 'taken').write_text('keep me\n')
        args = [command, str(tmp / 'bag')] if command == 'plot' else [command]
        code, out = cli([*args, '--out', str(tmp / 'taken')], tmp)
        result = handled(code, out, cli_codes.EXIT_USAGE, 'exists and is not a folder')
        if result.ok and (tmp / 'taken').read_text() != 'keep me\n':
            return Outcome('handled', False, '--out file modified', output=out)
        return result
    return run


def _repair_cut_bag(tmp: Path) -> Outcome:
    """A cut bag (killed recorder): check says not sound (exit 1), repair rebuilds it (exit
    0), then check passes and every message loads."""
    write_bag(tmp / 'bag', 300, close=False)
    steps = [cli(['check', str(tmp / 'bag')], tmp), cli(['repair', str(tmp / 'bag')], tmp),
             cli(['check', str(tmp / 'bag')], tmp)]
    codes = [c for c, _ in steps]
    text = '\n'.join(o for _, o in steps)
    n = load_run(tmp / 'bag').topics.get('/state', 0) if codes[1] == 0 else 0
    ok = codes == [cli_codes.EXIT_BAD_BAG, 0, 0] and not crashed(text) and n == 300
    return Outcome('survived', ok, f'check/repair/check exits {codes}, {n}/300 states',
                   output='' if ok else text)


def bag_cases() -> list[Case]:
    cases = []
    for kind, words in BAD_BAGS.items():
        for command in ('check', 'plot', 'repair', 'player'):
            if kind == 'metadata.yaml a folder' and command != 'repair':
                continue     # the repair case of the issue (half applied); the others read it
            cases.append(Case('bags', f'{command}: {kind}', _bag_case(kind, command, words),
                              quick=kind in QUICK_BAGS and command in ('check', 'player')))
    cases += [Case('bags', f'{c} --out an existing file', _out_exists(c), quick=c == 'plot')
              for c in ('plot', 'stability')]
    cases.append(Case('bags', 'check, repair, check a cut bag (killed recorder)',
                      _repair_cut_bag))
    return cases


# -- faults --------------------------------------------------------------------------------

def _second_plant(tmp: Path) -> Outcome:
    procs = Procs(tmp)
    try:
        plants = [procs.start(f'plant{i}', 'fohssv_sim', 'plant',
                              plant_args(model='delay-free')) for i in range(2)]
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and all(p.poll() is None for p in plants):
            time.sleep(0.1)
        time.sleep(1.0)           # the other plant's next look at the graph
        stopped = [i for i, p in enumerate(plants) if p.poll() is not None]
    finally:
        procs.close()
    outs = [procs.log(f'plant{i}') for i in stopped]
    ok = bool(stopped) and all(plants[i].returncode == plant_node.EXIT_SECOND_PLANT
                                    for i in stopped) and all(
        '2 publishers of /state' in o and not crashed(o) for o in outs)
    return Outcome('handled', ok, f'{len(stopped)} of 2 refused with exits '
                   f'{[plants[i].returncode for i in stopped]}',
                   output='' if ok else procs.outputs())


def _closed_loop_procs(procs: Procs, plant: dict) -> dict[str, subprocess.Popen]:
    """Plant + eq. 31 controller, no recorder."""
    return {'controller': procs.start('controller', 'fohssv_controller', 'state_feedback', [
                '--ros-args', *params(min_command_subscribers=1)]),
            'plant': procs.start('plant', 'fohssv_sim', 'plant', plant_args(**plant))}


def _demo_loop(procs: Procs, bag: Path, duration: float,
               plant: dict | None = None) -> dict[str, subprocess.Popen]:
    """The recorded closed loop of ``make demo`` (fohssv_sim.closed_loop: lockstep, the
    recorder pacing the plant), started in the demo's order: recorder, controller, plant."""
    out = {}
    for spec in closed_loop(duration=duration, bag_path=str(bag), plant=plant):
        out[spec.name] = procs.start(spec.name, spec.package, spec.executable,
                                     ros_args(spec))
        if spec.name == 'recorder':
            procs.wait_line('recorder', 'recording to', 60)
    return out


def _kill_recorder(tmp: Path) -> Outcome:
    """The demo's recorded loop (delay-free model); the recorder SIGKILLed once 2000 states
    reached the file: the plant finishes; the bag loads, repair completes it, check passes."""
    procs = Procs(tmp)
    bag = tmp / 'bag'
    try:
        p = _demo_loop(procs, bag, 3.0, {'model': 'delay-free'})
        rosproc.wait_for(lambda: _states(bag) >= 2000 or p['plant'].poll() is not None,
                         120, interval=0.1, what='2000 states in the bag')
        ok_fill = p['plant'].poll() is None
        p['recorder'].send_signal(signal.SIGKILL)
        p['recorder'].wait(timeout=10)
        code = wait(p['plant'], 300)
    finally:
        procs.close()
    n_before = _states(bag)
    steps = [cli(['repair', str(bag)], tmp), cli(['check', str(bag)], tmp)]
    n_after = _states(bag)
    text = '\n'.join(o for _, o in steps)
    codes = [c for c, _ in steps]
    ok = (ok_fill and code == 0 and codes == [0, 0] and n_after >= 2000
          and n_after >= n_before and not crashed(text + procs.log('plant')))
    return Outcome('survived', ok, f'plant exit {code}; {n_before} states readable after the '
                   f'kill; repair/check exits {codes}; {n_after} states after repair',
                   output='' if ok else procs.outputs() + text)


def _states(bag: Path) -> int:
    try:
        return len(load_run(bag).t)
    except BagError:
        return 0


def _kill_controller(sig: int, tmp: Path) -> Outcome:
    """A lockstep loop; the controller gets ``sig`` mid-run: the plant ends with exit 3
    naming the stalled controller; a SIGINTed controller exits 0 without a traceback."""
    procs = Procs(tmp)
    try:
        p = _closed_loop_procs(procs, {'model': 'delay-free', 'duration': 600.0,
                                       'command_timeout': 1.0})
        started = procs.wait_line('plant', 'peers matched', 60)
        time.sleep(1.0)
        p['controller'].send_signal(sig)
        ctl = wait(p['controller'], 20)
        code = wait(p['plant'], 30)
    finally:
        procs.close()
    out = procs.log('plant')
    ctl_ok = sig == signal.SIGKILL or (ctl == 0 and not crashed(procs.log('controller')))
    ok = (started and code == plant_node.EXIT_TIMEOUT and ctl_ok and not crashed(out)
          and 'lockstep timeout: the controller stalled' in out)
    return Outcome('handled', ok, f'controller exit {ctl}, plant exit {code}',
                   output='' if ok else procs.outputs())


def _sigint_plant(mode: str, tmp: Path) -> Outcome:
    procs = Procs(tmp)
    plant = {'model': 'delay-free', 'duration': 600.0}
    if mode == 'realtime':
        plant.update(REALTIME)
    try:
        p = _closed_loop_procs(procs, plant)
        started = procs.wait_line('plant', 'peers matched', 60)
        time.sleep(1.0)
        code = rosproc.stop(p['plant'])
        ctl = rosproc.stop(p['controller'])
    finally:
        procs.close()
    text = procs.log('plant') + procs.log('controller')
    ok = started and code == 0 and ctl == 0 and not crashed(text)
    return Outcome('survived', ok, f'plant exit {code}, controller exit {ctl}',
                   output='' if ok else procs.outputs())


def _sigint_recorder(after: float, tmp: Path) -> Outcome:
    """The demo's recorded loop; SIGINT to the recorder ``after`` s into the run: exit 0, a
    sound bag, and the plant (no longer paced) finishes its run."""
    procs = Procs(tmp)
    bag = tmp / 'bag'
    try:
        p = _demo_loop(procs, bag, 8.0, {'model': 'delay-free'})
        started = procs.wait_line('plant', 'peers matched', 60)
        time.sleep(after)
        running = p['plant'].poll() is None
        # the plant is paced by the recorder and runs on: the drain ends at drain_timeout
        code = rosproc.stop(p['recorder'], timeout=30)
        plant = wait(p['plant'], 300)
    finally:
        procs.close()
    check, out = cli(['check', str(bag)], tmp)
    text = procs.log('recorder') + out
    ok = (started and running and code == 0 and plant == 0 and check == 0
          and _states(bag) > 0 and not crashed(text))
    return Outcome('survived', ok, f'recorder exit {code}, fohssv check exit {check}, '
                   f'{_states(bag)} states; plant exit {plant}',
                   output='' if ok else procs.outputs() + out)


def _sigint_player(tmp: Path) -> Outcome:
    write_bag(tmp / 'src', 20000)           # 20000 samples: longer than the case at rate 1
    procs = Procs(tmp)
    try:
        player = procs.start('player', 'fohssv_sim', 'player', [
            '--ros-args', *params(bag_path=tmp / 'src', rate=1.0, min_subscribers=0)])
        started = procs.wait_line('player', 'republishing', 60)
        time.sleep(1.0)
        running = player.poll() is None
        code = rosproc.stop(player)
    finally:
        procs.close()
    out = procs.log('player')
    ok = started and running and code == 0 and not crashed(out)
    return Outcome('survived', ok, f'player exit {code} (running when signalled: {running})',
                   output='' if ok else out)


def fault_cases() -> list[Case]:
    return [
        Case('faults', 'a second plant on the same domain', _second_plant, quick=True),
        Case('faults', 'recorder SIGKILLed mid-run, then repair and check', _kill_recorder),
        Case('faults', 'controller SIGKILLed mid-lockstep',
             lambda tmp: _kill_controller(signal.SIGKILL, tmp), quick=True),
        Case('faults', 'SIGINT to the controller mid-lockstep',
             lambda tmp: _kill_controller(signal.SIGINT, tmp)),
        Case('faults', 'SIGINT to the plant mid-lockstep',
             lambda tmp: _sigint_plant('lockstep', tmp), quick=True),
        Case('faults', 'SIGINT to the plant in real time',
             lambda tmp: _sigint_plant('realtime', tmp)),
        # 1 s: inside the controller's 2 s grace of min_command_subscribers (matching.py)
        Case('faults', 'SIGINT to the recorder 1 s into a recorded loop',
             lambda tmp: _sigint_recorder(1.0, tmp)),
        Case('faults', 'SIGINT to the recorder 3 s into a recorded loop',
             lambda tmp: _sigint_recorder(3.0, tmp)),
        Case('faults', 'SIGINT to the player mid-replay', _sigint_player),
    ]


# -- reliability (issue 21): the graph tests of each class, run as cases -------------------

def _graph_test(module: str, name: str, *args, kind: str = 'survived', **kwargs
                ) -> Callable[[Path], Outcome]:
    """A case that runs the graph test ``module.name`` (real processes over DDS, see the
    test's docstring for what it asserts): ok when it passes; a skip (e.g. no root for the
    tmpfs) is reported as such and not counted as a failure."""
    def run(tmp: Path) -> Outcome:
        import importlib

        import pytest
        func = getattr(importlib.import_module(module), name)
        try:
            func(*[tmp if a == 'tmp' else a for a in args], **kwargs)
        except pytest.skip.Exception as exc:
            return Outcome(kind, True, f'skipped: {exc}')
        except AssertionError as exc:
            return Outcome(kind, False, 'assertion failed', output=str(exc)[-4000:])
        return Outcome(kind, True, f'{module}.{name} passed')
    return run


def _full_disk(tmp: Path) -> Outcome:
    """The full-disk test with its tmpfs (root only), outside pytest's fixtures."""
    import pytest
    from test_graph_full_disk import test_a_full_disk_ends_in_one_line_and_the_bag_repairs
    disk = tmp / 'disk'
    disk.mkdir()
    if os.geteuid() != 0 or subprocess.run(['mount', '-t', 'tmpfs', '-o', 'size=200k', 'tmpfs',
                                            str(disk)], capture_output=True).returncode:
        return Outcome('handled', True, 'skipped: needs root for a small tmpfs')
    try:
        test_a_full_disk_ends_in_one_line_and_the_bag_repairs(disk, tmp)
    except (AssertionError, pytest.fail.Exception) as exc:
        return Outcome('handled', False, 'assertion failed', output=str(exc)[-4000:])
    finally:
        subprocess.run(['umount', '-l', str(disk)], capture_output=True)
    return Outcome('handled', True, 'one line, exit 1, the bag repairs and checks')


def reliability_cases() -> list[Case]:
    g = _graph_test
    return [
        Case('reliability', '40 bad states to a controller: alive, 20 lines then 1/s',
             g('test_graph_controllers',
               'test_controller_survives_many_bad_states_and_throttles_their_lines'),
             quick=True),
        Case('reliability', '40 withheld (non-finite) commands: alive, 20 lines then 1/s',
             g('test_graph_controllers',
               'test_controller_survives_many_withheld_commands_and_throttles_their_lines')),
        Case('reliability', 'a plugin whose update raises: counted, rate-limited',
             g('test_graph_controllers',
               'test_a_plugin_that_raises_is_logged_rate_limited_and_the_node_lives', 'tmp')),
        Case('reliability', 'a hosted law failing every sample: counted, rate-limited',
             g('test_graph_hosted',
               'test_a_hosted_law_that_fails_every_sample_is_counted_and_rate_limited', 'tmp')),
        Case('reliability', 'a realtime /reset: the summary counts the whole run',
             g('test_graph_hosted',
               'test_after_a_realtime_reset_the_summary_is_the_whole_runs', 'tmp')),
        Case('reliability', 'one recorder, two namespaced vehicles',
             g('test_graph_recorder_sources',
               'test_one_recorder_records_two_namespaced_vehicles', 'tmp')),
        Case('reliability', 'two publishers of state, both run_ends: checked, exit 0',
             g('test_graph_recorder_sources',
               'test_two_publishers_of_a_topic_need_two_run_ends', 'tmp', True)),
        Case('reliability', 'two publishers of state, one run_end: unchecked, exit 7',
             g('test_graph_recorder_sources',
               'test_two_publishers_of_a_topic_need_two_run_ends', 'tmp', False,
               kind='handled')),
        Case('reliability', 'publishers gone without run_end: recorder exit 7',
             g('test_graph_recorder_sources',
               'test_publishers_gone_without_run_end_end_the_recording_with_exit_7', 'tmp',
               kind='handled'), quick=True),
        Case('reliability', 'SIGINT to a recorded lockstep plant: bag = run_end = summary',
             g('test_graph_run_end',
               'test_after_sigint_a_lockstep_plant_steps_and_publishes_nothing', 'tmp')),
        Case('reliability', 'three recorder/player pairs started at once',
             g('test_player', 'test_a_recorder_started_together_with_the_player_gets_its_'
               'run_end', 'tmp')),
        Case('reliability', 'recording into a full filesystem', _full_disk),
        Case('reliability', 'a plant binds UDP on loopback only',
             g('test_graph_transport', 'test_a_plant_binds_udp_on_loopback_only'),
             quick=True),
        Case('reliability', 'state publishes refused (injected): exit 9, bag = run_end',
             g('test_graph_publish_failure',
               'test_a_refused_sample_ends_the_run_with_exit_9_and_the_bag_agrees', 'tmp',
               False, False, kind='handled')),
        Case('reliability', 'a hosted run whose state publishes are refused: exit 9',
             g('test_graph_publish_failure',
               'test_a_refused_sample_ends_the_run_with_exit_9_and_the_bag_agrees', 'tmp',
               True, False, kind='handled')),
    ]


# -- loss ----------------------------------------------------------------------------------

def _stop_recorder(recorder: subprocess.Popen) -> tuple[int | None, str]:
    """Give the recorder STOP_GRACE s (more than its end_timeout, 10 s) to stop by itself at
    the run's ``run_end``, then SIGINT (it must drain what was delivered); returns its exit
    code and how it stopped."""
    try:
        return recorder.wait(timeout=STOP_GRACE), 'stopped by itself'
    except subprocess.TimeoutExpired:
        return rosproc.stop(recorder, timeout=60), f'SIGINT {STOP_GRACE:g} s after the run'


def _lockstep_loss(duration: float, tmp: Path) -> Outcome:
    """The demo's closed loop (fohssv_sim.closed_loop: FOM, lockstep, pace_to_subscribers)
    recorded; states and forces in the bag against the plant's samples, commands against
    the states answered (every one but possibly the last)."""
    bag = tmp / 'bag'
    procs = Procs(tmp)
    try:
        p = _demo_loop(procs, bag, duration)
        code = wait(p['plant'], 600)
        rec_code, how = _stop_recorder(p['recorder'])
        ctl_code = rosproc.stop(p['controller'])
    finally:
        procs.close()
    s = summary(procs.log('plant'))
    # states at t = 0, T, ..., t_end (the summary's samples counts the periods advanced)
    samples = round(s['t'] / s['control_period']) + 1 if s else 0
    try:
        run = load_run(bag)
    except BagError as e:
        return Outcome('lost', False, f'bag unreadable: {e}', output=procs.outputs())
    states, forces = len(run.t), len(run.planing_force_t)
    answered = int((run.command_t < s.get('t', 0.0)).sum())
    lost = max(0, samples - states) + max(0, samples - forces) + max(0, samples - 1 - answered)
    ok = (code == 0 and rec_code == 0 and ctl_code == 0 and samples > 0 and lost == 0
          and not crashed(procs.outputs()))
    return Outcome('lost', ok, f'plant exit {code}, {samples} states published; bag: {states} '
                   f'states, {forces} forces, {answered}/{samples - 1} commands (the last '
                   'state needs none); '
                   f'recorder {how}, exit {rec_code}', lost=lost,
                   output='' if ok else procs.outputs())


def _replay_loss(n: int, tmp: Path) -> Outcome:
    """A rate-0 replay of an n-sample bag into a recorder: every message of every contract
    topic (the player's own /clock aside) must reach the new bag."""
    write_bag(tmp / 'src', n)
    src = load_run(tmp / 'src').topics
    bag = tmp / 'bag'
    procs = Procs(tmp)
    try:
        rec = procs.start('recorder', 'fohssv_sim', 'recorder', [
            '--ros-args', *params(bag_path=bag, plant_node='none')])
        procs.wait_line('recorder', 'recording to', 60)
        player = procs.start('player', 'fohssv_sim', 'player', [
            '--ros-args', *params(bag_path=tmp / 'src', rate=0.0, start_timeout=60.0)])
        code = wait(player, 600)
        rec_code, how = _stop_recorder(rec)
    finally:
        procs.close()
    try:
        got = load_run(bag).topics
    except BagError as e:
        return Outcome('lost', False, f'bag unreadable: {e}', output=procs.outputs())
    topics = ('/state', '/planing_force', '/command')
    lost = sum(max(0, src[t] - got.get(t, 0)) for t in topics)
    ok = code == 0 and rec_code == 0 and lost == 0 and not crashed(procs.outputs())
    return Outcome('lost', ok, f'player exit {code}; ' + ', '.join(
        f'{t} {got.get(t, 0)}/{src[t]}' for t in topics) + f'; recorder {how}, exit '
        f'{rec_code}', lost=lost, output='' if ok else procs.outputs())


def loss_cases(quick: bool) -> list[Case]:
    duration = 0.2 if quick else 0.5
    n = 1001 if quick else 3001
    cases = []
    for loaded in (False, True):
        tag = ', two busy processes' if loaded else ''
        cases += [
            Case('loss', f'lockstep closed loop (FOM, {duration:g} s) recorded{tag}',
                 lambda tmp: _lockstep_loss(duration, tmp), quick=not loaded, loaded=loaded),
            Case('loss', f'rate-0 replay of {n} samples into a recorder{tag}',
                 lambda tmp: _replay_loss(n, tmp), quick=not loaded, loaded=loaded),
        ]
    return cases


# -- running -------------------------------------------------------------------------------

def run_case(case: Case, root: Path, index: int) -> dict:
    tmp = root / f'{index:03d}'
    tmp.mkdir()
    start = time.monotonic()
    try:
        outcome = case.run(tmp)
    except Exception:   # a broken case is a failed case, with its traceback in the report
        outcome = Outcome('error', False, 'the case itself failed',
                          output=traceback.format_exc())
    case.result = {'category': case.category, 'name': case.name, **asdict(outcome),
                   'seconds': round(time.monotonic() - start, 1)}
    mark = 'ok  ' if outcome.ok else 'FAIL'
    print(f'{mark} {case.category:10s} {case.name[:70]:70s} {outcome.detail[:90]}', flush=True)
    return case.result


class Busy:
    """Two ``yes > /dev/null`` processes (the issue's load on this 2-core machine)."""

    def __enter__(self):
        self.procs = [subprocess.Popen(['yes'], stdout=subprocess.DEVNULL) for _ in range(2)]
        return self

    def __exit__(self, *exc):
        for p in self.procs:
            p.kill()
            p.wait()


def table(results: list[dict]) -> str:
    head = ('category', 'cases', 'handled with clear error', 'survived', 'messages lost',
            'failed')
    rows = []
    for cat in CATEGORIES + ('all',):
        rs = [r for r in results if cat in ('all', r['category'])]
        if not rs:
            continue
        lost = [r for r in rs if r['kind'] == 'lost']
        rows.append((cat, len(rs), sum(r['ok'] and r['kind'] == 'handled' for r in rs),
                     sum(r['ok'] and r['kind'] == 'survived' for r in rs),
                     sum(r['lost'] for r in lost) if lost else '-',
                     sum(not r['ok'] for r in rs)))
    w = [max(len(str(x)) for x in col) for col in zip(head, *rows, strict=True)]
    fmt = '| ' + ' | '.join(f'{{:{"<" if i == 0 else ">"}{n}}}' for i, n in enumerate(w)) + ' |'
    sep = '|' + '|'.join('-' * (n + 2) for n in w) + '|'
    return '\n'.join([fmt.format(*head), sep, *(fmt.format(*r) for r in rows)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', type=Path, default=ROOT / 'bench' / 'results' / 'faults.json')
    ap.add_argument('--quick', action='store_true', help='a representative subset')
    ap.add_argument('--jobs', type=int, default=4, help='cases run at once (default 4)')
    ap.add_argument('--only', default='', help='comma-separated categories')
    ap.add_argument('--match', default='', help='only the cases whose name contains this text')
    a = ap.parse_args(argv)
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix='fohssv-faults-') as tmpdir:
        root = Path(tmpdir)
        cases = (parameter_cases(root / 'catalogue') + cli_parameter_cases(root / 'cli')
                 + command_cases() + bag_cases()
                 + fault_cases() + reliability_cases() + loss_cases(a.quick))
        if a.quick:
            cases = [c for c in cases if c.quick]
        if a.only:
            cases = [c for c in cases if c.category in a.only.split(',')]
        if a.match:
            cases = [c for c in cases if a.match in c.name]
        print(f'{len(cases)} cases, {a.jobs} at a time', flush=True)
        index = iter(range(len(cases)))
        # everything but the loss cases at once, then the loss cases alone, then under load
        plain = [c for c in cases if c.category != 'loss']
        with ThreadPoolExecutor(a.jobs) as pool:
            list(pool.map(lambda c: run_case(c, root, next(index)), plain))
        for loaded in (False, True):
            batch = [c for c in cases if c.category == 'loss' and c.loaded == loaded]
            if not batch:
                continue
            if loaded:
                print('two busy processes (yes > /dev/null) running', flush=True)
            with Busy() if loaded else _nothing(), ThreadPoolExecutor(1) as pool:
                list(pool.map(lambda c: run_case(c, root, next(index)), batch))
        rosproc.kill_leftovers()
    results = [c.result for c in cases]
    wall = time.monotonic() - started
    print(f'\nfault-and-bad-input suite{" (quick)" if a.quick else ""}: {len(results)} cases '
          f'in {wall:.0f} s\n')
    print(table(results))
    failed = [r for r in results if not r['ok']]
    for r in failed:
        print(f"\nFAILED {r['category']}: {r['name']}: {r['detail']}\n{r['output'][-4000:]}")
    lost = sum(r['lost'] for r in results)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({
        'benchmark': 'faults', 'quick': a.quick, 'wall_time': wall, 'cpus': os.cpu_count(),
        'load_avg_end': os.getloadavg(), 'cases': len(results), 'failed': len(failed),
        'messages_lost': lost, 'table': table(results), 'results': results}, indent=2) + '\n')
    print(f'wrote {a.out}')
    return 1 if failed or lost else 0


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None


if __name__ == '__main__':
    sys.exit(main())
