"""The README and docs/ state commands that work and figures without a date.

Every ```bash block of README.md and docs/*.md is checked here without running anything slow:
each ``fohssv`` command is parsed by the CLI's own parser, each node started (``ros2 run P E``
or ``ros2_ws/install/P/lib/P/E``) is an executable its package installs and every ``-p NAME``
given to it is a parameter that node declares, each ``make`` target, script and launch
argument exists, and every link between the pages resolves. Blocks marked with
:data:`RUN_MARKER` are also run in order, as written; the README's record block is run by
tests/test_launch.py, the controller package of docs/controllers.md by
tests/test_graph_controller_package.py.
"""

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / 'README.md').read_text()
PAGES = {'README.md': README} | {f'docs/{p.name}': p.read_text()
                                 for p in sorted((ROOT / 'docs').glob('*.md'))}

#: The marker of blocks that tests/test_readme.py runs in order, as written.
RUN_MARKER = '<!-- tests/test_readme.py runs this block -->'

#: What the stop check of issue 46 counts: a date, or an echo rate.
DATED = re.compile(r'20[0-9]{2}-[01][0-9]-[0-3][0-9]|round trips/s')


def test_readme_shows_the_two_commands_and_ci_runs_the_test_one():
    assert 'make demo' in README and 'make test' in README
    ci = (ROOT / '.ci' / 'run').read_text()
    assert '\nmake test\n' in ci


def test_readme_and_docs_hold_no_dated_measurement_history():
    """History lives in git; the latest benchmark figures live in bench/RESULTS.md."""
    hits = [(page, line) for page, text in PAGES.items()
            for line in text.splitlines() if DATED.search(line)]
    assert not hits, hits


def test_the_controller_example_is_in_the_readme_once_and_in_no_doc_page():
    example = (ROOT / 'tests' / 'examples' / 'pitch_damper.py').read_text().rstrip()
    assert README.count(f'```python\n{example}\n```') == 1
    body = example.split('class PitchDamper(Controller):')[1].strip().splitlines()[0]
    copies = [page for page, text in PAGES.items() if page != 'README.md' and body in text]
    assert not copies, f'the example is copied into {copies}: link the README instead'


def test_readme_error_example_is_what_the_model_says():
    """Issue 50 item 8: the README quotes the message the program prints, as printed."""
    from fohssv_sim.params import ModelParameters

    quoted = re.search(r'`ModelParameters\((\w+)=(-?\d+)\)` raises `([^`]+)`',
                       ' '.join(README.split()))
    assert quoted, 'README: no quoted ModelParameters error'
    name, value, text = quoted.groups()
    with pytest.raises(ValueError) as err:
        ModelParameters(**{name: int(value)})
    assert str(err.value).startswith(text), (str(err.value), text)


# -- every command block: parsed and resolved -----------------------------------------------

def bash_blocks() -> list[tuple[str, str]]:
    """(page, block) for every ```bash block of README.md and docs/*.md."""
    return [(page, block) for page, text in PAGES.items()
            for block in re.findall(r'^```bash\n(.*?)^```', text, re.S | re.M)]


def commands(block: str) -> list[list[str]]:
    """The simple commands of a bash block: continuations joined as bash joins them (the
    backslash and the newline removed), comments dropped, split at
    ; & && | ||, variables of simple assignments earlier in the block expanded."""
    assigned: dict[str, str] = {}
    out = []
    for line in block.replace('\\\n', '').splitlines():
        lexer = shlex.shlex(line, posix=True, punctuation_chars=True)
        lexer.whitespace_split = True
        lexer.commenters = '#'
        cmd: list[str] = []
        for token in [*lexer, ';']:
            if token in (';', '&', '&&', '|', '||'):
                while cmd and cmd[0] in ('do', 'then'):
                    cmd.pop(0)
                while cmd and re.fullmatch(r'[A-Z_]+=.*', cmd[0]):
                    key, value = cmd.pop(0).split('=', 1)
                    assigned[key] = value
                if cmd:
                    out.append(cmd)
                cmd = []
            elif token.startswith('$') and token[1:] in assigned:
                cmd += shlex.split(assigned[token[1:]])
            else:
                for key, value in assigned.items():
                    token = token.replace(f'${key}/', f'{value}/')
                cmd.append(token)
    return out


def _console_scripts(package: str) -> set[str]:
    setup = (ROOT / 'src' / package / 'setup.py').read_text()
    scripts = setup.split("'console_scripts'", 1)[1].split(']', 1)[0]
    return set(re.findall(r"'(\w+) = ", scripts))


