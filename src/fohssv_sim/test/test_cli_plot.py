"""`fohssv plot` on a real bag holding a simulated run (rosbag2 + MCAP written and read back).

One bad bag runs the installed ``fohssv`` script, as a user runs it; the other commands run
in-process through :func:`fohssv_sim.cli.main` (the same parser and commands: a new
interpreter importing numpy, numba, scipy and matplotlib for each would cost more than the
command itself)."""

import json
import subprocess
from pathlib import Path

import numpy as np
from ament_index_python.packages import get_package_prefix
from clirun import fohssv as run_cli

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim import contract
from fohssv_sim.analysis.orbits import local_maxima
from fohssv_sim.bag.synthetic import clock, float64_array
from fohssv_sim.bag.writer import RunWriter
from fohssv_sim.params import ModelParameters
from fohssv_sim.simulate import simulate

FOHSSV = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'fohssv'


def fohssv(argv, capfd) -> tuple[int, str]:
    """``fohssv ARGV`` in this process: (exit code, stderr)."""
    code, _, err = run_cli(capfd, *argv)
    return code, err


def record(path, run, params):
    w = RunWriter(path).open()
    for topic in contract.TOPICS:
        w.add_topic(topic.name if topic.name.startswith('/') else '/' + topic.name, topic.type)
    w.add_metadata({'fohssv.plant_parameters': {**params.to_dict(), 'control_period': None}})
    for i, t in enumerate(run.t):
        ns = round(t * 1e9)
        w.write('/clock', ns, clock(ns))
        w.write('/state', ns, float64_array(contract.STATE, [t, *run.state[i]]))
        w.write('/planing_force', ns, float64_array(contract.PLANING_FORCE,
                                                    [t, run.planing_force[i]]))
        w.write('/command', ns, float64_array(contract.COMMAND, [t, *run.inputs[i]]))
    w.close()


def test_plot_overlays_bags_and_summarises_them(tmp_path, capfd):
    p = ModelParameters(model='delay-free')
    run = simulate(p, StateFeedback(), 1.0, sample_every=20)
    record(tmp_path / 'a', run, p)
    q = ModelParameters(model='delayed')
    run2 = simulate(q, StateFeedback(), 1.0, sample_every=20)
    record(tmp_path / 'b', run2, q)
    code, err = fohssv(['plot', tmp_path / 'a', tmp_path / 'b', '--out', tmp_path / 'fig',
                        '--skip', '0.5'], capfd)
    assert code == 0, err
    for name in ('run_time.png', 'run_time.svg', 'run_phase.png', 'run_phase.svg'):
        assert (tmp_path / 'fig' / name).stat().st_size > 10_000
    s = json.loads((tmp_path / 'fig' / 'run_summary.json').read_text())[str(tmp_path / 'a')]
    assert s['samples'] == run.t.size
    last = run.t >= 0.5
    assert s['w_peak_to_peak'] == np.ptp(run.state[last, 1])   # bit-exact through the bag
    assert s['peak_abs_planing_force'] == np.abs(run.planing_force).max()
    # second method: the period between successive maxima of w
    tm, _ = local_maxima(run.t[last], run.state[last, 1])
    f_peaks = 1.0 / np.median(np.diff(tm))
    assert abs(s['w_dominant_frequency_hz'] - f_peaks) <= s['frequency_resolution_hz']


