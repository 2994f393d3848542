"""Write a run with RunWriter, read it back with our loader, rosbags' reader and mcap +
mcap_ros2; the structural check passes. Pure: no rclpy."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader
from ruamel.yaml import YAML

from fohssv_sim.bag import load_run
from fohssv_sim.bag.check import REQUIRED_METADATA_FIELDS, check
from fohssv_sim.bag.synthetic import METADATA, write_bag
from fohssv_sim.bag.writer import typestore

N = 400


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('bags') / 'run'
    t, x, _ = write_bag(path, N, flush_every=37)
    return path, t, x


def test_loader_returns_exact_series_and_times(bag):
    path, t, x = bag
    run = load_run(path)
    assert not run.truncated and run.recovery == ''
    assert np.array_equal(run.t, t) and np.array_equal(run.state, x)
    assert np.array_equal(run.planing_force_t, t) and np.array_equal(run.planing_force, x[:, 0])
    assert np.array_equal(run.command_t, t)
    assert np.array_equal(run.delta_f, -x[:, 2]) and np.array_equal(run.delta_c, x[:, 3])
    assert np.array_equal(run.log_time['state'], np.array([round(v * 1e9) for v in t]))
    assert np.array_equal(run.clock_t, run.log_time['state'] * 1e-9)
    assert run.topics == {'/clock': N, '/state': N, '/planing_force': N, '/command': N}
    assert run.metadata['fohssv.plant_parameters'] == METADATA['fohssv.plant_parameters']
    assert run.parameters['V'] == 75.0
    assert run.rejected == {'state': 0, 'planing_force': 0, 'command': 0}


def test_loader_accepts_dir_metadata_yaml_and_mcap_file(bag):
    path = bag[0]
    for p in (path, path / 'metadata.yaml', path / 'run.mcap'):
        assert len(load_run(p).t) == N


def test_rosbags_reader_reads_every_message(bag):
    path, t, x = bag
    ts = typestore()
    with Reader(path) as reader:
        assert reader.message_count == 4 * N
        conns = [c for c in reader.connections if c.topic == '/state']
        states = [ts.deserialize_cdr(raw, c.msgtype).data
                  for c, _, raw in reader.messages(connections=conns)]
    assert np.array_equal(np.array(states)[:, 1:], x)


def test_mcap_ros2_decodes_every_message(bag):
    path, t, x = bag
    with (path / 'run.mcap').open('rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary.statistics.message_count == 4 * N
        assert reader.get_header().profile == 'ros2'
        states = [m.data for _, c, _, m in reader.iter_decoded_messages(topics=['/state'])]
        names = {md.name for md in reader.iter_metadata()}
    assert np.array_equal(np.array(states)[:, 1:], x)
    assert names == {'fohssv', 'rosbag2'}
    chan = next(c for c in summary.channels.values() if c.topic == '/state')
    assert chan.metadata['topic_type_hash'].startswith('RIHS01_')
    assert 'offered_qos_profiles' in chan.metadata


def test_metadata_yaml_has_every_field_ros2_bag_info_reads(bag):
    info = YAML(typ='safe').load((bag[0] / 'metadata.yaml').read_text())
    info = info['rosbag2_bagfile_information']
    assert set(REQUIRED_METADATA_FIELDS) <= set(info)
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['message_count'] == 4 * N
    assert info['duration']['nanoseconds'] == round((N - 1) * 1e-3 * 1e9)
    assert info['custom_data']['fohssv.version'] == '0.1.0'


def test_structural_check_passes(bag):
    report = check(bag[0])
    assert report.ok, report.problems
    assert any('CRCs valid' in f for f in report.facts)


def test_structural_check_finds_a_flipped_byte(tmp_path):
    path = tmp_path / 'run'
    write_bag(path, 100, flush_every=10)
    mcap = path / 'run.mcap'
    data = bytearray(mcap.read_bytes())
    data[len(data) // 3] ^= 0x40
    mcap.write_bytes(bytes(data))
    report = check(path)
    assert not report.ok
    run = load_run(path)   # the loader still reads everything before the damage
    assert run.truncated and 0 < len(run.t) < 100
    assert 'corrupt' in run.recovery or 'truncated' in run.recovery