def _node_parameters(package: str, executable: str) -> set[str]:
    """Every parameter the node of that executable declares (rclpy's own included)."""
    def yaml_keys(path: Path) -> set[str]:
        return set(yaml.safe_load(path.read_text())['/**']['ros__parameters'])

    names = {'use_sim_time'}
    if package == 'fohssv_controller':
        from fohssv_sim.ros.options import CPU_AFFINITY, CPU_DMA_LATENCY

        for path in (ROOT / 'src' / package / 'config').glob('*.yaml'):
            names |= yaml_keys(path)
        return names | {'min_command_subscribers', CPU_AFFINITY.name, CPU_DMA_LATENCY.name}
    if executable == 'plant':
        return names | yaml_keys(ROOT / 'src' / 'fohssv_sim' / 'config' / 'plant.yaml')
    from fohssv_sim.ros.bag_options import PLAYER_PARAMETERS, RECORDER_PARAMETERS
    from fohssv_sim.ros.viewer_options import VIEWER_PARAMETERS

    table = {'recorder': RECORDER_PARAMETERS, 'player': PLAYER_PARAMETERS,
             'viewer': VIEWER_PARAMETERS}[executable]
    return names | {spec.name for spec in table}


def check_node(package: str, executable: str, args: list[str]) -> None:
    assert executable in _console_scripts(package), f'{package} installs no {executable!r}'
    declared = _node_parameters(package, executable) if executable != 'fohssv' else set()
    for flag, value in zip(args, args[1:]):
        if flag == '-p':
            name = value.split(':=', 1)[0]
            assert name in declared or name.startswith('controller.'), (
                f'{executable} declares no parameter {name!r}')
        if flag == '--params-file' and '/config/' in value:    # a file the project ships
            assert list(ROOT.glob(f'src/*/config/{Path(value).name}')), value


def check_command(cmd: list[str]) -> None:
    """One command of a docs block: it names things that exist and parses."""
    word = cmd[0]
    if word == 'fohssv':
        from fohssv_sim.cli import build_parser

        try:
            build_parser().parse_args(cmd[1:])
        except SystemExit:
            pytest.fail(f'fohssv does not parse: {shlex.join(cmd)}')
    elif word == 'ros2' and cmd[1] == 'run':
        if cmd[2] != 'my_controllers':                 # docs/controllers.md's own package
            check_node(cmd[2], cmd[3], cmd[4:])
    elif word == 'ros2' and cmd[1] == 'launch':
        launch = (ROOT / 'src' / cmd[2] / 'launch' / cmd[3]).read_text()
        import inspect

        from fohssv_sim.closed_loop import closed_loop

        arguments = set(inspect.signature(closed_loop).parameters) | {'hosted', 'viewer'}
        for arg in cmd[4:]:
            assert arg.split(':=', 1)[0] in arguments, f'{cmd[3]} takes no {arg!r}'
        assert 'closed_loop' in launch
    elif m := re.fullmatch(r'ros2_ws/install/(\w+)/lib/\1/(\w+)', word):
        check_node(m.group(1), m.group(2), cmd[1:])
    elif word == 'make':
        targets = set(re.findall(r'^([a-z-]+):', (ROOT / 'Makefile').read_text(), re.M))
        assert cmd[1] in targets, f'no make target {cmd[1]!r}'
    elif word in ('python', 'scripts/in-env'):
        script = next(a for a in cmd[1:] if a not in ('python', '-m'))
        if '-m' in cmd:
            import importlib.util

            assert importlib.util.find_spec(script), script
        elif not script.startswith('-'):
            assert (ROOT / script).is_file(), f'no script {script}'
    else:
        assert word in SHELL, f'unchecked command {shlex.join(cmd)}: teach check_command it'


#: Commands the check leaves to the shell, or that need what a test machine lacks.
SHELL = {'source', 'cd', 'mkdir', 'wait', 'kill', 'export', 'for', 'done', 'colcon', 'docker',
         'dask', '.venv/bin/pip', 'pip', 'ssh', 'git'}


@pytest.mark.parametrize('page,block', bash_blocks(),
                         ids=[f'{p}:{b.splitlines()[0][:40]}' for p, b in bash_blocks()])
def test_every_command_block_names_what_exists_and_parses(page, block):
    for cmd in commands(block):
        check_command(cmd)


