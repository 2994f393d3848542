"""Values the fractional solvers compute from scipy.special, kept on disk between processes.

A plant computes the same few values at every start: Gamma(alpha + 1), Gamma(alpha + 2) and
the SOE modes of its order (:mod:`.soe_kernel`). Importing scipy.special for them (with the
array-API layer it loads) and computing the modes cost a node about 0.2 s of CPU, more than
10 % of its start. :func:`stored` computes an array once and keeps it in ``__pycache__``
beside this file (where numba keeps the compiled kernels), one ``.npy`` file per key, so a
later process reads it back bit for bit without importing scipy.special. The file's name
hashes the key with the versions of numpy and scipy and the source of the modules that
compute the values, so a change to any of them computes anew; a file that cannot be read is
computed again, and where the folder cannot be written nothing is kept. At most
:data:`MAX_FILES` keys are kept (a sweep over many orders does not fill the folder).
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from collections.abc import Callable
from functools import cache, lru_cache
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ['stored', 'gamma', 'MAX_FILES']

#: Keys kept at most; beyond, values are computed in each process.
MAX_FILES = 64
#: The folder of the stored values (tests point it elsewhere).
FOLDER = Path(__file__).parent / '__pycache__'
_PREFIX = 'fohssv-stored-'


@cache
def _stamp() -> bytes:
    """The versions and sources the stored values depend on."""
    import scipy

    here = Path(__file__).parent
    parts = [np.__version__.encode(), scipy.__version__.encode()]
    parts += [(here / name).read_bytes() for name in ('_stored.py', 'soe_kernel.py')]
    return b'\0'.join(parts)


def stored(kind: str, key: tuple, compute: Callable[[], np.ndarray]) -> np.ndarray:
    """``compute()`` (a float64 array) for ``key``, read from the folder when a process
    stored it before, else computed and stored (see the module docstring)."""
    digest = hashlib.sha256(_stamp() + repr((kind, key)).encode()).hexdigest()[:32]
    path = FOLDER / f'{_PREFIX}{kind}-{digest}.npy'
    try:
        value = np.load(path, allow_pickle=False)
        if value.dtype == np.float64:
            return value
    except (OSError, ValueError, EOFError):
        pass
    value = np.asarray(compute(), dtype=np.float64)
    _keep(path, value)
    return value


def _keep(path: Path, value: np.ndarray) -> None:
    """Write ``value`` to ``path`` atomically (a whole file or none), unless the folder is
    full or not writable."""
    try:
        if len(list(FOLDER.glob(f'{_PREFIX}*.npy'))) >= MAX_FILES:
            return
        FOLDER.mkdir(exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=FOLDER, prefix=_PREFIX, suffix='.tmp')
        try:
            with os.fdopen(fd, 'wb') as f:
                np.save(f, value, allow_pickle=False)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:
        pass


def _scipy_gamma(x: Any) -> Any:
    from scipy.special import gamma as g

    return g(x)


@lru_cache(maxsize=256)
def _stored_gamma(x: float) -> np.float64:
    return stored('gamma', (x,), lambda: np.array([_scipy_gamma(x)]))[0]


def gamma(x: Any) -> Any:
    """scipy.special.gamma(x), the same numbers; a finite float's value is :func:`stored`."""
    if isinstance(x, float) and math.isfinite(x):
        return _stored_gamma(float(x))
    return _scipy_gamma(x)
