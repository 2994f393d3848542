"""The plant's compiled fast path, its compiled code: the lockstep sample of the FOM for a
command's serialized bytes, published through rcl's C functions called by address, and the
awaited command taken through rcl's wait and take (:mod:`.sample` builds and binds them).

The code reaches rcl only through function addresses in its int64 tables (no rclpy here);
the model's arrays through the held-input tables of :class:`fohssv_sim.kernels.FomHeldCall`;
the recording ring through :func:`fohssv_sim.bag.ring.place`. Compiled on first use and
cached on disk next to this file (numba's cache checks only this file's stamp, so
:func:`forget_stale_cache` drops it when a file compiled into it changed).
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

import numpy as np

from .... import kernels as _kernels
from ....bag import ring as _ring
from ....bag.ring import place
from ....kernels import (
    _T_LAW,
    _T_SHAPES,
    _T_X,
    _as_pointer,
    _fom_held_jit,
    _fom_prepare_jit,
    _fom_prepared_jit,
)

try:
    import numba
    from numba.extending import intrinsic
except ImportError:  # pragma: no cover - numba is pinned in requirements.txt
    numba = None


@functools.cache
def forget_stale_cache() -> None:
    """Remove numba's cached entry points of this file when this file, ``kernels.py`` or
    ``bag/ring.py`` (whose code is compiled into them) changed since they were cached: numba
    itself compares only this file's modification time and size. Once per process, before
    the entry points are compiled; a cache elsewhere (``NUMBA_CACHE_DIR``) is left alone."""
    sources = [os.path.realpath(f) for f in (__file__, _kernels.__file__, _ring.__file__)]
    stamp = hashlib.sha256(b''.join(Path(f).read_bytes() for f in sources)).hexdigest()
    cache = Path(sources[0]).parent / '__pycache__'
    seen = cache / 'entries.sources'
    try:
        if seen.read_text() == stamp:
            return
    except OSError:
        pass
    try:
        for old in cache.glob('entries.*.nb[ic]'):
            old.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        seen.write_text(stamp)
    except OSError:                 # a read-only tree: numba caches elsewhere, if at all
        pass


# -- the serialized sample: fom_soe_run for a command's bytes, the sample handed to a C sink --

#: Slots of the int64 table ``m`` of :func:`_fom_sample_entry`: the command layout (the address
#: of its first 12 bytes, the offset of its element count, the count, the offset of its
#: doubles, its length), the address of the sample's doubles, the sink (a C function
#: ``int32 sink(void *, void *, void *)``'s address and its first two arguments: the state's
#: publisher and the address of its serialized message, ``{buffer, length, ...}``), the step
#: index and the steps per period, the model's step count, armed (0/1), samples taken; then
#: the planing force's doubles, publisher and message; the clock's message and publisher, what
#: to do with the clock this sample (:data:`_S_CLOCK_PUBLISH` | :data:`_S_CLOCK_PUT`); the
#: ring (its data's address, capacity, the address of its head and tail counters; data 0:
#: no ring) and the record index of the state, the command, the force and the clock; the
#: records the last call's sample has (the state, the command, then the force and the clock
#: as they went out) and how many of them it put; the next period's part prepared ahead
#: (:func:`_prepare_period`: the address of ``P``, steps x 8, and of ``M``, 4 x L, float64)
#: and the step it was prepared from (-1: none), the periods taken so prepared.
(_S_CMD_HEAD, _S_CMD_COUNT_AT, _S_CMD_COUNT, _S_CMD_OFFSET, _S_CMD_SIZE, _S_OUT, _S_SINK,
 _S_SINK_A, _S_SINK_B, _S_N, _S_STEPS, _S_MODEL_N, _S_ARMED, _S_TAKEN,
 _S_FORCE_OUT, _S_FORCE_A, _S_FORCE_B, _S_CLOCK_A, _S_CLOCK_B, _S_CLOCK,
 _S_RING, _S_RING_CAP, _S_RING_COUNTERS, _S_REC_STATE, _S_REC_COMMAND, _S_REC_FORCE,
 _S_REC_CLOCK, _S_RECORDS, _S_PUT, _S_PREP_P, _S_PREP_M, _S_PREPARED, _S_PREP_USED) = range(33)
_S_M_SIZE = 33
#: Slots of its float64 table ``g``: the awaited time, the deflection limits, the step, V,
#: the pitch limit, what the sinks returned (state, planing force, clock).
_S_AWAITED, _S_MAX_FIN, _S_MAX_CAV, _S_H, _S_V, _S_PITCH, _S_RET, _S_FORCE_RET, _S_CLOCK_RET = (
    range(9))
_S_G_SIZE = 9
#: Its results: the command not taken (nothing done); the sample written, the sink refused its
#: state (nothing else done); the state went out, the sink refused the planing force (the
#: state's and the command's records put, no clock); below _S_FAILED: the period failed,
#: _S_FAILED - code steps taken (nothing written, nothing handed on).
_S_NOT_TAKEN, _S_SINK_REFUSED, _S_FORCE_REFUSED, _S_FAILED = -1, -2, -3, -10
#: ``m[_S_CLOCK]`` bits: hand the clock to the sink; put it into the ring.
_S_CLOCK_PUBLISH, _S_CLOCK_PUT = 1, 2

if numba is not None:
    def _c_caller(nargs):
        """An intrinsic's typing for calling the C function at an int64 address with
        ``nargs`` int64 arguments (addresses or integers, passed as the C ABI passes both;
        0 for NULL) and an int32 result (rcl's ``rcl_ret_t``)."""
        def caller(typingctx, fn, *args):
            def codegen(context, builder, signature, values):
                from llvmlite import ir

                i64 = ir.IntType(64)
                fnty = ir.FunctionType(ir.IntType(32), [i64] * nargs)
                function = builder.inttoptr(values[0], fnty.as_pointer())
                return builder.call(function, list(values[1:]))
            return numba.types.int32(*([numba.types.int64] * (nargs + 1))), codegen
        return caller

    # numba's intrinsic needs a fixed argument list: one per arity
    @intrinsic
    def _call1(typingctx, fn, a):
        return _c_caller(1)(typingctx, fn, a)

    @intrinsic
    def _call2(typingctx, fn, a, b):
        return _c_caller(2)(typingctx, fn, a, b)

    @intrinsic
    def _call3(typingctx, fn, a, b, c):
        return _c_caller(3)(typingctx, fn, a, b, c)

    @intrinsic
    def _call4(typingctx, fn, a, b, c, d):
        return _c_caller(4)(typingctx, fn, a, b, c, d)

    @intrinsic
    def _release_fence(typingctx):
        """A release fence: the stores before it are not moved after the stores after it
        (the ring's record before its head; on x86 only the compiler's order is at stake)."""
        def codegen(context, builder, signature, args):
            builder.fence('release')
            return context.get_dummy_value()
        return numba.types.none(), codegen

    _place = numba.njit(error_model='numpy')(place)

    @numba.njit(error_model='numpy')
    def _ring_put(ring, cap, counters_at, index, buffer, n):
        """One record into the plant's ring (:func:`fohssv_sim.bag.ring.place` on the data
        at ``ring``, ``cap`` bytes, head and tail at ``counters_at``): the ``n`` bytes at
        ``buffer`` for topic ``index``; False when there is no room (nothing written). The
        record's bytes are stored before the head that publishes them."""
        counters = numba.carray(_as_pointer(counters_at), (2,), np.int64)
        data = numba.carray(_as_pointer(ring), (cap,), np.uint8)
        got = numba.carray(_as_pointer(buffer), (n,), np.uint8)
        head = _place(data, cap, counters[0], counters[1], index, got, n)
        if head < 0:
            return False
        _release_fence()
        counters[0] = head
        return True

    @numba.njit(error_model='numpy')
    def _ring_put_message(ring, cap, counters_at, index, message):
        """:func:`_ring_put` of the serialized message whose ``{buffer, length, ...}`` lie at
        ``message`` (an rcl_serialized_message_t)."""
        msg = numba.carray(_as_pointer(message), (2,), np.int64)
        return _ring_put(ring, cap, counters_at, index, msg[0], msg[1])

    @numba.njit(error_model='numpy')
    def _after_state(f, m, g, raw, size, t_out):
        """:func:`_fom_sample_entry` once the sink took the state at ``t_out``: the planing
        force (False: the sink refused it), the clock as asked, then the ring's records in
        the order the interpreted path puts them."""
        force = numba.carray(_as_pointer(m[_S_FORCE_OUT]), (2,), np.float64)
        force[0] = t_out
        force[1] = f[3]
        ret = _call3(m[_S_SINK], m[_S_FORCE_A], m[_S_FORCE_B], 0)
        g[_S_FORCE_RET] = ret
        g[_S_CLOCK_RET] = 0
        clock = m[_S_CLOCK] if ret == 0 else 0
        if clock != 0:
            message = numba.carray(_as_pointer(m[_S_CLOCK_B]), (2,), np.int64)
            stamp = numba.carray(_as_pointer(message[0] + 4), (2,), np.uint32)
            ns = np.int64(np.rint(t_out * 1e9))   # round(t * 1e9): ties to even, as Python's
            stamp[0] = np.uint32(ns // 1000000000)
            stamp[1] = np.uint32(ns % 1000000000)
            if clock & _S_CLOCK_PUBLISH:
                g[_S_CLOCK_RET] = _call3(m[_S_SINK], m[_S_CLOCK_A], m[_S_CLOCK_B], 0)
                if g[_S_CLOCK_RET] != 0:
                    clock = 0                     # not published: not recorded either
        # the sample's records: the state and the command, the force and the clock as they
        # went out (a clock rcl refused is not recorded, as on the interpreted path)
        m[_S_RECORDS] = 2 if ret != 0 else (4 if clock & _S_CLOCK_PUT else 3)
        ring = m[_S_RING]
        if ring == 0:
            return ret == 0
        cap = m[_S_RING_CAP]
        at = m[_S_RING_COUNTERS]
        put = 0
        while put < m[_S_RECORDS]:
            if put == 0:
                done = _ring_put_message(ring, cap, at, m[_S_REC_STATE], m[_S_SINK_B])
            elif put == 1:
                done = _ring_put(ring, cap, at, m[_S_REC_COMMAND], raw, size)   # as received
            elif put == 2:
                done = _ring_put_message(ring, cap, at, m[_S_REC_FORCE], m[_S_FORCE_B])
            else:
                done = _ring_put_message(ring, cap, at, m[_S_REC_CLOCK], m[_S_CLOCK_B])
            if not done:
                break
            put += 1
        m[_S_PUT] = put
        return ret == 0


def _fom_sample_entry(t, f, m, g, raw, size):   # pragma: no cover - compiled by its user
    """One held-input period for a serialized command, its sample written into serialized messages
    and handed to a C sink (:mod:`.sample` compiles it, cached by this file): when armed and
    the ``size`` bytes at ``raw`` have the command layout ``m`` names, answer the awaited
    time with both deflections within their limits, disarm, run
    :func:`~fohssv_sim.kernels._fom_held_entry` on the tables ``t``, ``f`` with that input
    and, when the period stayed finite and |w| <= V, |theta| <= pi/2, write ``[t, z, w,
    theta, q]`` and hand the state to the sink; once it took it, write ``[t, Fp]`` and hand
    on the planing force, then the clock (``round(t * 1e9)`` ns) as ``m[_S_CLOCK]`` asks,
    and, with a ring, put the records of the state, the command (its bytes as received), the
    force and the clock, in that order, until one does not fit (``m[_S_RECORDS]`` the sample
    has, ``m[_S_PUT]`` were put). Then, the sample out, it prepares the next period
    (``kernels._prepare_period``, into the arrays ``m[_S_PREP_P]`` and ``m[_S_PREP_M]``,
    ``m[_S_PREPARED]`` its first step), which the next call uses when armed for that step
    (the node sets -1 when anything else may have changed the model's arrays). Returns the
    steps taken (state and force went out; ``g[_S_CLOCK_RET]`` says whether the clock did),
    or one of the ``_S_*`` results."""
    if m[_S_ARMED] == 0 or size != m[_S_CMD_SIZE]:
        return _S_NOT_TAKEN
    head = numba.carray(_as_pointer(m[_S_CMD_HEAD]), (12,), np.uint8)
    got = numba.carray(_as_pointer(raw), (size,), np.uint8)
    for i in range(12):
        if got[i] != head[i]:
            return _S_NOT_TAKEN
    at = m[_S_CMD_COUNT_AT]
    count = (np.int64(got[at]) | (np.int64(got[at + 1]) << 8) | (np.int64(got[at + 2]) << 16)
             | (np.int64(got[at + 3]) << 24))
    if count != m[_S_CMD_COUNT]:
        return _S_NOT_TAKEN
    cmd = numba.carray(_as_pointer(raw + m[_S_CMD_OFFSET]), (3,), np.float64)
    t_cmd = cmd[0]
    delta_f = cmd[1]
    delta_c = cmd[2]
    if not (t_cmd == g[_S_AWAITED] and abs(delta_f) <= g[_S_MAX_FIN]
            and abs(delta_c) <= g[_S_MAX_CAV]):
        return _S_NOT_TAKEN
    m[_S_ARMED] = 0
    law = numba.carray(_as_pointer(t[_T_LAW]), (t[_T_SHAPES + 1],), np.float64)
    law[8] = delta_f
    law[9] = delta_c
    steps = m[_S_STEPS]
    n = m[_S_N]
    P = numba.carray(_as_pointer(m[_S_PREP_P]), (steps, 8), np.float64)
    M = numba.carray(_as_pointer(m[_S_PREP_M]), (4, t[_T_SHAPES + 11]), np.float64)
    if m[_S_PREPARED] == n:   # prepared after the previous sample (the node unsets it else)
        taken = _fom_prepared_jit(t, f, n, steps, P, M)
        m[_S_PREP_USED] += 1
    else:
        taken = _fom_held_jit(t, f, n, steps)
    m[_S_PREPARED] = -1
    x = numba.carray(_as_pointer(t[_T_X]), (4,), np.float64)
    w = x[1]
    theta = x[2]
    v = g[_S_V]
    if not (taken == steps and -v <= w <= v and -g[_S_PITCH] <= theta <= g[_S_PITCH]):
        return _S_FAILED - taken
    out = numba.carray(_as_pointer(m[_S_OUT]), (5,), np.float64)
    t_out = (m[_S_MODEL_N] + steps) * g[_S_H]
    out[0] = t_out
    out[1] = x[0]
    out[2] = w
    out[3] = theta
    out[4] = x[3]
    m[_S_TAKEN] += 1
    m[_S_PUT] = 0
    ret = _call3(m[_S_SINK], m[_S_SINK_A], m[_S_SINK_B], 0)
    g[_S_RET] = ret
    if ret != 0:
        return _S_SINK_REFUSED
    if not _after_state(f, m, g, raw, size, t_out):
        return _S_FORCE_REFUSED
    # the state is out: what the next period's steps need that no command changes, now
    if _fom_prepare_jit(t, f, n + steps, steps, P, M):
        m[_S_PREPARED] = n + steps
    return steps


# -- the awaited command taken in compiled code: rcl's wait and take, then the sample --------

#: Slots of the int64 table ``w`` of :func:`_fom_take_entry`: the addresses of rcl's
#: ``rcl_take_serialized_message``, ``rcl_wait_set_clear``, ``rcl_wait_set_add_subscription``
#: and ``rcl_wait``; the wait set's, the subscription's and the received message's
#: (``rcl_serialized_message_t``: buffer, length, capacity, allocator) addresses; the wait's
#: timeout (ns); what rcl last returned when it was neither a message nor a timeout.
(_W_TAKE, _W_CLEAR, _W_ADD, _W_WAIT, _W_SET, _W_SUB, _W_MSG, _W_TIMEOUT, _W_RET) = range(9)
_W_SIZE = 9
#: :func:`_fom_take_entry`'s own results beside :func:`_fom_sample_entry`'s: nothing came
#: within the timeout; rcl failed to take or to wait (``w[_W_RET]`` says what it returned);
#: the wait ended but there was still nothing to take (the middleware's wait may wake for
#: a sample that is not data: the caller's turn, so no call outlasts one timeout).
_S_TIMED_OUT, _S_RCL_ERROR, _S_WOKEN = -4, -5, -6
#: rcl's return codes it tells apart (rcl/types.h): a take that found nothing, a wait that
#: timed out.
_RCL_TAKE_FAILED, _RCL_TIMEOUT = 401, 2

if numba is not None:
    _fom_sample_jit = numba.njit(error_model='numpy')(_fom_sample_entry)


def _fom_take_entry(t, f, m, g, w):   # pragma: no cover - compiled by its user
    """Wait for the next message on the subscription ``w`` names, take it and hand it to
    :func:`_fom_sample_entry` (which takes it as the awaited command, or leaves it:
    :data:`_S_NOT_TAKEN`, its bytes in ``w``'s message for the node's interpreted path):
    rcl's take first, and only when it finds nothing, the wait (cleared, the subscription
    added, at most ``w[_W_TIMEOUT]`` ns) and the take again, once. Returns the sample entry's
    result, :data:`_S_TIMED_OUT` when nothing came in time, :data:`_S_WOKEN` when the wait
    ended with nothing to take, or :data:`_S_RCL_ERROR` (``w[_W_RET]``: what rcl
    returned)."""
    sub = w[_W_SUB]
    msg = w[_W_MSG]
    for attempt in range(2):
        ret = _call4(w[_W_TAKE], sub, msg, 0, 0)
        if ret == 0:
            got = numba.carray(_as_pointer(msg), (2,), np.int64)
            return _fom_sample_jit(t, f, m, g, got[0], got[1])
        if ret != _RCL_TAKE_FAILED:
            w[_W_RET] = ret
            return _S_RCL_ERROR
        if attempt == 1:
            break
        wait_set = w[_W_SET]
        ret = _call1(w[_W_CLEAR], wait_set)
        if ret == 0:
            ret = _call3(w[_W_ADD], wait_set, sub, 0)
        if ret == 0:
            ret = _call2(w[_W_WAIT], wait_set, w[_W_TIMEOUT])
        if ret == _RCL_TIMEOUT:
            return _S_TIMED_OUT
        if ret != 0:
            w[_W_RET] = ret
            return _S_RCL_ERROR
    return _S_WOKEN