def test_the_command_check_catches_what_it_should():
    """The check above can fail: a misspelt parameter, executable, subcommand or target."""
    for bad in ('ros2 run fohssv_sim plant --ros-args -p sped:=80',
                'ros2 run fohssv_sim plnat', 'fohssv sweeep V', 'make tests',
                '$P/recorder --ros-args -p bag:=x', 'python scripts/nope.py'):
        block = f'P=ros2_ws/install/fohssv_sim/lib/fohssv_sim\n{bad}\n'
        with pytest.raises((AssertionError, pytest.fail.Exception, StopIteration)):
            for cmd in commands(block):
                check_command(cmd)


# -- the blocks run as written ---------------------------------------------------------------

def marked_commands() -> list[str]:
    """The command lines of the marked bash blocks of README.md and docs/, in order."""
    lines = []
    for text in PAGES.values():
        for part in text.split(RUN_MARKER)[1:]:
            block = part.split('```bash\n', 1)[1].split('```', 1)[0]
            lines += [ln.strip() for ln in block.splitlines() if ln.strip()]
    return lines


def record_small_bag(path):
    """runs/mine as the README's record block records it (a real rosbag2/MCAP bag of a
    simulated closed loop: state, planing force, command, /clock)."""
    from fohssv_controller.state_feedback import StateFeedback
    from fohssv_sim import contract
    from fohssv_sim.bag.synthetic import clock, float64_array
    from fohssv_sim.bag.writer import RunWriter
    from fohssv_sim.params import ModelParameters
    from fohssv_sim.simulate import simulate

    p = ModelParameters(model='delay-free')
    run = simulate(p, StateFeedback(), 0.1, sample_every=10)
    w = RunWriter(path).open()
    for topic in contract.TOPICS:
        w.add_topic(topic.name if topic.name.startswith('/') else '/' + topic.name, topic.type)
    w.add_metadata({'fohssv.plant_parameters': {**p.to_dict(), 'control_period': None}})
    for i, t in enumerate(run.t):
        ns = round(t * 1e9)
        w.write('/clock', ns, clock(ns))
        w.write('/state', ns, float64_array(contract.STATE, [t, *run.state[i]]))
        w.write('/planing_force', ns, float64_array(contract.PLANING_FORCE,
                                                    [t, run.planing_force[i]]))
        w.write('/command', ns, float64_array(contract.COMMAND, [t, *run.inputs[i]]))
    w.close()


def on_cluster(argv: list[str], address: str) -> list[str]:
    """``argv`` with its ``--workers N`` (a local cluster of N worker processes) replaced by
    ``--scheduler address``."""
    if '--workers' not in argv:
        return argv
    k = argv.index('--workers')
    return [*argv[:k], '--scheduler', address, *argv[k + 2:]]


