"""Compiled (numba) inner loop of :func:`~.fft.solve_abm_fft`, used when rhs is compiled too.

The FFT-blocked solver spends almost all its time in the short base blocks, where each step
calls rhs twice and sums the lags inside the block directly. With a plain Python rhs that loop
is interpreted (two rhs calls and a handful of tiny numpy operations per step). When rhs is a
numba ``@njit`` function, the whole base block runs compiled: :func:`base_block` below, the
same arithmetic as the Python base block (summation order differs only inside the block, so the
two agree to rounding; tested against :class:`~.abm.ABMStepper` to 1e-12).

numba is imported lazily: without numba installed every solver still works, interpreted.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ['available', 'is_compiled', 'base_block', 'OK', 'NONFINITE',
           'SHAPE']


@lru_cache(maxsize=1)
def _numba():
    try:
        import numba
    except ImportError:          # optional at run time; pinned in requirements.txt
        return None
    return numba


def available() -> bool:
    """True when numba can be imported."""
    return _numba() is not None


def is_compiled(fn) -> bool:
    """True when ``fn`` is a numba CPU dispatcher compiled in nopython mode (``@njit``, or
    ``@jit`` without ``forceobj``)."""
    nb = _numba()
    if nb is None:
        return False
    from numba.core.registry import CPUDispatcher
    return isinstance(fn, CPUDispatcher) and not fn.targetoptions.get('forceobj', False)


# status codes returned by the base block (with the step index and, for SHAPE, the length)
OK, NONFINITE, SHAPE = 0, 1, 2


def _base_block_py(rhs, lo, hi, t0, h, x0, acc, cp, cc, WR, G, X, U, seq):
    """Advance steps lo..hi-1 of the ABM scheme (see fft.solve_abm_fft's base block).

    acc[n] holds the unscaled history sums of step n over j < lo (and the j = 0 terms);
    WR[B-1-k] = (cp b(k), cc c(k)); G[j] = f_j (G[0] = 0); U is (1, du) (constant input) or
    (N, du) with ``seq`` true. Returns (status, step, length): (OK, -1, 0); (NONFINITE, n, 0)
    with n the first step whose state is not finite; (SHAPE, n, L) when rhs returned L values
    instead of d while computing step n (nothing of that evaluation is used).
    """
    B = WR.shape[0]
    d = x0.shape[0]
    xn = X[lo].copy()
    xp = np.empty(d)
    xc = np.empty(d)
    for i in range(hi - lo):
        n = lo + i
        un = U[n] if seq else U[0]
        if n > 0:
            f = rhs(t0 + n * h, xn, un)
            if f.shape[0] != d:
                return SHAPE, n, f.shape[0]
            for k in range(d):
                G[n, k] = f[k]
        off = B - 1 - i
        for k in range(d):
            sp = 0.0
            sc = 0.0
            for m in range(i + 1):
                g = G[lo + m, k]
                sp += WR[off + m, 0] * g
                sc += WR[off + m, 1] * g
            xp[k] = sp + (x0[k] + cp * acc[n, 0, k])
            xc[k] = sc + (x0[k] + cc * acc[n, 1, k])
        fp = rhs(t0 + (n + 1) * h, xp, un)
        if fp.shape[0] != d:
            return SHAPE, n + 1, fp.shape[0]
        bad = False
        for k in range(d):
            v = xc[k] + cc * fp[k]
            xn[k] = v
            X[n + 1, k] = v
            if not np.isfinite(v):
                bad = True
        if bad:
            return NONFINITE, n + 1, 0
    return OK, -1, 0


@lru_cache(maxsize=1)
def _compiled_base_block():
    nb = _numba()
    return nb.njit(cache=False, nogil=True)(_base_block_py)


def base_block(rhs, lo, hi, t0, h, x0, acc, cp, cc, WR, G, X, U, seq) -> tuple:
    """Compiled base block (numba); ``rhs`` must be a numba dispatcher. See _base_block_py."""
    return _compiled_base_block()(rhs, lo, hi, t0, h, x0, acc, cp, cc, WR, G, X, U, seq)
