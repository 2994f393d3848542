"""Coefficients against an independently derived table (docs/model.md §6 is rendered from
the numbers asserted here)."""

import math
import re
from pathlib import Path

import numpy as np
import pytest

from fohssv_sim.coefficients import coefficients
from fohssv_sim.params import ModelParameters

ROOT = Path(__file__).resolve().parents[3]

# An independent evaluation of docs/model.md §3.2, §3.3 at L = 1.8: quantity -> (V = 75, 84.5)
TABLE = {
    'C': (0.0596981, 0.0596981),
    'S': (1.064473, 1.064473),
    'T': (9.485546, 9.485546),
    'a22': (-9.81188, -11.05472),
    'a24': (79.94277, 90.06885),
    'a42': (6.78343, 7.64267),
    'a44': (-5.83965, -6.57934),
    'b21': (205.948, 261.426),
    'b22': (-941.841, -1195.552),
    'b41': (-243.319, -308.863),
    'b42': (752.076, 954.669),
    'd2': (-1.22660, -1.22660),
    'd4': (1.44918, 1.44918),
    'K1': (0.544932, 0.544932),
    'K2': (0.889795, 0.889795),
    'Rc': (0.0901755, 0.0901755),
    'R_prime': (0.775108, 0.775108),
    'Rc_dot': (-3.29655, -3.71411),
    'w0': (1.64064, 1.84846),
    'tau': (0.024000, 0.021302),
}
UNITS = {'C': '–', 'S': 'm²', 'T': '1/m²', 'a22': '1/s', 'a24': 'm/s', 'a42': '1/(m s)',
         'a44': '1/s', 'b21': 'm/s²', 'b22': 'm/s²', 'b41': '1/s²', 'b42': '1/s²', 'd2': '1/m',
         'd4': '1/m²', 'K1': '–', 'K2': '–', 'Rc': 'm', 'R_prime': '–', 'Rc_dot': 'm/s',
         'w0': 'm/s', 'tau': 's'}


def coefficient_table_markdown() -> str:
    """The table of docs/model.md §6, from :data:`TABLE` (the numbers asserted below)."""
    rows = ['| quantity | V = 75 | V = 84.5 | unit |', '|---|---|---|---|']
    rows += [f'| `{k}` | {v75!r} | {v84!r} | {UNITS[k]} |' for k, (v75, v84) in TABLE.items()]
    return '\n'.join(rows)


@pytest.mark.parametrize('column,speed', [(0, 75.0), (1, 84.5)])
@pytest.mark.parametrize('name', sorted(TABLE))
def test_coefficient_matches_table_to_five_significant_digits(name, column, speed):
    c = coefficients(ModelParameters(speed=speed))
    expected = TABLE[name][column]
    # five significant digits: within half a unit of the fifth digit
    half_unit = 0.5 * 10.0 ** (math.floor(math.log10(abs(expected))) - 4)
    assert abs(getattr(c, name) - expected) <= half_unit


def test_model_doc_table_is_the_tested_table():
    doc = (ROOT / 'docs' / 'model.md').read_text()
    assert coefficient_table_markdown() in doc, coefficient_table_markdown()


def test_open_loop_eigenvalues_at_75():
    eig = np.sort_complex(np.linalg.eigvals(coefficients(ModelParameters()).A))
    assert np.allclose(eig, np.sort_complex(np.array([-31.197, 0, 0, 15.546])), atol=1e-3)


def test_consistent_w0_is_the_contact_velocity_and_numeric_w0_is_kept():
    c = coefficients(ModelParameters())
    assert c.w0 == pytest.approx(c.R_prime * c.R * c.V / c.L, rel=1e-15)
    assert coefficients(ModelParameters(planing_offset=2.8)).w0 == 2.8


def test_matrices_hold_the_scalars():
    c = coefficients(ModelParameters(speed=84.5))
    assert c.A[0, 2] == -84.5 and c.A[1, 1] == c.a22 and c.A[3, 3] == c.a44
    assert c.B[1, 0] == c.b21 and c.B[3, 1] == c.b42 and c.D[1] == c.d2 and c.G[1] == 9.81
    with pytest.raises(ValueError):
        c.A[0, 0] = 1.0   # read-only


@pytest.mark.parametrize('changes', [{'speed': 1e308}, {'speed': 5e153},
                                     {'fin_effectiveness': 1e308}])
def test_legal_values_whose_coefficients_overflow_are_refused_naming_them(changes):
    from fohssv_sim.params import ParameterError

    (name, value), = changes.items()
    words = re.escape(f'coefficients overflow with {name}={value!r}:')
    with pytest.raises(ParameterError, match=words):
        coefficients(ModelParameters(**changes))
