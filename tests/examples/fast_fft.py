import numba
import numpy as np

from fohssv_sim.fractional import solve_abm_fft

A = np.array([[-1.0, 2.0], [-2.0, -1.0]])
B = np.array([0.0, 1.0])


@numba.njit                    # compiled rhs: solve_abm_fft then runs its inner loop compiled
def rhs(t, x, u):              # D^0.85 x = A x + B u
    return A @ x + B * u[0]


u = np.zeros((100_000, 1))     # one input row per step (here zero: the free response)
sol = solve_abm_fft(rhs, alpha=0.85, step=1e-4, x0=[1.0, 0.0], n_steps=100_000, u=u)
t, x = sol.t, sol.x           # (100001,), (100001, 2): the ABM numbers, 0.2 s once compiled
