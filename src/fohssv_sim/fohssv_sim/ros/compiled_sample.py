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
   code on the same arrays as :meth:`HeldPeriod.run <fohssv_sim.models.HeldPeriod.run>`);
3. when the period stayed finite and within the bounds, writes ``[t, z, w, theta, q]`` into
   the state's serialized message and publishes it with rcl's
   ``rcl_publish_serialized_message`` on the publisher's rcl handle (the address rclpy
   exposes as ``handle.pointer``), as rclpy's ``publish_raw`` does.

Everything else (the model's bookkeeping, ``planing_force``, ``/clock``, the views, the
checks) follows in the node, in Python, as on the interpreted path. The call is *armed* by the
node for one awaited sample (:meth:`CompiledSample.arm`, with the model's step counts and the
current deflection limits) and disarms itself when it takes the command; any command it does
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
from ..models import MAX_PITCH, HeldPeriod
from .wire import ArrayReader, ArrayWriter

try:
    import numba
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover - numba is a dependency
    numba = None

#: :meth:`CompiledSample.call`: the command was not taken (the node's interpreted path runs)
NOT_TAKEN = -1
#: the sample was written, rcl refused its publish (``rcl_ret`` says what rcl returned)
PUBLISH_REFUSED = -2
#: below this: the period failed, ``FAILED - code`` steps were taken (non-finite or beyond
#: the bounds: nothing was written or published; the node settles it and stops the run)
FAILED = -10

# the int64 table (m) and float64 table (g) the entry point reads; the node writes them
(_M_CMD_HEAD, _M_CMD_COUNT_AT, _M_CMD_COUNT, _M_CMD_OFFSET, _M_CMD_SIZE, _M_STATE, _M_PUBLISH,
 _M_PUBLISHER, _M_MESSAGE, _M_N, _M_STEPS, _M_MODEL_N, _M_ARMED, _M_TAKEN) = range(14)
_M_SIZE = 14
_G_AWAITED, _G_MAX_FIN, _G_MAX_CAV, _G_H, _G_V, _G_PITCH, _G_RET = range(7)
_G_SIZE = 7

if numba is not None:
    @intrinsic
    def _call3(typingctx, fn, a, b):
        """``fn(a, b, NULL)`` for a C function ``int32 fn(void *, void *, void *)`` at the
        int64 address ``fn`` (compiled code only): rcl_publish_serialized_message."""
        def codegen(context, builder, signature, args):
            address, first, second = args
            ptr = ir.IntType(8).as_pointer()
            fnty = ir.FunctionType(ir.IntType(32), [ptr, ptr, ptr])
            function = builder.inttoptr(address, fnty.as_pointer())
            return builder.call(function, [builder.inttoptr(first, ptr),
                                           builder.inttoptr(second, ptr),
                                           ir.Constant(ptr, None)])
        return types.int32(types.int64, types.int64, types.int64), codegen


def _sample_entry(t, f, m, g, raw, size):   # pragma: no cover - compiled by _entry
    """The entry point's body (the module docstring); ``t``, ``f``: the kernel call's tables
    (:class:`fohssv_sim.kernels.FomHeldCall`), ``m``, ``g``: this module's, ``raw``: the
    command's address, ``size``: its length."""
    if m[_M_ARMED] == 0 or size != m[_M_CMD_SIZE]:
        return NOT_TAKEN
    head = numba.carray(kernels._as_pointer(m[_M_CMD_HEAD]), (12,), np.uint8)
    got = numba.carray(kernels._as_pointer(raw), (size,), np.uint8)
    for i in range(12):
        if got[i] != head[i]:
            return NOT_TAKEN
    at = m[_M_CMD_COUNT_AT]
    count = (np.int64(got[at]) | (np.int64(got[at + 1]) << 8) | (np.int64(got[at + 2]) << 16)
             | (np.int64(got[at + 3]) << 24))
    if count != m[_M_CMD_COUNT]:
        return NOT_TAKEN
    cmd = numba.carray(kernels._as_pointer(raw + m[_M_CMD_OFFSET]), (3,), np.float64)
    t_cmd = cmd[0]
    delta_f = cmd[1]
    delta_c = cmd[2]
    if not (t_cmd == g[_G_AWAITED] and abs(delta_f) <= g[_G_MAX_FIN]
            and abs(delta_c) <= g[_G_MAX_CAV]):
        return NOT_TAKEN
    m[_M_ARMED] = 0
    law = numba.carray(kernels._as_pointer(t[kernels._T_LAW]), (t[kernels._T_SHAPES + 1],),
                       np.float64)
    law[8] = delta_f
    law[9] = delta_c
    steps = m[_M_STEPS]
    taken = _held(t, f, m[_M_N], steps)
    x = numba.carray(kernels._as_pointer(t[kernels._T_X]), (4,), np.float64)
    w = x[1]
    theta = x[2]
    v = g[_G_V]
    if not (taken == steps and -v <= w <= v and -g[_G_PITCH] <= theta <= g[_G_PITCH]):
        return FAILED - taken
    out = numba.carray(kernels._as_pointer(m[_M_STATE]), (5,), np.float64)
    out[0] = (m[_M_MODEL_N] + steps) * g[_G_H]
    out[1] = x[0]
    out[2] = w
    out[3] = theta
    out[4] = x[3]
    m[_M_TAKEN] += 1
    ret = _call3(m[_M_PUBLISH], m[_M_PUBLISHER], m[_M_MESSAGE])
    g[_G_RET] = ret
    return steps if ret == 0 else PUBLISH_REFUSED


