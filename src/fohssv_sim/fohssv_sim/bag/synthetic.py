"""Synthetic runs for tests of anything that reads bags (loader, analysis, player).

Contract messages serialized with rosbags (CDR identical to rclpy's), written with
:class:`~.writer.RunWriter` the way the recorder writes them: log time = round(t * 1e9),
``/clock`` at the same time, a flush every ``flush_every`` steps. Pure: no rclpy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import contract
from .writer import RunWriter, typestore

__all__ = ['METADATA', 'float64_array', 'clock', 'trajectory', 'write_bag', 'edit_metadata',
           'write_simulation']

METADATA = {'fohssv.version': '0.1.0', 'fohssv.plant_parameters': {'V': 75.0, 'model':
                                                                    'delay-free'}}


def float64_array(topic: contract.Topic, values) -> bytes:
    """``values`` as a serialized Float64MultiArray labelled with ``topic``'s fields."""
    ts = typestore()
    m = ts.types[contract.FLOAT64_ARRAY]
    layout = ts.types['std_msgs/msg/MultiArrayLayout']
    dim = ts.types['std_msgs/msg/MultiArrayDimension']
    msg = m(layout=layout(dim=[dim(label=topic.label, size=len(values), stride=len(values))],
                          data_offset=0), data=np.asarray(values, dtype=np.float64))
    return bytes(ts.serialize_cdr(msg, contract.FLOAT64_ARRAY))


def clock(t_ns: int) -> bytes:
    """A serialized rosgraph_msgs/Clock at ``t_ns``."""
    ts = typestore()
    time_t = ts.types['builtin_interfaces/msg/Time']
    msg = ts.types[contract.CLOCK.type](clock=time_t(sec=t_ns // 10**9, nanosec=t_ns % 10**9))
    return bytes(ts.serialize_cdr(msg, contract.CLOCK.type))


def trajectory(n: int, h: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """A deterministic, non-trivial trajectory: times n*h and states with awkward doubles."""
    t = np.arange(n) * h
    x = np.column_stack([np.sin(7.1 * t) / 3, np.cos(3.3 * t) * 1e-3, t ** 1.5 / 7,
                         np.exp(-t) / 9])
    return t, x


def write_bag(path: Path, n: int = 500, *, flush_every: int = 50, close: bool = True,
              chunk_size: int = 64 * 1024) -> tuple[np.ndarray, np.ndarray, RunWriter]:
    """Write ``n`` steps of :func:`trajectory` on every contract topic to a new bag at
    ``path``; ``close=False`` leaves it as a killed recorder would (no summary, no
    metadata.yaml). Returns (t, state, writer). The command is [t, -theta, q]; Fp = z."""
    t, x = trajectory(n)
    w = RunWriter(path, chunk_size=chunk_size).open()
    for topic in contract.TOPICS:
        name = topic.name if topic.name.startswith('/') else '/' + topic.name
        w.add_topic(name, topic.type)
    w.add_metadata(METADATA)
    for i in range(n):
        ns = round(t[i] * 1e9)
        w.write('/clock', ns, clock(ns))
        w.write('/state', ns, float64_array(contract.STATE, [t[i], *x[i]]))
        w.write('/planing_force', ns, float64_array(contract.PLANING_FORCE, [t[i], x[i, 0]]))
        w.write('/command', ns, float64_array(contract.COMMAND, [t[i], -x[i, 2], x[i, 3]]))
        if flush_every and (i + 1) % flush_every == 0:
            w.flush()
    if close:
        w.close()
    return t, x, w


def edit_metadata(bag: Path, **fields) -> None:
    """Overwrite ``fields`` of a closed bag's ``metadata.yaml`` (rosbag2_bagfile_information),
    e.g. with wrong shapes, for tests of bad input."""
    from ruamel.yaml import YAML

    yaml = YAML(typ='safe', pure=True)
    meta = Path(bag) / 'metadata.yaml'
    data = yaml.load(meta.read_text())
    data['rosbag2_bagfile_information'].update(fields)
    with meta.open('w') as f:
        yaml.dump(data, f)


def write_simulation(path: Path, result, plant_parameters: dict, *, commands: bool = True
                     ) -> Path:
    """Write an in-process run (:class:`fohssv_sim.simulate.SimulationResult` sampled every
    control period) as the recorder would record it from the lockstep plant: state, Fp and
    /clock at every sample, the command answering each sample but the last (``commands=False``
    leaves the command topic out), and ``plant_parameters`` as ``fohssv.plant_parameters``."""
    w = RunWriter(path).open()
    for topic in contract.TOPICS:
        if topic is contract.COMMAND and not commands:
            continue
        name = topic.name if topic.name.startswith('/') else '/' + topic.name
        w.add_topic(name, topic.type)
    w.add_metadata({'fohssv.version': '0.1.0',
                    'fohssv.plant_parameters': plant_parameters})
    t, x, fp, u = result.t, result.state, result.planing_force, result.inputs
    for i in range(t.size):
        ns = round(t[i] * 1e9)
        w.write('/clock', ns, clock(ns))
        w.write('/state', ns, float64_array(contract.STATE, [t[i], *x[i]]))
        w.write('/planing_force', ns, float64_array(contract.PLANING_FORCE, [t[i], fp[i]]))
        if commands and i < t.size - 1:
            w.write('/command', ns, float64_array(contract.COMMAND, [t[i], *u[i]]))
    w.close()
    return Path(path)
