"""The 4-state linear test problem shared by the fractional-solver tests (bench_fractional.py
uses the same A4 and X4): D^a x = A4 x + B4 u, x(0) = X4, a lightly coupled oscillator
(eigenvalues of the upper block -1 +- 2i) and a damped pair."""

import numpy as np

A4 = np.array([[-1.0, 2.0, 0.0, 0.0],
               [-2.0, -1.0, 0.0, 0.5],
               [0.0, 0.0, -3.0, 1.0],
               [0.1, 0.0, -1.0, -0.5]])
B4 = np.array([[0.0], [1.0], [0.0], [1.0]])
X4 = np.array([1.0, 0.5, -0.3, 0.2])
