"""The README states the commands CI and users run, and its tables are the code's tables."""

from pathlib import Path

from fohssv_sim.docs import parameter_table

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / 'README.md').read_text()


def test_readme_shows_the_two_commands_and_ci_runs_the_test_one():
    assert 'make demo' in README and 'make test' in README
    ci = (ROOT / '.ci' / 'run').read_text()
    assert '\nmake test\n' in ci


def test_readme_parameter_table_is_generated_from_the_parameter_table():
    assert parameter_table() in README, 'regenerate with: python -m fohssv_sim.docs'


def test_readme_topic_table_and_controller_example_are_the_real_ones():
    from fohssv_sim.docs import topic_table, view_table

    assert topic_table() in README
    assert view_table() in README, 'regenerate with: python -m fohssv_sim.docs'
    example = (ROOT / 'tests' / 'examples' / 'pitch_damper.py').read_text().rstrip()
    assert f'```python\n{example}\n```' in README


#: The marker of README blocks that this test runs in order, as written.
RUN_MARKER = '<!-- tests/test_readme.py runs this block -->'


def marked_commands() -> list[str]:
    """The command lines of the README's marked bash block(s), in order."""
    lines = []
    for part in README.split(RUN_MARKER)[1:]:
        block = part.split('```bash\n', 1)[1].split('```', 1)[0]
        lines += [ln.strip() for ln in block.splitlines() if ln.strip()]
    return lines


def record_small_bag(path):
    """runs/mine as the README's graph block records it (a real rosbag2/MCAP bag of a
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


def test_readme_analysis_block_runs_in_order_as_written(tmp_path, monkeypatch, capfd):
    """Issue 22 item 3: the README's fohssv commands, run one after the other in a fresh
    folder, all succeed; each command's outputs are in a folder of its own under reports/,
    the repeated sweep reuses its folder (no chunk computed), no folder holds two jobs.

    The commands run in this process through the CLI's ``main`` (the parser and commands
    the console script calls, with the block's argv): seven interpreters importing numpy,
    numba, scipy and matplotlib cost more than the commands themselves. The installed
    ``fohssv`` script is run as a user runs it by tests/test_stack.py and
    src/fohssv_sim/test/test_cli_bad_input.py."""
    import json
    import shlex

    from fohssv_sim.cli import main

    commands = marked_commands()
    assert commands and all(c.startswith('fohssv ') for c in commands), commands
    record_small_bag(tmp_path / 'runs' / 'mine')
    monkeypatch.chdir(tmp_path)
    capfd.readouterr()
    folders = []
    for k, command in enumerate(commands):
        argv = shlex.split(command)
        code = main(argv[1:])
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


def test_readme_full_size_commands_get_distinct_folders():
    """The README's reproduction commands (too long to run here) each resolve to a folder of
    their own: parsed and specified by the CLI itself, nothing run."""
    import re
    import shlex

    from fohssv_sim.cli import build_parser
    from fohssv_sim.cli import gainmap as gainmap_cli
    from fohssv_sim.cli import sweep as sweep_cli

    commands = re.findall(r'`(fohssv (?:sweep|gainmap) [^`]*)`', README)
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
    assert len(folders) == len(set(commands))
