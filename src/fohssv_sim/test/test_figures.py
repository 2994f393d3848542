"""What the analysis figures say, read back from the saved files (PNG ``Title`` text chunk,
written from the figure's visible titles) and from the figures' matplotlib objects."""

from __future__ import annotations

import math

import numpy as np
from PIL import Image

from fohssv_controller.state_feedback import StateFeedback
from fohssv_sim.analysis.diagrams import plot_alpha_v, plot_orbit_diagram
from fohssv_sim.analysis.figures import QUICK_LABEL
from fohssv_sim.analysis.stability import (
    critical_order_curve,
    plot_critical_order,
    plot_wedge,
)
from fohssv_sim.analysis.sweep import SweepResult
from fohssv_sim.equilibria import find_equilibria
from fohssv_sim.params import ModelParameters


def _png_title(path) -> str:
    with Image.open(path) as im:
        return im.text.get('Title', '')


def _row(i, alpha, speed, kind, maxima):
    return {'point': i, 'alpha': alpha, 'speed': speed, 'label': kind, 'kind': kind,
            'period': 1 if kind == 'periodic' else 0, 'k01': math.nan, 'amplitude': 0.1,
            'n_maxima': len(maxima), 'failed': False, 'step_check': '', 'maxima': maxima}


def _sweep(rows, alphas, speeds, model='fractional'):
    spec = {'alphas': list(alphas), 'speeds': list(speeds), 'state': 'w', 'transient': 1.5,
            'window': 0.5, 'control_period': None}
    side = {'spec': spec, 'model': model, 'solver': 'soe' if model == 'fractional' else 'rk4',
            'step': 2e-5}
    return SweepResult(rows, side)


def test_orbit_diagrams_name_the_fixed_parameter_and_the_unit_of_w(tmp_path):
    rows = [_row(0, 0.7, 84.5, 'steady', [1.87]),
            _row(1, 0.8, 84.5, 'periodic', [2.1, 2.1, 2.1])]
    fig = plot_orbit_diagram(_sweep(rows, (0.7, 0.8), (84.5,)), 'alpha', [tmp_path / 'a.png'])
    ax = fig.axes[0]
    assert ax.get_ylabel() == 'local maxima of w (m/s)'
    assert ax.get_title().startswith('Orbit diagram at V = 84.5 m/s\n')
    assert _png_title(tmp_path / 'a.png') == ax.get_title()
    rows = [_row(0, 0.85, 75.0, 'periodic', [2.0]), _row(1, 0.85, 80.0, 'periodic', [2.2])]
    fig = plot_orbit_diagram(_sweep(rows, (0.85,), (75.0, 80.0)), 'speed',
                             [tmp_path / 'v.png'], QUICK_LABEL)
    title = _png_title(tmp_path / 'v.png')
    assert title.startswith(QUICK_LABEL + '\nOrbit diagram at α = 0.85\n'), title
    rows = [_row(0, 1.0, 75.0, 'periodic', [2.0])]
    fig = plot_orbit_diagram(_sweep(rows, (1.0,), (75.0,), 'delay-free'), 'speed',
                             [tmp_path / 'd.png'])
    title = fig.axes[0].get_title()
    assert title.startswith('Orbit diagram\ndelay-free model') and 'α' not in title


def _legend(fig):
    return [t.get_text() for t in fig.axes[0].get_legend().get_texts()]


def test_alpha_v_legend_lists_alpha_star_only_when_it_is_drawn(tmp_path):
    # at V = 75 the orbits change from steady to periodic between alpha 0.7 and 0.8 (a
    # drifting point between them is neither side and is skipped); at 80 they never do
    rows = [_row(0, 0.7, 75.0, 'steady', [1.8]), _row(4, 0.75, 75.0, 'drifting', [1.9]),
            _row(1, 0.8, 75.0, 'periodic', [2.0]),
            _row(2, 0.7, 80.0, 'periodic', [2.0]), _row(3, 0.8, 80.0, 'periodic', [2.0])]
    fig = plot_alpha_v(_sweep(rows, (0.7, 0.75, 0.8), (75.0, 80.0)), [tmp_path / 'm.png'])
    label = 'α*(V): steady → oscillating'
    assert label in _legend(fig)
    (star,) = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == label]
    # one speed only: a line alone would draw nothing, the marker shows the point
    assert star.get_marker() not in ('', 'None', None)
    assert list(star.get_xdata()) == [75.0] and list(star.get_ydata()) == [0.75]
    rows = [_row(0, 0.7, 75.0, 'periodic', [2.0]), _row(1, 0.8, 75.0, 'periodic', [2.0])]
    fig = plot_alpha_v(_sweep(rows, (0.7, 0.8), (75.0,)), [tmp_path / 'n.png'], label='x')
    assert label not in _legend(fig)
    assert 'α*(V): no steady-oscillating change on the grid' in _legend(fig)
    assert not [ln for ln in fig.axes[0].get_lines() if len(ln.get_xdata())]


def test_wedge_shows_its_speed_and_critical_order_plot_has_a_title(tmp_path):
    p = ModelParameters(speed=84.5)
    (eq,) = find_equilibria(p, StateFeedback())
    fig = plot_wedge(eq, 0.7, [tmp_path / 'w.png'], speed=p.speed)
    assert 'V = 84.5 m/s, α = 0.7' in fig.axes[0].get_title()
    assert 'V = 84.5 m/s' in _png_title(tmp_path / 'w.png')
    curve = critical_order_curve(p, StateFeedback(), [80.0, 84.5])
    fig = plot_critical_order(curve, [tmp_path / 'c.png'], 0.85, caption='eq. 31',
                              label=QUICK_LABEL)
    title = _png_title(tmp_path / 'c.png')
    assert title == fig.axes[0].get_title()
    assert title.splitlines() == [QUICK_LABEL, 'Critical order α_c(V) of the closed-loop '
                                  'equilibrium (Matignon, eq. 30)', 'eq. 31']
    assert np.isclose(fig.axes[0].get_lines()[0].get_ydata()[1], eq.critical_order)
