"""The plant's entry loads scipy.linalg.cython_blas without the scipy.linalg package
(ros/entry.py): in a new process, numba then loads the plant's kernels and its own BLAS
calls work, scipy.linalg is not imported, and a later import of it (the LQR's) works and
takes the same module. The numbers are checked against numpy's own."""

from __future__ import annotations

import subprocess
import sys

_SCRIPT = '''
import sys
import numpy as np
from fohssv_sim.ros import entry
entry.blas_alone()
blas = sys.modules['scipy.linalg.cython_blas']
import numba
from fohssv_sim import models
from fohssv_sim.params import ModelParameters
models.make_plant(ModelParameters(), duration=0.01).compile()
assert 'scipy.linalg' not in sys.modules, 'scipy.linalg imported'

@numba.njit
def product(a, b):
    return a @ b

a = np.arange(9.0).reshape(3, 3)
assert np.array_equal(product(a, a.T), a @ a.T)
import scipy.linalg
from scipy.linalg import cython_blas
assert cython_blas is blas
x = scipy.linalg.solve_continuous_are(np.eye(2), np.eye(2), np.eye(2), np.eye(2))
assert np.allclose(x, (1 + np.sqrt(2)) * np.eye(2))
print('ok')
'''


def test_numba_and_scipy_linalg_work_with_the_blas_module_alone():
    done = subprocess.run([sys.executable, '-c', _SCRIPT], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == 'ok', done.stderr[-2000:]