def test_plot_bad_bags_exit_1_like_check_without_traceback(tmp_path, capfd):
    """A missing or unreadable bag: one line and exit 1 from plot, check and repair alike
    (2 is for bad options); the first case through the installed script too."""
    (tmp_path / 'empty').mkdir()
    (tmp_path / 'junk.mcap').write_bytes(b'not an mcap file at all')
    script = subprocess.run([str(FOHSSV), 'plot', str(tmp_path / 'junk.mcap'), '--out',
                             str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert script.returncode == 1 and len(script.stderr.strip().splitlines()) == 1, (
        script.stderr)
    assert 'Traceback' not in script.stderr and str(tmp_path / 'junk.mcap') in script.stderr
    for bad in ('missing', 'empty', 'junk.mcap'):
        for command in (['plot', str(tmp_path / bad), '--out', str(tmp_path)],
                        ['check', str(tmp_path / bad)], ['repair', str(tmp_path / bad)]):
            code, err = fohssv(command, capfd)
            assert code == 1, (command, err)
            assert 'Traceback' not in err and str(tmp_path / bad) in err
            assert len(err.strip().splitlines()) == 1, err


def test_plot_out_an_existing_file_is_one_line_and_exit_2(tmp_path, capfd):
    p = ModelParameters(model='delay-free')
    record(tmp_path / 'a', simulate(p, StateFeedback(), 0.05, sample_every=20), p)
    (tmp_path / 'taken.png').write_bytes(b'mine')
    code, err = fohssv(['plot', tmp_path / 'a', '--out', tmp_path / 'taken.png'], capfd)
    assert code == 2, err
    assert 'exists and is not a folder' in err and 'Traceback' not in err
    assert len(err.strip().splitlines()) == 1
    assert (tmp_path / 'taken.png').read_bytes() == b'mine'


def test_plot_a_bag_with_two_namespaces_by_namespace(tmp_path, capfd):
    """Two vehicles in one bag: without --namespace the error names both namespaces; with it
    the one named plots, and its summary is that vehicle's run (not the first one's)."""
    runs = {}
    w = RunWriter(tmp_path / 'two').open()
    for ns, model in (('/v1', 'delay-free'), ('/v2', 'delayed')):
        runs[ns] = simulate(ModelParameters(model=model), StateFeedback(), 0.3,
                            sample_every=20)
        for topic in (contract.STATE, contract.PLANING_FORCE, contract.COMMAND):
            w.add_topic(f'{ns}/{topic.name}', topic.type)
    for ns, run in runs.items():
        for i, t in enumerate(run.t):
            ns_t = round(t * 1e9)
            w.write(f'{ns}/state', ns_t, float64_array(contract.STATE, [t, *run.state[i]]))
            w.write(f'{ns}/planing_force', ns_t, float64_array(
                contract.PLANING_FORCE, [t, run.planing_force[i]]))
            w.write(f'{ns}/command', ns_t, float64_array(contract.COMMAND,
                                                         [t, *run.inputs[i]]))
    w.close()
    code, err = fohssv(['plot', tmp_path / 'two', '--out', tmp_path / 'fig'], capfd)
    assert code == 1 and 'one of /v1, /v2' in err and '--namespace' in err, err
    for ns, run in list(runs.items())[1:]:      # the second vehicle (the first is the default)
        fig = tmp_path / f'fig{ns.strip("/")}'
        code, err = fohssv(['plot', tmp_path / 'two', '--namespace', ns, '--out', fig], capfd)
        assert code == 0, err
        s = json.loads((fig / 'run_summary.json').read_text())[str(tmp_path / 'two')]
        assert s['samples'] == run.t.size


def test_plot_titles_name_the_controller_and_step_zoom_the_last_cycles(tmp_path):
    """The time-response figure (read back from the saved PNG's Title and the SVG's text):
    title with the controller (recorded by the recorder as fohssv.controller) and the step
    ('auto' resolved to the model's 1e-5 s), a zoom on the last cycles of the 36 Hz delay-free
    tail slap (four periods, from the spectrum), and the legend below the plots."""
    import matplotlib
    from PIL import Image

    from fohssv_sim.analysis.plots import plot_phase_portrait, plot_time_responses, zoom_window
    from fohssv_sim.bag import load_run

    p = ModelParameters(model='delay-free')
    run = simulate(p, StateFeedback(), 1.0, sample_every=20)
    w = RunWriter(tmp_path / 'a').open()
    for topic in contract.TOPICS:
        w.add_topic(topic.name if topic.name.startswith('/') else '/' + topic.name, topic.type)
    w.add_metadata({'fohssv.plant_parameters': {**p.to_dict(), 'control_period': 1e-4},
                    'fohssv.controller': 'state_feedback', 'fohssv.controller_node': '/c'})
    for i, t in enumerate(run.t):
        ns = round(t * 1e9)
        w.write('/state', ns, float64_array(contract.STATE, [t, *run.state[i]]))
        w.write('/planing_force', ns, float64_array(contract.PLANING_FORCE,
                                                    [t, run.planing_force[i]]))
        w.write('/command', ns, float64_array(contract.COMMAND, [t, *run.inputs[i]]))
    w.close()
    bag = load_run(tmp_path / 'a')
    tm, _ = local_maxima(run.t[run.t >= 0.5], run.state[run.t >= 0.5, 1])
    period = float(np.median(np.diff(tm)))                        # second method: the maxima
    z0, z1 = zoom_window(bag)
    assert z1 == run.t[-1] and abs((z1 - z0) - 4 * period) < 0.1 * period
    with matplotlib.rc_context({'svg.fonttype': 'none'}):         # text stays text in SVG
        plot_time_responses([bag], [tmp_path / 't.png', tmp_path / 't.svg'])
        plot_phase_portrait([bag], [tmp_path / 'p.png'], 0.5)
    with Image.open(tmp_path / 't.png') as im:
        title = im.text['Title']
    assert title.splitlines()[0] == ('Time responses: controller state_feedback, h=1e-05 s, '
                                     'ZOH 0.0001 s')
    assert f'zoom: last {z1 - z0:.3g} s' in title
    with Image.open(tmp_path / 'p.png') as im:
        assert 'controller state_feedback, h=1e-05 s' in im.text['Title']
    svg = (tmp_path / 't.svg').read_text()
    assert 'a: controller state_feedback, delay-free, V=75, h=1e-05 s, ZOH 0.0001 s' in svg
