"""Values kept on disk between processes (fractional/_stored.py): what a later process reads
back is, bit for bit, what scipy.special and the SOE construction compute, a damaged file is
computed again, and a folder that cannot be written keeps nothing and changes nothing."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.special

from fohssv_sim.fractional import _stored, soe_kernel


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """An empty store, and no value remembered in this process."""
    monkeypatch.setattr(_stored, 'FOLDER', tmp_path)
    soe_kernel._soe_modes_cached.cache_clear()
    _stored._stored_gamma.cache_clear()
    yield tmp_path
    soe_kernel._soe_modes_cached.cache_clear()
    _stored._stored_gamma.cache_clear()


def _bits(modes) -> list[bytes]:
    return [a.tobytes() for a in (modes.s, modes.weight, modes.decay, modes.pred, modes.corr)]


def _computed(alpha: float) -> list[bytes]:
    """The modes computed here, without the store."""
    return [a.tobytes() for a in soe_kernel._mode_arrays(alpha, 16, 1e-10, 10**8)]


@pytest.mark.parametrize('alpha', [0.85, 0.9, 1.0])
def test_stored_modes_are_the_computed_ones(folder, monkeypatch, alpha):
    first = soe_kernel.soe_modes(alpha)
    assert _bits(first) == _computed(alpha)
    assert len(list(folder.glob('*.npy'))) == 1
    soe_kernel._soe_modes_cached.cache_clear()     # a new process: only the file remains

    def refuse(*args):
        raise AssertionError('computed again although stored')

    monkeypatch.setattr(soe_kernel, '_mode_arrays', refuse)
    again = soe_kernel.soe_modes(alpha)
    assert again is not first and _bits(again) == _bits(first)
    assert not any(a.flags.writeable for a in (again.s, again.decay, again.pred, again.corr))


@pytest.mark.parametrize('x', [1.9, 2.9, 1.85, 2.85, 1.5])
def test_stored_gamma_is_scipys(folder, x):
    expected = scipy.special.gamma(x)
    assert _stored.gamma(x).tobytes() == expected.tobytes()
    _stored._stored_gamma.cache_clear()
    assert _stored.gamma(x).tobytes() == expected.tobytes()      # read back
    arr = np.array([1.5, 2.5])                                   # arrays are not stored
    assert np.array_equal(_stored.gamma(arr), scipy.special.gamma(arr))
    assert len(list(folder.glob('*.npy'))) == 1


def test_a_damaged_file_is_computed_again(folder):
    expected = _computed(0.9)
    soe_kernel.soe_modes(0.9)
    (path,) = folder.glob('*.npy')
    path.write_bytes(path.read_bytes()[:100])
    soe_kernel._soe_modes_cached.cache_clear()
    assert _bits(soe_kernel.soe_modes(0.9)) == expected


def test_an_unwritable_folder_keeps_nothing(tmp_path, monkeypatch, folder):
    blocker = tmp_path / 'a_file'
    blocker.write_text('')
    monkeypatch.setattr(_stored, 'FOLDER', blocker / 'store')     # cannot be created
    assert _bits(soe_kernel.soe_modes(0.9)) == _computed(0.9)


def test_a_full_folder_keeps_nothing_more(folder, monkeypatch):
    monkeypatch.setattr(_stored, 'MAX_FILES', 1)
    soe_kernel.soe_modes(0.9)
    soe_kernel.soe_modes(0.8)
    assert len(list(folder.glob('*.npy'))) == 1
