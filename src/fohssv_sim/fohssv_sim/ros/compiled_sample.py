"""The lockstep FOM sample compiled up to its publish: the plant's path for the awaited command.

In lockstep with an external controller the round trip waits for every microsecond the plant
spends between the command's arrival and the state's publish, and interpreted code costs
the loop more than its time in one process (docs/ros.md, *The ceiling with this controller*).
:class:`CompiledSample` makes that stretch one compiled call: given the command's serialized
bytes it

1. checks them as :meth:`ArrayReader.read <fohssv_sim.ros.wire.ArrayReader.read>`'s fast path
   does (the length, the first 12 bytes, the element count) and as the plant's short path
   does (``t`` answers the awaited sample, both deflections within their limits);
2. runs the model's held-input kernel call on the model's own arrays (the body of
   :func:`fohssv_sim.kernels._fom_held_entry`, compiled into this entry point: the same
   code on the same arrays as :meth:`HeldPeriod.run <fohssv_sim.models.HeldPeriod.run>`;
   the entry point is :func:`fohssv_sim.kernels._fom_sample_entry`, which knows the sink
   it hands the sample to only as a C function's address);
3. when the period stayed finite and within the bounds, writes ``[t, z, w, theta, q]`` into
   the state's serialized message and publishes it with rcl's
   ``rcl_publish_serialized_message`` on the publisher's rcl handle (the address rclpy
   exposes as ``handle.pointer``), as rclpy's ``publish_raw`` does.

Everything else (the model's bookkeeping, ``planing_force``, ``/clock``, the views, the
checks) follows in the node, in Python, as on the interpreted path. The call is *armed* by the
node for one awaited sample (:meth:`CompiledSample.arm`, with the model's step counts; the
deflection limits are the node's to set, :meth:`CompiledSample.limit`, at start and when they
change) and disarms itself when it takes the command; any command it does
not take (not armed, another layout, another ``t``, a deflection beyond its limit, a
non-finite value) is left to the node's interpreted path untouched.

The entry point is built with numba (cached on disk like the kernels); where it cannot be
built, or rcl's symbol is not found in the process, :meth:`CompiledSample.build` returns None
and the node keeps the interpreted path (one line says why). Never imports rclpy: the node
passes the handle's address.
"""

from __future__ import annotations

import ctypes
import functools
from typing import Any

import numpy as np

from .. import kernels
from ..kernels import (
    _S_ARMED,
    _S_AWAITED,
    _S_CMD_COUNT,
    _S_CMD_COUNT_AT,
    _S_CMD_HEAD,
    _S_CMD_OFFSET,
    _S_CMD_SIZE,
    _S_FAILED,
    _S_G_SIZE,
    _S_H,
    _S_M_SIZE,
    _S_MAX_CAV,
    _S_MAX_FIN,
    _S_MODEL_N,
    _S_N,
    _S_NOT_TAKEN,
    _S_OUT,
    _S_PITCH,
    _S_RET,
    _S_SINK,
    _S_SINK_A,
    _S_SINK_B,
    _S_SINK_REFUSED,
    _S_STEPS,
    _S_TAKEN,
    _S_V,
)
from ..models import MAX_PITCH, HeldPeriod
from .wire import ArrayReader, ArrayWriter

#: :meth:`CompiledSample.call`: the command was not taken (the node's interpreted path runs)
NOT_TAKEN = _S_NOT_TAKEN
#: the sample was written, rcl refused its publish (``rcl_ret`` says what rcl returned)
PUBLISH_REFUSED = _S_SINK_REFUSED
#: below this: the period failed, ``FAILED - code`` steps were taken (non-finite or beyond
#: the bounds: nothing was written or published; the node settles it and stops the run)
FAILED = _S_FAILED


@functools.cache
def _entry() -> Any:
    """The C entry point as a ctypes function (compiled on first use, cached on disk), or
    the reason it could not be built (a str)."""
    if kernels.numba is None:  # pragma: no cover
        return 'numba is not installed'
    try:
        import numba
        from numba import types

        sig = types.int64(types.CPointer(types.int64), types.CPointer(types.float64),
                          types.CPointer(types.int64), types.CPointer(types.float64),
                          types.int64, types.int64)
        # compiled from kernels.py's function, so numba's cache follows that file (the kernel
        # it runs lives there)
        entry = numba.cfunc(sig, nopython=True, error_model='numpy', cache=True)(
            kernels._fom_sample_entry)
        proto = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p,
                                 ctypes.c_void_p, ctypes.c_void_p, ctypes.c_char_p,
                                 ctypes.c_int64)
        return proto(entry.address), entry
    except Exception as exc:  # noqa: BLE001 - the interpreted path remains
        return f'the entry point could not be compiled ({type(exc).__name__}: {exc})'


class _ErrorString(ctypes.Structure):
    _fields_ = [('str', ctypes.c_char * 1024)]      # rcutils_error_string_t