@pytest.fixture
def dask_cluster():
    """A Dask cluster of one worker thread in this process, reachable as ``--scheduler``
    takes it (tcp://HOST:PORT)."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol='tcp://',
                      host='127.0.0.1', dashboard_address=':0',
                      scheduler_kwargs={'dashboard': False}) as cluster:
        yield cluster


def test_docs_analysis_block_runs_in_order_as_written(tmp_path, monkeypatch, capfd,
                                                      dask_cluster):
    """Issue 22 item 3: the marked block's fohssv commands (docs/cli.md), run one after the
    other in a fresh folder, all succeed; each command's outputs are in a folder of its own
    under reports/, the repeated sweep reuses its folder (no chunk computed), no folder holds
    two jobs.

    The commands run in this process through the CLI's ``main`` (the parser and commands
    the console script calls, with the block's argv), their ``--workers 1`` on a Dask cluster
    of one thread: seven interpreters and two worker processes importing numpy,
    numba, scipy and matplotlib cost more than the commands themselves. The installed
    ``fohssv`` script is run as a user runs it by tests/test_stack.py and
    src/fohssv_sim/test/test_cli_bad_input.py, a sweep on its own local cluster by
    src/fohssv_sim/test/test_sweep.py."""
    import json

    from fohssv_sim.cli import main

    commands = marked_commands()
    assert commands and all(c.startswith('fohssv ') for c in commands), commands
    record_small_bag(tmp_path / 'runs' / 'mine')
    monkeypatch.chdir(tmp_path)
    capfd.readouterr()
    folders = []
    for k, command in enumerate(commands):
        argv = shlex.split(command)
        code = main(on_cluster(argv[1:], dask_cluster.scheduler_address))
        out = capfd.readouterr()
        assert code == 0, (command, out.out[-2000:], out.err[-2000:])
        if argv[1] in ('stability', 'sweep', 'plot'):
            folder = next(w for w in out.out.split() if w.startswith(f'reports/{argv[1]}/'))
            folders.append(Path(folder.split('/')[0], folder.split('/')[1],
                                folder.split('/')[2].rstrip(',:')))
        if k == 3:          # the first sweep again
            assert '0 chunks computed' in out.out, out.out
    stability, sweep_v, sweep_alpha, sweep_v_again, plot_a, plot_b = folders
    assert sweep_v == sweep_v_again and len({stability, sweep_v, sweep_alpha, plot_a,
                                             plot_b}) == 5
    assert (tmp_path / stability / 'stability.json').exists()
    assert (tmp_path / sweep_v / 'orbit_V.png').stat().st_size > 5000
    assert (tmp_path / sweep_alpha / 'orbit_alpha.png').stat().st_size > 5000
    for plot in (plot_a, plot_b):
        assert (tmp_path / plot / 'run_time.png').stat().st_size > 5000
        assert set(json.loads((tmp_path / plot / 'job.json').read_text())) == {'plot:run'}
    assert json.loads((tmp_path / plot_b / 'job.json').read_text())['plot:run']['skip'] == 0.05
    assert not [p for p in (tmp_path / 'reports').iterdir() if p.is_file()]


def test_docs_full_size_commands_get_distinct_folders():
    """The reproduction commands of the docs (too long to run here) each resolve to a folder
    of their own: parsed and specified by the CLI itself, nothing run."""
    from fohssv_sim.cli import build_parser
    from fohssv_sim.cli import gainmap as gainmap_cli
    from fohssv_sim.cli import sweep as sweep_cli

    commands = re.findall(r'`(fohssv (?:sweep|gainmap) [^`]*)`', '\n'.join(PAGES.values()))
    commands = sorted(set(commands))
    assert len(commands) >= 5, commands
    folders = set()
    for command in commands:
        args = build_parser().parse_args(shlex.split(command)[1:])
        if args.command == 'sweep':
            folder = sweep_cli.default_folder(args.kind, sweep_cli.build_spec(args))
        else:
            folder = gainmap_cli.default_folder(gainmap_cli.build_spec(args))
        assert folder.parts[:2] == ('reports', args.command)
        folders.add(folder)
    assert len(folders) == len(commands)


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r'[^\w\- ]', '', heading.strip().lower()).replace(' ', '-')


#: Pages other engineers write on branches of their own (the lead merges them): linked from
#: the index already. The lead empties this set at merge.
WRITTEN_ELSEWHERE: set[str] = set()


def test_every_link_between_the_pages_resolves():
    """A relative link names a file of the repository and, with #anchor, a heading of it:
    pages moved or renamed leave no dead link behind."""
    dead = []
    for page, text in PAGES.items():
        base = (ROOT / page).parent
        for target in re.findall(r'\]\(([^)\s]+)\)', text):
            if re.match(r'[a-z]+:', target):
                continue                                  # http(s), mailto
            path, _, anchor = target.partition('#')
            file = (base / path).resolve() if path else ROOT / page
            if not file.exists():
                if file.relative_to(ROOT).as_posix() not in WRITTEN_ELSEWHERE:
                    dead.append((page, target))
            elif anchor and file.suffix == '.md':
                heads = re.findall(r'^#+ (.*)$', file.read_text(), re.M)
                if anchor not in {_slug(h) for h in heads}:
                    dead.append((page, target))
    assert not dead, dead


def test_readme_python_blocks_run_as_written(tmp_path, monkeypatch):
    """The README's Python blocks (the model without ROS; loading the record block's bag)
    run as written, on a bag like the one the record block writes; the controller example
    is run against the real plant by tests/test_graph_controllers.py."""
    blocks = re.findall(r'```python\n(.*?)```', README, re.S)
    example = (ROOT / 'tests' / 'examples' / 'pitch_damper.py').read_text()
    blocks = [b for b in blocks if b != example]
    assert len(blocks) == 2, blocks
    record_small_bag(tmp_path / 'runs' / 'mine')
    monkeypatch.chdir(tmp_path)
    for block in blocks:
        scope: dict = {}
        exec(compile(block, 'README.md', 'exec'), scope)      # noqa: S102 - the docs' own code
        run = scope['run']
        assert len(run.t) == len(run.state) > 100, block
        if 'part' in scope:           # the window: every 5th sample of [0.02, 0.08] s
            inside = run.t[(run.t >= 0.02) & (run.t <= 0.08)]
            assert len(inside) > 50 and np.array_equal(scope['part'].t, inside[::5]), block
