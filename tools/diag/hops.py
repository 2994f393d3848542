"""A lockstep node with its round trip timed hop by hop (a diagnostic tool).

    python tools/diag/hops.py plant DIR --ros-args -p mode:=lockstep ...
    python tools/diag/hops.py controller DIR

Runs the product's node (the plant, or the eq. 31 controller node ``state_feedback``) as
``ros2 run`` does, with two timestamps per round trip taken on ``CLOCK_MONOTONIC`` (one clock
for every process of the machine): when the callback that answers the peer is entered, and
when its answer's publish has returned. The plant's callback is the lockstep command callback
and its answer the next ``state``; the controller's callback is its ``state`` callback and its
answer the ``command``. ``bench/ros_echo.py --hops DIR`` takes the same two timestamps in the
bare echo's ping and pong, at the same places, at the same cost (a ``monotonic_ns`` call and
an array store, under 1 us).

From the four series, :func:`hops` gives each hop of the round trip: the DDS delivery each way
(publish returned -> callback entered in the other process) and each process's work (callback
entered -> its answer published). Written at exit as ``DIR/ROLE_in.npy`` and ``ROLE_out.npy``
(int64 ns).
"""

from __future__ import annotations

import atexit
import sys
from pathlib import Path
from time import monotonic_ns

import numpy as np

#: At most this many round trips are timed (a longer run keeps its first ones).
CAPACITY = 1_000_000


class Stamps:
    """Callback-entered and answer-published times, saved at exit as ``DIR/ROLE_*.npy``."""

    def __init__(self, folder: str, role: str) -> None:
        self.entered = np.zeros(CAPACITY, dtype=np.int64)
        self.answered = np.zeros(CAPACITY, dtype=np.int64)
        self.n_in = self.n_out = 0
        self._path = Path(folder) / role
        atexit.register(self.save)

    def enter(self) -> None:
        i = self.n_in
        if i < CAPACITY:
            self.entered[i] = monotonic_ns()
            self.n_in = i + 1

    def answer(self) -> None:
        i = self.n_out
        if i < CAPACITY:
            self.answered[i] = monotonic_ns()
            self.n_out = i + 1

    def save(self) -> None:
        np.save(f'{self._path}_in.npy', self.entered[:self.n_in])
        np.save(f'{self._path}_out.npy', self.answered[:self.n_out])


def _instrument(cls: type, callback: str, send: str, stamps: Stamps) -> None:
    """Time ``cls.callback`` (entry) and the instance's ``send`` (return), set in __init__."""
    inner = getattr(cls, callback)

    def timed_callback(self, raw: bytes) -> None:
        stamps.enter()
        inner(self, raw)

    init = cls.__init__

    def timed_init(self, *args, **kwargs) -> None:
        init(self, *args, **kwargs)
        publish = getattr(self, send)

        def timed_send(payload):
            publish(payload)
            stamps.answer()

        setattr(self, send, timed_send)

    setattr(cls, callback, timed_callback)
    cls.__init__ = timed_init


def hops(lead: str, peer: str, folder: str, skip: int = 1000) -> dict[str, dict[str, float]]:
    """Each hop of the round trips ``lead`` (the one whose answer starts a round trip: ping,
    plant) -> ``peer`` -> ``lead`` from their saved stamps, the first ``skip`` round trips
    left out (the start): median and 90th percentile in us of ``delivery_to_peer``, ``peer``
    (its work), ``delivery_to_lead``, ``lead`` and the ``round_trip``. The k-th answer of the
    lead is the one the peer's k-th callback took (lockstep: one answer per message each way);
    raises RuntimeError when the series do not pair so (a lost or extra message: counts that
    differ, hops of minus a round trip)."""
    load = {k: np.load(Path(folder) / f'{k}.npy')
            for k in (f'{lead}_out', f'{peer}_in', f'{peer}_out', f'{lead}_in')}
    n = min(len(v) for v in load.values()) - 1
    if n <= skip + 100:
        raise RuntimeError(f'too few round trips timed: {n}')
    out0 = load[f'{lead}_out'][:n]
    out1 = load[f'{lead}_out'][1:n + 1]
    p_in, p_out, l_in = load[f'{peer}_in'][:n], load[f'{peer}_out'][:n], load[f'{lead}_in'][:n]
    parts = {'delivery_to_peer': p_in - out0, peer: p_out - p_in,
             'delivery_to_lead': l_in - p_out, lead: out1 - l_in, 'round_trip': out1 - out0}
    # A hop can be negative: the receiver may enter its callback before the sender's publish
    # has returned (the sender preempted after waking it; with idle CPUs polling,
    # cpu_dma_latency, a delivery takes a few us), now and then by more than half a round
    # trip. A series paired wrongly (a lost or extra message: lockstep, so one per side at
    # most in the counts) is off by a whole round trip from there on.
    counts = [len(v) for v in load.values()]
    wrong = -0.5 * float(np.median(parts['round_trip']))
    for name, d in parts.items():
        if max(counts) - min(counts) > 2 or (d < wrong).mean() > 0.05:
            raise RuntimeError(f'the {name} series does not pair the messages: stamps '
                               f'{counts}, {int((d < wrong).sum())} of {n} below minus half a '
                               'round trip')
    return {name: {'median_us': float(np.median(d[skip:])) / 1e3,
                   'p90_us': float(np.percentile(d[skip:], 90)) / 1e3}
            for name, d in parts.items()}


def main() -> int:
    role, folder = sys.argv[1], sys.argv[2]
    del sys.argv[1:3]                   # the node parses the rest (--ros-args ...)
    stamps = Stamps(folder, role)
    if role == 'plant':
        from fohssv_sim.ros import plant_node
        _instrument(plant_node.PlantNode, '_on_command_lockstep', '_send_state', stamps)
        plant_node.main()
    elif role == 'controller':
        from fohssv_controller.ros import controller_node
        _instrument(controller_node.ControllerNode, '_on_state', '_send_command', stamps)
        controller_node.main_state_feedback()
    else:
        raise SystemExit(f'role {role!r}: plant or controller')
    return 0


if __name__ == '__main__':
    sys.exit(main())
