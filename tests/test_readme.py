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