if numba is not None:
    # the kernel entry point's body as a compiled function this entry point calls (not cached
    # on its own: compiled into the entry point, which is)
    _held = numba.njit(error_model='numpy')(kernels._fom_held_entry)


@functools.cache
def _entry() -> Any:
    """The C entry point as a ctypes function (compiled on first use, cached on disk), or
    the reason it could not be built (a str)."""
    if numba is None:  # pragma: no cover
        return 'numba is not installed'
    try:
        sig = types.int64(types.CPointer(types.int64), types.CPointer(types.float64),
                          types.CPointer(types.int64), types.CPointer(types.float64),
                          types.int64, types.int64)
        entry = numba.cfunc(sig, nopython=True, error_model='numpy', cache=True)(
            _sample_entry)
        proto = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p,
                                 ctypes.c_void_p, ctypes.c_void_p, ctypes.c_char_p,
                                 ctypes.c_int64)
        return proto(entry.address), entry
    except Exception as exc:  # noqa: BLE001 - the interpreted path remains
        return f'the entry point could not be compiled ({type(exc).__name__}: {exc})'


@functools.cache
def _rcl() -> Any:
    """(rcl_publish_serialized_message's address, rcutils_reset_error) from the rcl and
    rcutils libraries rclpy has loaded, or the reason they are not available (a str)."""
    try:
        rcl = ctypes.CDLL('librcl.so')
        rcutils = ctypes.CDLL('librcutils.so')
        publish = ctypes.cast(rcl.rcl_publish_serialized_message, ctypes.c_void_p).value
        reset = rcutils.rcutils_reset_error
        reset.argtypes, reset.restype = [], None
    except (OSError, AttributeError) as exc:
        return f'rcl is not loadable here ({exc})'
    return publish, reset


def _not_taken(raw: bytes, size: int) -> int:
    return NOT_TAKEN


class CompiledSample:
    """The compiled sample of one node (the module docstring). :meth:`call` ``(raw,
    len(raw))`` returns the steps taken when it published the sample, or :data:`NOT_TAKEN`,
    :data:`PUBLISH_REFUSED`, or a code below :data:`FAILED`."""

    def __init__(self, entry: Any, publish: int, reset_error: Any, period: HeldPeriod,
                 state: ArrayWriter, command: ArrayReader, publisher: int) -> None:
        self._entry = entry
        self._reset_error = reset_error
        self._period = period
        head, count_at, count, offset, size = command.layout()
        self._head = np.frombuffer(head, dtype=np.uint8).copy()
        address, length, doubles = state.address()
        self._state = state                    # keeps the message's buffer alive
        # rcl_serialized_message_t: buffer, buffer_length, buffer_capacity, then an
        # allocator that rcl does not use to publish (four functions and a state: zeros)
        self._message = np.zeros(8, dtype=np.int64)
        self._message[:3] = (address, length, length)
        m = np.zeros(_M_SIZE, dtype=np.int64)
        m[_M_CMD_HEAD] = self._head.ctypes.data
        m[_M_CMD_COUNT_AT], m[_M_CMD_COUNT] = count_at, count
        m[_M_CMD_OFFSET], m[_M_CMD_SIZE] = offset, size
        m[_M_STATE] = address + doubles
        m[_M_PUBLISH], m[_M_PUBLISHER] = publish, publisher
        m[_M_MESSAGE] = self._message.ctypes.data
        m[_M_STEPS] = period.steps
        self._m = m
        self._g = np.zeros(_G_SIZE)
        self._g[_G_PITCH] = MAX_PITCH
        self._mv = memoryview(m)               # item writes without numpy scalars
        self._gv = memoryview(self._g)
        self._held: kernels.FomHeldCall | None = None
        self.call: Any = _not_taken         # until first armed (bound to the arrays)
        self.steps = period.steps

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
        return int(self._m[_M_TAKEN])

    @property
    def rcl_ret(self) -> int:
        """What rcl returned for the last publish (0: published)."""
        return int(self._g[_G_RET])

    def reset_error(self) -> None:
        """Clear rcl's error state after :data:`PUBLISH_REFUSED` (as rclpy does when it raises)."""
        self._reset_error()

    def arm(self, awaited: float, max_fin: float, max_cav: float) -> bool:
        """Take the command answering the sample at ``awaited`` s if it comes with
        deflections within ``max_fin`` and ``max_cav`` rad; False (and disarmed) when the
        model's kernel call is not bound (the interpreted path binds it)."""
        bound = self._period.bound()
        mv = self._mv
        if bound is None:
            mv[_M_ARMED] = 0
            return False
        held, n, model_n = bound
        if held is not self._held:           # the model's arrays changed (a reset, the start)
            self._held = held
            self.call = functools.partial(self._entry, ctypes.c_void_p(held._table.ctypes.data),
                                          ctypes.c_void_p(held._floats.ctypes.data),
                                          ctypes.c_void_p(self._m.ctypes.data),
                                          ctypes.c_void_p(self._g.ctypes.data))
            model = self._period._model
            self._gv[_G_H] = model.h
            self._gv[_G_V] = model.params.speed
        gv = self._gv
        mv[_M_N] = n
        mv[_M_MODEL_N] = model_n
        gv[_G_AWAITED] = awaited
        gv[_G_MAX_FIN] = max_fin
        gv[_G_MAX_CAV] = max_cav
        mv[_M_ARMED] = 1
        return True

    def disarm(self) -> None:
        """Take no command until armed again."""
        self._mv[_M_ARMED] = 0

    def armed(self) -> bool:
        return bool(self._mv[_M_ARMED])



def warm_up() -> None:
    """Compile the entry point (or load it from numba's cache), so that the first plant to
    start does not pay for it (about 2 CPU s)."""
    _entry()
