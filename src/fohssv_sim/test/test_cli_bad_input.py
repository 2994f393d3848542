"""Issue 21 class 3: every bad input of every ``fohssv`` subcommand ends in one line on stderr
(naming the option, the value, the allowed range or limit and the unit), exit 2 (1 for a bag
that is not there, as ``fohssv check``), never a traceback, and nothing written.

The catalogue below is the CLI's start-up catalogue (as tests/test_graph_startup.py is the
nodes'): one row per bad input, ``(argv, exit code, words the one line must hold)``. Every
row runs in-process through :func:`fohssv_sim.cli.main` (the real parser and commands; all of
them refuse before any work, so the table is quick); a sample of rows also runs through the
installed console script, as a user runs it.
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import time
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix
from clirun import fohssv

from fohssv_sim import contract
from fohssv_sim.bag.synthetic import float64_array
from fohssv_sim.bag.writer import RunWriter
from fohssv_sim.cli.common import LIMITS, CliError, output_file, safe_name

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'
CORES = os.cpu_count() or 1


def free_port() -> int:
    """A local TCP port where nothing listens (bound, then released)."""
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def small_bag(path: Path) -> Path:
    """A real rosbag2/MCAP bag of 11 states over 0.1 s."""
    w = RunWriter(path).open()
    w.add_topic('/state', contract.STATE.type)
    for i in range(11):
        t = i * 0.01
        w.write('/state', round(t * 1e9), float64_array(contract.STATE, [t, 0, 0.1, 0, 0]))
    w.close()
    return path


def catalogue(tmp: Path) -> list[tuple[list[str], int, str]]:
    """(argv, exit code, words of the one line). ``tmp`` holds the files some rows need."""
    bag = str(small_bag(tmp / 'bag'))
    (tmp / 'afile').write_text('mine\n')
    afile = str(tmp / 'afile')
    other = tmp / 'other_sweep'
    other.mkdir()
    (other / 'sweep.json').write_text(json.dumps({'spec': {'a': 1}, 'chunks': []}))
    taken = tmp / 'taken_plot'
    taken.mkdir()
    (taken / 'run_time.png').write_bytes(b'not from fohssv')
    port = str(free_port())
    nobody = f'tcp://127.0.0.1:{port}'
    quick = ['--transient', '0.01', '--window', '0.01']
    gm = ['gainmap', '--x', 'pitch_rate_gain=-1:0:0.5', '--y', 'vertical_velocity_gain=0,0.1']
    max_workers = LIMITS['workers_per_core'] * CORES
    tn = ['tune', '--tune', 'pitch_rate_gain=-1:0', '--envelope-speeds', '75',
          '--envelope-alphas', '0.85']
    fb = ['fit', bag, '--fit', 'fractional_order', '--controller', 'state_feedback']
    fr = ['fit', '--fit', 'fractional_order', '--reference', 'delayed', '--speeds', '75']
    return [
        # -- the command line itself --
        ([], 2, 'the following arguments are required: command'),
        (['nope'], 2, "invalid choice: 'nope'"),
        # -- stability --
        (['stability', '--speeds', '75:1e9:1e-3'], 2,
         "--speeds='75:1e9:1e-3' has 1e+12 values; the limit is 10000"),
        (['stability', '--controller', 'fractional_pid'], 2,
         '--controller fractional_pid keeps internal state'),
        (['stability', '--controller', 'nope'], 2, "'nope'"),
        (['stability', '--set', 'speed=1e308'], 2,
         "the model's coefficients overflow with speed=1e+308:"),
        (['stability', '--speed', '0'], 2,
         '--speed: speed=0.0 is outside the allowed range (0, inf) m/s (forward speed)'),
        (['stability', '--speed', 'fast'], 2, "speed='fast' is not valid; allowed: (0, inf) m/s"),
        (['stability', '--alpha', '1.5'], 2, '--alpha=1.5 is outside the allowed range (0, 1]'),
        (['stability', '--alpha', 'nan'], 2, '--alpha=nan is outside the allowed range (0, 1]'),
        (['stability', '--speeds', '90:75:1'], 2, 'must be start:stop:step (stop >= start'),
        (['stability', '--speeds', ''], 2, "--speeds='' must be start:stop:step"),
        (['stability', '--speeds=-5,75'], 2,
         '--speeds: speed=-5.0 is outside the allowed range (0, inf) m/s'),
        (['stability', '--speeds', '75,1e308'], 2, 'cannot be evaluated at speed=1e+308'),
        (['stability', '--set', 'speed=80', '--set', 'speed=90'], 2,
         "--set speed is given twice (speed=80.0 and 'speed=90')"),
        (['stability', '--set', '=3'], 2, "--set '=3' has no name"),
        (['stability', '--set', 'sped=80'], 2, 'unknown parameter(s) sped'),
        (['stability', '--set', 'step=0'], 2,
         "step=0.0 is outside the allowed range 'auto' or (0, 0.01] s"),
        (['stability', '--gain', 'depth_gain=1e308'], 2,
         'the equilibrium search failed at V = 75 m/s with state_feedback(depth_gain=1e+308'),
        (['stability', '--gain', 'depth_gain'], 2, "--gain 'depth_gain' must look like name=value"),
        (['stability', '--preset', 'nope'], 2, "preset='nope' is unknown"),
        (['stability', '--alpha', '0.8', '--set', 'fractional_order=0.7'], 2,
         '--set fractional_order=0.7 and --alpha both set fractional_order; give it once'),
        (['stability', '--speed', '80', '--set', 'speed=75'], 2,
         '--set speed=75.0 and --speed both set speed'),
        (['stability', '--out', afile], 2, f'--out {afile}: exists and is not a folder'),
        (['stability', '--bogus'], 2, 'unrecognized arguments: --bogus'),
        # -- sweep --
        (['sweep'], 2, 'the following arguments are required: kind'),
        (['sweep', 'beta'], 2, "invalid choice: 'beta'"),
        (['sweep', 'alpha', '--alpha', '0.6:1:1e-9'], 2,
         "--alpha='0.6:1:1e-9' has 4e+08 values; the limit is 100000"),
        (['sweep', 'alpha', '--alpha', '0.5,1.2'], 2,
         '--alpha: fractional_order=1.2 is outside the allowed range (0, 1]'),
        (['sweep', 'V', '--speed', '0:10:1'], 2,
         '--speed: speed=0.0 is outside the allowed range (0, inf) m/s'),
        (['sweep', 'alpha-V', '--alpha', '0.001:1:0.001', '--speed', '1:1000:0.1'], 2,
         'the sweep (alpha-V) has 9.991e+06 points; the limit is 1e+06'),
        (['sweep', 'alpha', '--transient', '1e9'], 2,
         '(1e+09 s simulated at step 2e-05 s) has 5e+13 integration steps per run; the limit '
         'is 1e+09'),
        (['sweep', 'alpha', '--set', 'step=1e-12'], 2,
         'has 2e+12 integration steps per run; the limit is 1e+09'),
        (['sweep', 'alpha', '--alpha', '0.5:1:0.0001', '--window', '100', '--chunk-size',
          '10000'], 2, 'GiB per task; the limit is 2 GiB'),
        (['sweep', 'alpha', '--window', '0'], 2,
         '--window=0 is outside the allowed range (0, inf) s'),
        (['sweep', 'alpha', '--window', 'nan'], 2, '--window=nan is outside the allowed range'),
        (['sweep', 'alpha', '--transient', '-1'], 2,
         '--transient=-1 is outside the allowed range [0, inf) s'),
        (['sweep', 'alpha', '--sample-every', '0'], 2,
         '--sample-every=0 is outside the allowed range [1, inf) steps'),
        (['sweep', 'alpha', '--sample-every', '1.5'], 2,
         '--sample-every=1.5 is not a whole number'),
        (['sweep', 'alpha', '--chunk-size', '-5', *quick], 2,
         '--chunk-size=-5 is outside the allowed range [1, 100000] points'),
        (['sweep', 'alpha', '--chunk-size', '0', *quick], 2, '--chunk-size=0 is outside'),
        (['sweep', 'alpha', '--workers', '-1', *quick], 2,
         f'--workers=-1 is outside the allowed range [0, {max_workers}] processes'),
        (['sweep', 'alpha', '--workers', '1000', *quick], 2,
         f'--workers=1000 is outside the allowed range [0, {max_workers}] processes'),
        (['sweep', 'alpha', '--scheduler', nobody, *quick], 2,
         f'--scheduler={nobody}: no Dask scheduler answers there'),
        (['sweep', 'alpha', '--scheduler', 'nonsense', *quick], 2,
         "--scheduler='nonsense' is not a scheduler address"),
        (['sweep', 'alpha', '--check-step', '-1', *quick], 2,
         '--check-step=-1 is outside the allowed range [0, inf) points'),
        (['sweep', 'alpha', '--control-period', '-1', *quick], 2,
         '--control-period=-1 is outside the allowed range (0, inf) s'),
        (['sweep', 'alpha', '--control-period', '3e-5', *quick], 2,
         '--control-period=3e-05 s must be a whole multiple of the integration step'),
        (['sweep', 'alpha', '--control-period', '10', *quick], 2,
         '--control-period=10 s is longer than the run'),
        (['sweep', 'alpha', '--controller', 'fractional_pid', *quick], 2,
         '--controller fractional_pid is not an affine state feedback'),
        (['sweep', 'alpha', '--state', 'x'], 2, "argument --state: invalid choice: 'x'"),
        (['sweep', 'V', '--set', 'speed=80'], 2,
         '--set speed=80.0 and --speed both set speed (a V sweep sets V from --speed'),
        (['sweep', 'alpha', '--set', 'fractional_order=0.9'], 2,
         '--set fractional_order=0.9 and --alpha both set fractional_order (an alpha sweep'),
        (['sweep', 'alpha', '--alpha', '0.9', *quick, '--out', str(other)], 2,
         f'{other} holds a different job'),
        # -- gainmap --
        (['gainmap'], 2, 'the following arguments are required: --x, --y'),
        (['gainmap', '--x', 'pitch_rate_gain', '--y', 'vertical_velocity_gain=0'], 2,
         "--x 'pitch_rate_gain' must look like NAME=VALUES"),
        (['gainmap', '--x', 'nosuch=0:1:0.5', '--y', 'vertical_velocity_gain=0'], 2,
         "state_feedback has no parameter 'nosuch'"),
        (['gainmap', '--x', 'pitch_rate_gain=-1:0:1e-9', '--y', 'vertical_velocity_gain=0'], 2,
         "--x pitch_rate_gain='-1:0:1e-9' has 1e+09 values; the limit is 100000"),
        (['gainmap', '--x', 'pitch_rate_gain=-1:0:0.0001', '--y',
          'vertical_velocity_gain=-0.2:0.3:0.0001'], 2,
         'the gain map has 5.0015e+07 points; the limit is 1e+06'),
        (['gainmap', '--x', 'pitch_rate_gain=-1,inf', '--y', 'vertical_velocity_gain=0'], 2,
         '--x pitch_rate_gain value=inf is outside the allowed range'),
        ([*gm, '--duration', '1e9'], 2, 'integration steps per run; the limit is 1e+09'),
        ([*gm, '--duration', '0'], 2, '--duration=0 is outside the allowed range (0, inf) s'),
        ([*gm, '--transient', '3'], 2, '--transient=3 s must be shorter than --duration=2 s'),
        ([*gm, '--control-period', '-1'], 2,
         '--control-period=-1 is outside the allowed range [0, inf) s'),
        ([*gm, '--control-period', '3e-5'], 2, 'must be a whole multiple of the integration step'),
        ([*gm, '--settle-band', '0'], 2, '--settle-band=0 is outside the allowed range (0, 1]'),
        ([*gm, '--alpha', '2'], 2, '--alpha: fractional_order=2.0 is outside the allowed range'),
        ([*gm, '--speed', '-1'], 2, '--speed: speed=-1.0 is outside the allowed range (0, inf)'),
        ([*gm, '--envelope-speeds', '0:100:50'], 2,
         '--envelope-speeds: speed=0.0 is outside the allowed range (0, inf) m/s'),
        ([*gm, '--envelope-alphas', '0.5:1.5:0.5'], 2,
         '--envelope-alphas: fractional_order=1.5 is outside the allowed range (0, 1]'),
        ([*gm, '--chunk-size', '0'], 2, '--chunk-size=0 is outside the allowed range [1, 100000]'),
        ([*gm, '--workers', '1000'], 2, '--workers=1000 is outside the allowed range'),
        ([*gm, '--scheduler', nobody], 2, 'no Dask scheduler answers there'),
        ([*gm, '--check-step', '-1'], 2, '--check-step=-1 is outside the allowed range [0, inf)'),
        ([*gm, '--set', 'speed=1e308'], 2, 'the model cannot be evaluated at speed=1e+308'),
        ([*gm, '--speed', '80', '--set', 'speed=75'], 2,
         '--set speed=75.0 and --speed both set speed'),
        # -- plot --
        (['plot'], 2, 'the following arguments are required: bags'),
        (['plot', bag, '--name', '../../escape'], 2,
         "--name='../../escape' must be a plain name"),
        (['plot', bag, '--name', 'sub/dir'], 2, "--name='sub/dir' must be a plain name"),
        (['plot', bag, '--skip', '-1'], 2, '--skip=-1 is outside the allowed range [0, inf) s'),
        (['plot', bag, '--skip', '5'], 2,
         '--skip=5 s leaves nothing of', ),
        (['plot', bag, '--out', afile], 2, f'--out {afile}: exists and is not a folder'),
        (['plot', bag, '--out', str(taken)], 2,
         f'{taken / "run_time.png"} exists and {taken / "job.json"} does not say this job '
         'wrote it'),
        (['plot', str(tmp / 'no_such_bag')], 1, str(tmp / 'no_such_bag')),
        # -- report --
        (['report', '--workers', '-1'], 2, '--workers=-1 is outside the allowed range [0, '),
        (['report', '--scheduler', nobody], 2, 'no Dask scheduler answers there'),
        (['report', '--out', afile], 2, 'exists and is not a folder'),
        (['report', '--bogus'], 2, 'unrecognized arguments: --bogus'),
        # -- tune: the same Dask options and limits as sweep and gainmap --
        ([*tn, '--workers', '1000'], 2,
         f'--workers=1000 is outside the allowed range [0, {max_workers}] processes'),
        ([*tn, '--workers', '-1'], 2, '--workers=-1 is outside the allowed range'),
        ([*tn, '--scheduler', nobody], 2, 'no Dask scheduler answers there'),
        ([*tn, '--duration', '1e9'], 2,
         '--duration (1e+09 s simulated at step 2e-05 s) has 5e+13 integration steps per run; '
         'the limit is 1e+09'),
        ([*tn, '--chunk-size', '-5'], 2, '--chunk-size=-5 is outside the allowed range [1, '
         '100000] points'),
        ([*tn, '--budget', '100000000', '--population', '10000000'], 2,
         'one generation of the search (population x scenarios) has 1e+07 points; the limit '
         'is 1e+06'),
        ([*tn, '--control-period', '1e9'], 2,
         '--control-period=1e+09 s is longer than the run (--duration=2 s)'),
        ([*tn, '--settle-band', 'inf'], 2, '--settle-band=inf is outside the allowed range (0, 1]'),
        ([*tn, '--seed', '-1'], 2, '--seed=-1 is outside the allowed range [0, '),
        # -- fit, of a bag and of the delayed model --
        ([*fb, '--speeds', '75'], 2, '--speeds 75 is for --reference'),
        ([*fb, '--control-period', '0'], 2,
         '--control-period=0 is outside the allowed range (0, inf) s'),
        ([*fr, '--seed', '-1'], 2, '--seed=-1 is outside the allowed range [0, '),
        ([*fr, '--set', 'speed=80'], 2, '--set speed=80.0 is not used with --reference'),
        ([*fr, '--control-period', '3e-5'], 2,
         '--control-period=3e-05 s must be a whole multiple of the integration step 2e-05 s'),
        ([*fr, '--control-period', '2'], 2,
         '--control-period=2 s is longer than the run (--duration=1 s)'),
        ([*fb, '--workers', '1000'], 2, '--workers=1000 is outside the allowed range'),
        ([*fb, '--scheduler', nobody], 2, 'no Dask scheduler answers there'),
        ([*fb, '--population', '1000000000'], 2,
         '--population=1000000000 is outside the allowed range [2, 1e+06] points'),
        ([*fr, '--workers', '-1'], 2, '--workers=-1 is outside the allowed range'),
        ([*fr, '--scheduler', nobody], 2, 'no Dask scheduler answers there'),
        ([*fr, '--duration', '1e9'], 2,
         '--duration (1e+09 s simulated at step 2e-05 s) has 5e+13 integration steps'),
        ([*fr, '--chunk-size', '-5'], 2, '--chunk-size=-5 is outside the allowed range'),
        ([*fr, '--starts', '65'], 2,
         '--starts=65 is outside the allowed range [1, 64] points'),
        ([*fr, '--profile-points', '1000000000'], 2,
         '--profile-points=1000000000 is outside the allowed range [3, 100000] points'),
        # -- check, repair --
        (['check'], 2, 'fohssv check: error: the following arguments are required: bag'),
        (['check', bag, bag], 2, f'fohssv: error: unrecognized arguments: {bag}'),
        (['check', str(tmp / 'no_such_bag')], 1, str(tmp / 'no_such_bag')),
        (['repair'], 2, 'fohssv repair: error: the following arguments are required: bag'),
        (['repair', str(tmp / 'no_such_bag')], 1, str(tmp / 'no_such_bag')),
    ]


def files_under(path: Path) -> set[Path]:
    return {p for p in path.rglob('*')}


def run_in_process(argv: list[str], capfd) -> tuple[int, str]:
    code, _, err = fohssv(capfd, *argv)
    return code, err


def test_every_bad_input_of_every_subcommand_is_one_line_and_refused(tmp_path, monkeypatch,
                                                                     capfd):
    """Each row: its exit code, exactly one line on stderr holding the row's words, no
    traceback, and no file written (run from an empty folder: no reports/ appears)."""
    inputs = tmp_path / 'inputs'
    inputs.mkdir()
    cases = catalogue(inputs)
    work = tmp_path / 'cwd'
    work.mkdir()
    monkeypatch.chdir(work)
    before = files_under(inputs)
    failures = []
    for argv, code, words in cases:
        started = time.monotonic()
        got, err = run_in_process(argv, capfd)
        lines = err.strip().splitlines()
        if got != code or len(lines) != 1 or words not in err or 'Traceback' in err:
            failures.append(f'{argv}: exit {got} (want {code}), stderr {err!r} (want one line '
                            f'with {words!r})')
        if time.monotonic() - started > 30:
            failures.append(f'{argv}: took {time.monotonic() - started:.0f} s to refuse')
        if list(work.iterdir()) or files_under(inputs) != before:
            failures.append(f'{argv}: wrote {sorted(map(str, files_under(work)))} '
                            f'{sorted(map(str, files_under(inputs) - before))}')
            for p in sorted(files_under(work), reverse=True):
                p.rmdir() if p.is_dir() else p.unlink()
            before = files_under(inputs)
    assert not failures, '\n'.join(failures)
    assert {argv[0] for argv, _, _ in cases if argv} >= {
        'stability', 'sweep', 'gainmap', 'plot', 'report', 'check', 'repair', 'tune', 'fit'}


def test_the_installed_script_refuses_in_one_line_too(tmp_path):
    """A sample of the catalogue through the console script (real processes, concurrently):
    same exit code and line; the unreachable scheduler is refused within seconds."""
    cases = catalogue(tmp_path)
    picked = [c for c in cases if c[0][:1] == ['stability']][:1] + [
        c for c in cases if '--scheduler' in c[0] and 'sweep' in c[0]][:1] + [
        c for c in cases if c[0][:1] == ['check']][-1:]
    started = time.monotonic()
    procs = [(c, subprocess.Popen([str(FOHSSV), *c[0]], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, cwd=tmp_path))
             for c in picked]
    for (argv, code, words), proc in procs:
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == code, (argv, err)
        assert len(err.strip().splitlines()) == 1 and words in err, (argv, err)
        assert 'Traceback' not in err
    assert time.monotonic() - started < 90     # each refuses at start, not after a timeout
    assert not (tmp_path / 'reports').exists()


def test_output_names_never_leave_the_folder(tmp_path):
    """safe_name refuses every way out of the output folder; output_file refuses a link."""
    for bad in ('../x', 'a/b', '..', '.hidden', '-rf', '', 'a' * 121, '/etc/passwd', 'c:\\x',
                'a\x00b', 'x..y'):
        with pytest.raises(CliError):
            safe_name(bad)
    assert safe_name('run_V84.5+alpha=0.85') == 'run_V84.5+alpha=0.85'
    outside = tmp_path / 'outside.txt'
    outside.write_text('keep')
    (tmp_path / 'out').mkdir()
    (tmp_path / 'out' / 'run_summary.json').symlink_to(outside)
    with pytest.raises(CliError, match='symbolic link'):
        output_file(tmp_path / 'out', 'run_summary.json')
    assert outside.read_text() == 'keep'


@pytest.mark.parametrize('gain', ['depth_gain=1e308', 'pitch_gain=-1e308'])
def test_an_absurd_gain_in_a_gain_map_task_is_mapped_not_a_traceback(gain):
    """Issue 21: ``fohssv gainmap --gain depth_gain=1e308`` ended in exit 70 with a Dask
    worker's traceback: the equilibrium search of a point went where 1e308 z overflows, and
    NonFiniteCommand escaped the task. A gain in its allowed range (-inf, inf) is run: the
    task (what each Dask worker calls, run here in-process) classifies every point from its
    run and leaves the linearisation NaN where it cannot be found."""
    from fohssv_sim.analysis.gainmap import GainMapSpec, run_points

    name, value = gain.split('=')
    spec = GainMapSpec(controller='state_feedback', gain_x='pitch_rate_gain',
                       x_values=(-0.4, -0.2), gain_y='vertical_velocity_gain',
                       y_values=(0.0,), gains={name: float(value)}, duration=0.05,
                       transient=0.01)
    spec.validate()
    rows = run_points(spec.to_dict(), list(range(spec.n_points)))
    assert len(rows) == 2
    assert all(r['outcome'] in ('steady', 'periodic', 'chaotic', 'diverged', 'drifting')
               for r in rows), rows
    assert all(math.isnan(r['alpha_c']) for r in rows), rows
