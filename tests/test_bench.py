"""The benchmarks still start and run: each one's tiny case (``scripts/bench.py --quick``), so
a benchmark that no longer runs fails the build; and the results file the full run writes."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = sorted(p.stem.removeprefix('bench_') for p in (ROOT / 'bench').glob('bench_*.py'))

_spec = importlib.util.spec_from_file_location('bench_runner', ROOT / 'scripts' / 'bench.py')
runner = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(runner)
_spec = importlib.util.spec_from_file_location('benchutil', ROOT / 'bench' / 'benchutil.py')
benchutil = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(benchutil)


@pytest.mark.graph      # some benchmarks start nodes, a writer process or a Dask cluster
@pytest.mark.bench_smoke    # minutes of CPU: `make bench-smoke` (CI runs it after `make test`)
@pytest.mark.parametrize('name', BENCHMARKS)
def test_each_benchmark_runs_its_quick_case(name, tmp_path):
    out = subprocess.run([sys.executable, str(ROOT / 'scripts' / 'bench.py'), '--quick',
                          '--only', name, '--out-dir', str(tmp_path)],
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    summary = json.loads((tmp_path / 'summary.json').read_text())
    assert summary[name]['returncode'] == 0
    assert isinstance(json.loads((tmp_path / f'{name}.json').read_text()), dict)


def test_an_unknown_benchmark_name_is_refused_with_exit_2(capsys):
    assert runner.main(['--only', 'nosuch', '--out-dir', '/nonexistent-never-made']) == 2
    assert 'nosuch' in capsys.readouterr().err


def test_the_results_file_lists_each_figure_with_its_target_and_the_echo(tmp_path):
    # two benchmarks' JSON as they write it: benchutil's rows and bench_ros's rows
    (tmp_path / 'simulate.json').write_text(json.dumps({'figures': [
        ['model', 'keep 1'], ['fractional', '0.0123']], 'targets': [
        {'name': 'fractional: simulate keep 1 / keep 50', 'measured': 1.2, 'op': '<=',
         'goal': 1.5, 'met': True}]}))
    (tmp_path / 'ros.json').write_text(json.dumps({
        'echo': {'round_trips_per_second': 4321.0},
        'targets': [{'target': 'lockstep FOM / echo', 'text': '0.61', 'goal': '>= 0.5',
                     'pass': True}]}))
    summary = {'simulate': {'returncode': 0, 'seconds': 3.0},
               'ros': {'returncode': 1, 'seconds': 9.0}}
    text = runner.results_markdown(summary, tmp_path, 'make bench', '2026-01-01 00:00 UTC',
                                   (0.5, 0.7))
    assert '- command: `make bench`' in text and '2026-01-01 00:00 UTC' in text
    assert "4321 round trips/s" in text and f"{os.cpu_count()} CPUs" in text
    assert '| fractional: simulate keep 1 / keep 50 | 1.2 | <= 1.5 | yes |' in text
    assert '| model | keep 1 |' in text and '| fractional | 0.0123 |' in text
    assert '| lockstep FOM / echo | 0.61 | >= 0.5 | yes |' in text
    assert '## ros (bench/bench_ros.py: FAILED, exit 1, 9 s)' in text


def test_host_steal_share_from_two_proc_stat_readings(tmp_path):
    """/proc/stat's cpu line: user nice system idle iowait irq softirq steal guest guest_nice
    (guest time is already inside user, so it is not added again)."""
    stat = tmp_path / 'stat'
    stat.write_text('cpu  100 5 40 800 10 0 5 40 30 0\ncpu0 50 2 20 400 5 0 2 20 15 0\n')
    before = benchutil.host_cpu_ticks(str(stat))
    assert before == (1000, 40)
    stat.write_text('cpu  150 5 60 1000 10 0 5 70 60 0\n')
    after = benchutil.host_cpu_ticks(str(stat))
    assert after == (1300, 70)
    assert benchutil.steal_share(before, after) == pytest.approx(30 / 300)
    assert benchutil.steal_share(after, after) is None
    assert benchutil.steal_share(None, after) is None
    # 30 ticks of 1 / SC_CLK_TCK s stolen (0.3 s of CPU time at Linux's 100 Hz)
    steal = benchutil.steal_seconds
    assert steal(before, after) == pytest.approx(30 / os.sysconf('SC_CLK_TCK'))
    assert steal(None, after) is None and steal(after, after) == 0.0
    stat.write_text('intr 1 2 3\n')
    assert benchutil.host_cpu_ticks(str(stat)) is None
    assert benchutil.host_cpu_ticks(str(tmp_path / 'missing')) is None
    real = benchutil.host_cpu_ticks()      # this machine's, where Linux gives it
    assert real is None or (real[0] > 0 and 0 <= real[1] <= real[0])