@functools.cache
def _rcl() -> Any:
    """(rcl_publish_serialized_message's address, a function returning rcl's error text and
    clearing it) from the rcl and rcutils libraries rclpy has loaded, or the reason they are
    not available (a str)."""
    try:
        rcl = ctypes.CDLL('librcl.so')
        rcutils = ctypes.CDLL('librcutils.so')
        publish = ctypes.cast(rcl.rcl_publish_serialized_message, ctypes.c_void_p).value
        get = rcutils.rcutils_get_error_string
        get.argtypes, get.restype = [], _ErrorString
        reset = rcutils.rcutils_reset_error
        reset.argtypes, reset.restype = [], None
    except (OSError, AttributeError) as exc:
        return f'rcl is not loadable here ({exc})'

    def take_error() -> str:
        text = get().str.decode(errors='replace')
        reset()
        return text

    return publish, take_error


def _not_taken(raw: bytes, size: int) -> int:
    return NOT_TAKEN


class CompiledSample:
    """The compiled sample of one node (the module docstring). :meth:`call` ``(raw,
    len(raw))`` returns the steps taken when it published the sample, or :data:`NOT_TAKEN`,
    :data:`PUBLISH_REFUSED`, or a code below :data:`FAILED`."""

    def __init__(self, entry: Any, publish: int, take_error: Any, period: HeldPeriod,
                 state: ArrayWriter, command: ArrayReader, publisher: int) -> None:
        self._entry = entry
        self._take_error = take_error
        self._period = period
        head, count_at, count, offset, size = command.layout()
        self._head = np.frombuffer(head, dtype=np.uint8).copy()
        address, length, doubles = state.address()
        self._state = state                    # keeps the message's buffer alive
        # rcl_serialized_message_t: buffer, buffer_length, buffer_capacity, then an
        # allocator that rcl does not use to publish (four functions and a state: zeros)
        self._message = np.zeros(8, dtype=np.int64)
        self._message[:3] = (address, length, length)
        m = np.zeros(_S_M_SIZE, dtype=np.int64)
        m[_S_CMD_HEAD] = self._head.ctypes.data
        m[_S_CMD_COUNT_AT], m[_S_CMD_COUNT] = count_at, count
        m[_S_CMD_OFFSET], m[_S_CMD_SIZE] = offset, size
        m[_S_OUT] = address + doubles
        m[_S_SINK], m[_S_SINK_A] = publish, publisher
        m[_S_SINK_B] = self._message.ctypes.data
        m[_S_STEPS] = period.steps
        self._m = m
        self._g = np.zeros(_S_G_SIZE)
        self._g[_S_PITCH] = MAX_PITCH
        self._mv = memoryview(m)               # item writes without numpy scalars
        self._gv = memoryview(self._g)
        self._held: kernels.FomHeldCall | None = None
        self.call: Any = _not_taken         # until first armed (bound to the arrays)

    @classmethod
    def build(cls, period: HeldPeriod, state: ArrayWriter, command: ArrayReader,
              publisher: int) -> CompiledSample | str:
        """For ``period`` (the node's :class:`HeldPeriod`, writing into ``state``'s doubles),
        commands laid out as ``command`` reads them and the rcl publisher at ``publisher``;
        or why not (a str)."""
        entry = _entry()
        if isinstance(entry, str):
            return entry
        rcl = _rcl()
        if isinstance(rcl, str):
            return rcl
        return cls(entry[0], rcl[0], rcl[1], period, state, command, publisher)

    @property
    def taken(self) -> int:
        """Commands taken and samples published by the compiled call so far."""
        return int(self._m[_S_TAKEN])

    @property
    def rcl_ret(self) -> int:
        """What rcl returned for the last publish (0: published)."""
        return int(self._g[_S_RET])

    def take_error(self) -> str:
        """rcl's error text after :data:`PUBLISH_REFUSED`, its error state cleared (as
        rclpy's publish does when it raises)."""
        return self._take_error()

    def arm(self, awaited: float) -> bool:
        """Take the command answering the sample at ``awaited`` s if it comes with
        deflections within the limits (:meth:`limit`); False (and disarmed) when the model's
        kernel call is not bound (the interpreted path binds it)."""
        bound = self._period.bound()
        mv = self._mv
        if bound is None:
            mv[_S_ARMED] = 0
            return False
        held, n, model_n = bound
        if held is not self._held:           # the model's arrays changed (a reset, the start)
            self._held = held
            self.call = functools.partial(self._entry, ctypes.c_void_p(held._table.ctypes.data),
                                          ctypes.c_void_p(held._floats.ctypes.data),
                                          ctypes.c_void_p(self._m.ctypes.data),
                                          ctypes.c_void_p(self._g.ctypes.data))
            model = self._period._model
            self._gv[_S_H] = model.h
            self._gv[_S_V] = model.params.speed
        mv[_S_N] = n
        mv[_S_MODEL_N] = model_n
        self._gv[_S_AWAITED] = awaited
        mv[_S_ARMED] = 1
        return True

    def limit(self, max_fin: float, max_cav: float) -> None:
        """The deflection limits (rad) of the commands it takes, the one awaited now
        included (0 until set: it takes none but all-zero deflections)."""
        self._gv[_S_MAX_FIN] = max_fin
        self._gv[_S_MAX_CAV] = max_cav

    def disarm(self) -> None:
        """Take no command until armed again."""
        self._mv[_S_ARMED] = 0

    def armed(self) -> bool:
        return bool(self._mv[_S_ARMED])


def warm_up() -> None:
    """Compile the entry point (or load it from numba's cache), so that the first plant to
    start does not pay for it (about 2 CPU s)."""
    _entry()
