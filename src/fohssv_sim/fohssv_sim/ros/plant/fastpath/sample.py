"""The lockstep FOM sample compiled, its publishes included: the awaited command's path.

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
   the entry point is :func:`.entries._fom_sample_entry`, which knows the sink
   it hands the sample to only as a C function's address);
3. when the period stayed finite and within the bounds, writes ``[t, z, w, theta, q]`` into
   the state's serialized message and publishes it with rcl's
   ``rcl_publish_serialized_message`` on the publisher's rcl handle (the address rclpy
   exposes as ``handle.pointer``), as rclpy's ``publish_raw`` does;
4. then, off the round trip's path (the controller has the state), writes ``[t, Fp]`` into
   the planing force's message and publishes it the same way, and the clock
   (``round(t * 1e9)`` ns) when the node asks for it this sample;
5. with in-plant recording (``record:=PATH``), puts the records of the state, the command (its
   bytes as received), the planing force and the clock into the writer's ring
   (:class:`fohssv_sim.bag.inplant.Ring`'s layout, the producer's side), in that order, the
   order the interpreted path puts them in, until one does not fit: the node puts the rest
   (:attr:`CompiledSample.put`), where a full ring waits or counts a loss as always;
6. last, with the state on its way, prepares the next period: the part of its steps that no
   command changes (:func:`fohssv_sim.kernels._prepare_period`: each step's sums over f_0,
   the SOE history's modes and the window's values from before the period, all but the
   last i + 1 of the about 110 rows at the period's step i, and the window's fold when one
   is due in the period), so that the next call, when :meth:`CompiledSample.arm` finds that this
   call took the sample before it (nothing else ran a period, the arrays are the same), only
   finishes the steps before it publishes (:func:`fohssv_sim.kernels.fom_soe_prepared_run`:
   the same sums in the same order, the kernel's results bit for bit).

Everything else (the model's bookkeeping, the views, the checks and counts) follows in the
node, in Python, as on the interpreted path. The call is *armed* by the node for one awaited
sample (:meth:`CompiledSample.arm`, with the model's step counts and what to do with the
clock; the deflection limits are the node's to set, :meth:`CompiledSample.limit`, at start
and when they change) and disarms itself when it takes the command; any command it does
not take (not armed, another layout, another ``t``, a deflection beyond its limit, a
non-finite value) is left to the node's interpreted path untouched.

The command can also reach it without the executor (:meth:`CompiledSample.take_from`,
:meth:`CompiledSample.take`): one C call (:func:`.entries._fom_take_entry`) takes
the next message of the ``command`` subscription with rcl's ``rcl_take_serialized_message``,
waiting in ``rcl_wait`` on a wait set of its own when there is none, and hands its bytes to
the entry point above; a message it does not take stays readable
(:meth:`CompiledSample.received`) for the node's interpreted path. The node's lockstep loop
(``PlantNode.spin_taking``) calls it instead of waiting in the executor: measured side by side
the pinned lockstep loop ran about 1.17 times as fast (docs/ros.md).

The entry point is built with numba (cached on disk like the kernels); where it cannot be
built, or rcl's symbol is not found in the process, :meth:`CompiledSample.build` returns None
and the node keeps the interpreted path (one line says why). Never imports rclpy: the node
passes the handle's address.
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import numpy as np

from ....kernels import FomHeldCall
from ....models import MAX_PITCH, HeldPeriod
from ...wire import ArrayReader, ArrayWriter, ClockWriter
from . import entries
from .entries import (
    _S_ARMED,
    _S_AWAITED,
    _S_CLOCK,
    _S_CLOCK_A,
    _S_CLOCK_B,
    _S_CLOCK_PUBLISH,
    _S_CLOCK_PUT,
    _S_CLOCK_RET,
    _S_CMD_COUNT,
    _S_CMD_COUNT_AT,
    _S_CMD_HEAD,
    _S_CMD_OFFSET,
    _S_CMD_SIZE,
    _S_FAILED,
    _S_FORCE_A,
    _S_FORCE_B,
    _S_FORCE_OUT,
    _S_FORCE_REFUSED,
    _S_FORCE_RET,
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
    _S_PREP_M,
    _S_PREP_P,
    _S_PREP_USED,
    _S_PREPARED,
    _S_PUT,
    _S_REC_CLOCK,
    _S_REC_COMMAND,
    _S_REC_FORCE,
    _S_REC_STATE,
    _S_RECORDS,
    _S_RET,
    _S_RING,
    _S_RING_CAP,
    _S_RING_COUNTERS,
    _S_SINK,
    _S_SINK_A,
    _S_SINK_B,
    _S_SINK_REFUSED,
    _S_STEPS,
    _S_TAKEN,
    _S_V,
    _W_ADD,
    _W_CLEAR,
    _W_MSG,
    _W_RET,
    _W_SET,
    _W_SIZE,
    _W_SUB,
    _W_TAKE,
    _W_TIMEOUT,
    _W_WAIT,
)
from .rcl import publish_api, serialized_message, take_api

#: :meth:`CompiledSample.call`: the command was not taken (the node's interpreted path runs)
NOT_TAKEN = _S_NOT_TAKEN
#: the sample was written, rcl refused its publish (``rcl_ret`` says what rcl returned)
PUBLISH_REFUSED = _S_SINK_REFUSED
#: the state went out, rcl refused the planing force's publish (``force_ret``); the state's
#: and the command's records were put (as far as :attr:`CompiledSample.put` says), no clock
FORCE_REFUSED = _S_FORCE_REFUSED
#: :meth:`CompiledSample.arm`'s ``clock``: publish the clock this sample; put it into the ring
CLOCK_PUBLISH, CLOCK_PUT = _S_CLOCK_PUBLISH, _S_CLOCK_PUT
#: below this: the period failed, ``FAILED - code`` steps were taken (non-finite or beyond
#: the bounds: nothing was written or published; the node settles it and stops the run)
FAILED = _S_FAILED
#: :meth:`CompiledSample.take`: nothing came within its timeout
TIMED_OUT = entries._S_TIMED_OUT
#: :meth:`CompiledSample.take`: rcl failed to take or to wait (:attr:`CompiledSample.take_ret`)
RCL_ERROR = entries._S_RCL_ERROR
#: :meth:`CompiledSample.take`: the wait ended, but with nothing to take (call it again)
WOKEN = entries._S_WOKEN


@functools.cache
def _entry() -> Any:
    """The C entry point as a ctypes function (compiled on first use, cached on disk), or
    the reason it could not be built (a str)."""
    if entries.numba is None:  # pragma: no cover
        return 'numba is not installed'
    entries.forget_stale_cache()
    try:
        import numba
        from numba import types

        sig = types.int64(types.CPointer(types.int64), types.CPointer(types.float64),
                          types.CPointer(types.int64), types.CPointer(types.float64),
                          types.int64, types.int64)
        # numba's cache follows the file of the compiled function: entries.py
        entry = numba.cfunc(sig, nopython=True, error_model='numpy', cache=True)(
            entries._fom_sample_entry)
        proto = ctypes.CFUNCTYPE(ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p,
                                 ctypes.c_void_p, ctypes.c_void_p, ctypes.c_char_p,
                                 ctypes.c_int64)
        return proto(entry.address), entry
    except Exception as exc:  # noqa: BLE001 - the interpreted path remains
        return f'the entry point could not be compiled ({type(exc).__name__}: {exc})'


@functools.cache
def _take_entry() -> Any:
    """The C entry point of :func:`.entries._fom_take_entry` as a ctypes function
    (compiled on first use, cached on disk), or the reason it could not be built (a str)."""
    if entries.numba is None:  # pragma: no cover
        return 'numba is not installed'
    entries.forget_stale_cache()
    try:
        import numba
        from numba import types

        i64p, f64p = types.CPointer(types.int64), types.CPointer(types.float64)
        sig = types.int64(i64p, f64p, i64p, f64p, i64p)
        entry = numba.cfunc(sig, nopython=True, error_model='numpy', cache=True)(
            entries._fom_take_entry)
        proto = ctypes.CFUNCTYPE(ctypes.c_int64, *([ctypes.c_void_p] * 5))
        return proto(entry.address), entry
    except Exception as exc:  # noqa: BLE001 - the executor's callback remains
        return f'the take entry point could not be compiled ({type(exc).__name__}: {exc})'


@dataclasses.dataclass
class _Taking:
    """:meth:`CompiledSample.take_from`'s rcl objects: its functions, the wait set and the
    received message (kept alive, freed by :meth:`CompiledSample.close`), the entry's int64
    table, the subscription's address, the message's first words (buffer, length)."""
    api: Any
    wait_set: np.ndarray
    message: np.ndarray
    w: np.ndarray
    entry: Any
    allocator: Any
    subscription: int
    words: memoryview


def _available(*parts: Any) -> tuple | str:
    """Each of ``parts`` called (the cached builders above), or the first reason one of them
    is not available (a str)."""
    built = []
    for part in parts:
        got = part()
        if isinstance(got, str):
            return got
        built.append(got)
    return tuple(built)


def _not_taken(raw: bytes, size: int) -> int:
    return NOT_TAKEN


class CompiledSample:
    """The compiled sample of one node (the module docstring). :meth:`call` ``(raw,
    len(raw))`` returns the steps taken when it published the sample, or :data:`NOT_TAKEN`,
    :data:`PUBLISH_REFUSED`, :data:`FORCE_REFUSED`, or a code below :data:`FAILED`."""

    def __init__(self, entry: Any, publish: int, take_error: Any, period: HeldPeriod,
                 state: ArrayWriter, command: ArrayReader, publisher: int,
                 force: tuple[ArrayWriter, int], clock: tuple[ClockWriter, int]) -> None:
        self._entry = entry
        self._take_error = take_error
        self._period = period
        head, count_at, count, offset, size = command.layout()
        self._head = np.frombuffer(head, dtype=np.uint8).copy()
        address, length, doubles = state.address()
        force_address, force_length, force_doubles = force[0].address()
        clock_address, clock_length = clock[0].address()
        self._writers = (state, force[0], clock[0])     # keep the messages' buffers alive
        self._message = serialized_message(address, length)
        self._force_message = serialized_message(force_address, force_length)
        self._clock_message = serialized_message(clock_address, clock_length)
        m = np.zeros(_S_M_SIZE, dtype=np.int64)
        m[_S_CMD_HEAD] = self._head.ctypes.data
        m[_S_CMD_COUNT_AT], m[_S_CMD_COUNT] = count_at, count
        m[_S_CMD_OFFSET], m[_S_CMD_SIZE] = offset, size
        m[_S_OUT] = address + doubles
        m[_S_SINK], m[_S_SINK_A] = publish, publisher
        m[_S_SINK_B] = self._message.ctypes.data
        m[_S_FORCE_OUT] = force_address + force_doubles
        m[_S_FORCE_A], m[_S_FORCE_B] = force[1], self._force_message.ctypes.data
        m[_S_CLOCK_A], m[_S_CLOCK_B] = clock[1], self._clock_message.ctypes.data
        m[_S_STEPS] = period.steps
        self._m = m
        self._g = np.zeros(_S_G_SIZE)
        self._g[_S_PITCH] = MAX_PITCH
        self._mv = memoryview(m)               # item writes without numpy scalars
        self._gv = memoryview(self._g)
        self._held: FomHeldCall | None = None
        self._armed_taken = -2                 # m[_S_TAKEN] at the last arm
        self._prepared: tuple[np.ndarray, np.ndarray] | None = None
        m[_S_PREPARED] = -1
        self._ring: Any = None
        self.call: Any = _not_taken         # until first armed (bound to the arrays)
        self._tables: tuple[int, int] = (0, 0)   # the bound kernel call's t and f
        self._taking: _Taking | None = None  # take_from's rcl objects, until close
        self.take: Any = None               # take_from's compiled wait and take

    @classmethod
    def build(cls, period: HeldPeriod, state: ArrayWriter, command: ArrayReader,
              publisher: int, force: tuple[ArrayWriter, int], clock: tuple[ClockWriter, int],
              sink: Callable[[int, int], int] | None = None) -> CompiledSample | str:
        """For ``period`` (the node's :class:`HeldPeriod`, writing into ``state``'s doubles),
        commands laid out as ``command`` reads them, the rcl publisher of the state at
        ``publisher``, the planing force's and the clock's messages with their rcl
        publishers' addresses; or why not (a str). ``sink(publish, publisher)``: the address
        of a C function standing in for rcl's publish at ``publish`` (fault injection,
        :meth:`fohssv_sim.ros.faults.StateFault.sink`)."""
        built = _available(_entry, publish_api)
        if isinstance(built, str):
            return built
        entry, rcl = built
        publish = rcl[0] if sink is None else sink(rcl[0], publisher)
        return cls(entry[0], publish, rcl[1], period, state, command, publisher, force, clock)

    def record_into(self, ring: Any, state: int = 0, command: int = 0, force: int = 0,
                    clock: int = 0) -> None:
        """Put each sample's records into ``ring`` (a :class:`fohssv_sim.bag.inplant.Ring`
        this process produces into), with these record indexes of the state, the command,
        the planing force and the clock; ``ring`` None: no longer (before it closes)."""
        mv = self._mv
        if ring is None:
            mv[_S_RING] = 0
            self._ring = None
            return
        data, capacity, counters = ring.address()
        self._ring = ring                      # the mapping stays open while it is used
        mv[_S_RING_CAP], mv[_S_RING_COUNTERS] = capacity, counters
        mv[_S_REC_STATE], mv[_S_REC_COMMAND] = state, command
        mv[_S_REC_FORCE], mv[_S_REC_CLOCK] = force, clock
        mv[_S_RING] = data

    @property
    def taken(self) -> int:
        """Commands taken and samples published by the compiled call so far."""
        return int(self._m[_S_TAKEN])

    @property
    def prepared(self) -> int:
        """Of those, the samples whose period was prepared after the sample before it (the
        input-free part of its steps done while the state travelled:
        :func:`fohssv_sim.kernels._prepare_period`)."""
        return int(self._m[_S_PREP_USED])

    @property
    def rcl_ret(self) -> int:
        """What rcl returned for the last publish (0: published)."""
        return int(self._g[_S_RET])

    def take_error(self) -> str:
        """rcl's error text after :data:`PUBLISH_REFUSED`, its error state cleared (as
        rclpy's publish does when it raises)."""
        return self._take_error()

    @property
    def records(self) -> int:
        """Records the last call's sample has for the ring: the state, the command, then the
        planing force and the clock as far as they went out and were asked for (2, 3 or 4,
        in that order)."""
        return int(self._m[_S_RECORDS])

    @property
    def put(self) -> int:
        """Of those, the records the last call put into the ring (the first ``put``)."""
        return int(self._m[_S_PUT])

    @property
    def force_ret(self) -> int:
        """What rcl returned for the last planing force publish (0: published)."""
        return int(self._g[_S_FORCE_RET])

    @property
    def clock_asked(self) -> int:
        """What the last :meth:`arm` asked of the clock (:data:`CLOCK_PUBLISH` |
        :data:`CLOCK_PUT`)."""
        return int(self._mv[_S_CLOCK])

    @property
    def clock_ret(self) -> int:
        """What rcl returned for the last clock publish (0: published, or not asked)."""
        return int(self._g[_S_CLOCK_RET])

    def arm(self, awaited: float, clock: int = 0) -> bool:
        """Take the command answering the sample at ``awaited`` s if it comes with
        deflections within the limits (:meth:`limit`), and do with the sample's clock what
        ``clock`` asks (:data:`CLOCK_PUBLISH` | :data:`CLOCK_PUT`, 0: nothing); False (and
        disarmed) when the model's kernel call is not bound (the interpreted path binds
        it)."""
        bound = self._period.bound()
        mv = self._mv
        if bound is None:
            mv[_S_ARMED] = 0
            return False
        held, n, model_n = bound
        taken = mv[_S_TAKEN]
        if held is not self._held or taken != self._armed_taken + 1:
            # the period prepared after the last sample is good only if this call took that
            # sample and nothing else ran a period or replaced the arrays since
            mv[_S_PREPARED] = -1
        self._armed_taken = taken
        if held is not self._held:           # the model's arrays changed (a reset, the start)
            self._held = held
            L = held._arrays['eps_k'].shape[2]
            self._prepared = (np.zeros((self._period.steps, 8)), np.zeros((4, L)))
            mv[_S_PREP_P] = self._prepared[0].ctypes.data
            mv[_S_PREP_M] = self._prepared[1].ctypes.data
            self._tables = (held._table.ctypes.data, held._floats.ctypes.data)
            self.call = functools.partial(self._entry, *self._pointers())
            if self._taking is not None:
                self._bind_take()
            model = self._period._model
            self._gv[_S_H] = model.h
            self._gv[_S_V] = model.params.speed
        mv[_S_N] = n
        mv[_S_MODEL_N] = model_n
        mv[_S_CLOCK] = clock
        self._gv[_S_AWAITED] = awaited
        mv[_S_ARMED] = 1
        return True

    def _pointers(self) -> tuple[ctypes.c_void_p, ...]:
        return (ctypes.c_void_p(self._tables[0]), ctypes.c_void_p(self._tables[1]),
                ctypes.c_void_p(self._m.ctypes.data), ctypes.c_void_p(self._g.ctypes.data))

    # -- the command taken in compiled code ------------------------------------------------
    def take_from(self, context: int, subscription: int, timeout: float) -> str | None:
        """Take the commands of the rcl subscription at ``subscription`` (rclpy's
        ``handle.pointer``; ``context``: its rcl context's) in compiled code from now on:
        :meth:`take` waits for the next message at most ``timeout`` s, takes it with rcl
        and hands it to the compiled sample, with no executor, no Python frame and no bytes
        object in between (:func:`.entries._fom_take_entry`). None when set up,
        else why not (a str; nothing changed). The node must then take the subscription's
        messages only this way (:meth:`detach_listener`) and :meth:`close` it before its
        context shuts down."""
        built = _available(_take_entry, take_api)
        if isinstance(built, str):
            return built
        entry, api = built
        allocator = api.allocator()
        wait_set = np.zeros(16, dtype=np.int64)   # an rcl_wait_set_t (13 words) zeroed
        ret = api.wait_set_init(wait_set.ctypes.data, 1, 0, 0, 0, 0, 0, context, allocator)
        if ret != 0:
            return f'rcl_wait_set_init returned {ret}: {self._take_error()}'
        message = np.zeros(8, dtype=np.int64)     # an rcl_serialized_message_t
        ret = api.array_init(message.ctypes.data, 256, ctypes.byref(allocator))
        if ret != 0:
            api.wait_set_fini(wait_set.ctypes.data)
            return f'rcutils_uint8_array_init returned {ret}: {self._take_error()}'
        w = np.zeros(_W_SIZE, dtype=np.int64)
        w[_W_TAKE], w[_W_CLEAR], w[_W_ADD], w[_W_WAIT] = api.addresses
        w[_W_SET], w[_W_SUB], w[_W_MSG] = wait_set.ctypes.data, subscription, message.ctypes.data
        w[_W_TIMEOUT] = round(timeout * 1e9)
        self._taking = _Taking(api, wait_set, message, w, entry, allocator, subscription,
                               memoryview(message))
        self._bind_take()
        return None

    def _bind_take(self) -> None:
        taking = self._taking
        self.take = functools.partial(taking.entry[0], *self._pointers(),
                                      ctypes.c_void_p(taking.w.ctypes.data))

    def received(self) -> bytes:
        """The bytes of the message :meth:`take` took last."""
        words = self._taking.words
        return ctypes.string_at(words[0], words[1])

    @property
    def take_ret(self) -> int:
        """What rcl returned when :meth:`take` returned :data:`RCL_ERROR`."""
        return int(self._taking.w[_W_RET])

    def set_timeout(self, timeout: float) -> None:
        """:meth:`take`'s wait, at most ``timeout`` s from now on."""
        self._taking.w[_W_TIMEOUT] = round(timeout * 1e9)

    def detach_listener(self) -> int:
        """Unset the subscription's new-message callback (an event-driven executor's: its
        events would otherwise queue up for messages :meth:`take` took); what rcl
        returned. An executor that sets it again (a new entity) is undone by the next
        call."""
        taking = self._taking
        return int(taking.api.set_listener(taking.subscription, None, None))

    def close(self) -> None:
        """Free the wait set and the received message (before the context shuts down)."""
        taking, self._taking, self.take = self._taking, None, None
        if taking is not None:
            taking.api.array_fini(taking.message.ctypes.data)
            taking.api.wait_set_fini(taking.wait_set.ctypes.data)

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
    _take_entry()
