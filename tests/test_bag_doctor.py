"""Bags written by the project pass ``pymcap-cli doctor`` (an MCAP checker we did not write)
with no error and no warning: a complete run, a run without messages, and a killed run after
``repair``. And the checker does find the two faults bags used to have, so a clean verdict
means something: a file with a summary offset for an empty attachment-index group and
duplicate metadata names (written here with the mcap library directly)."""

from __future__ import annotations

import shutil

from mcap.reader import make_reader
from mcap.writer import Writer

from fohssv_sim.bag import load_run
from fohssv_sim.bag.check import check
from fohssv_sim.bag.repair import repair
from fohssv_sim.bag.synthetic import METADATA, write_bag
from fohssv_sim.bag.writer import RunWriter

from mcap_doctor import assert_doctor_clean, doctor


def _metadata_names(mcap) -> list[str]:
    with open(mcap, 'rb') as f:
        return [m.name for m in make_reader(f).iter_metadata()]


def test_complete_bag_is_doctor_clean_with_unique_metadata_names(tmp_path):
    _, _, w = write_bag(tmp_path / 'run', n=300)
    w2 = RunWriter(tmp_path / 'two').open()    # two metadata records, as the recorder writes
    w2.add_topic('/state', 'std_msgs/msg/Float64MultiArray')
    w2.add_metadata({'fohssv.version': '0.1.0'})
    w2.add_metadata({'fohssv.plant_parameters': {'V': 84.5}})
    w2.close()
    summary = assert_doctor_clean(w.mcap_path)
    assert summary['messages'] == 4 * 300
    assert_doctor_clean(w2.mcap_path)
    names = _metadata_names(w2.mcap_path)
    assert sorted(names) == ['fohssv', 'fohssv.2', 'rosbag2']
    # both records still reach the run's metadata
    meta = load_run(tmp_path / 'two').metadata
    assert meta['fohssv.version'] == '0.1.0' and meta['fohssv.plant_parameters'] == {'V': 84.5}


def test_bag_without_messages_is_doctor_clean(tmp_path):
    w = RunWriter(tmp_path / 'empty').open()
    w.add_topic('/state', 'std_msgs/msg/Float64MultiArray')
    w.add_metadata(METADATA)
    w.close()
    assert assert_doctor_clean(w.mcap_path)['messages'] == 0
    bare = RunWriter(tmp_path / 'bare').open()     # stopped before it declared a topic
    bare.close()
    assert_doctor_clean(bare.mcap_path)


def test_repaired_killed_bag_is_doctor_clean(tmp_path):
    bag = tmp_path / 'killed'
    _, _, w = write_bag(bag, n=400, flush_every=50, close=False)
    assert doctor(w.mcap_path)[0]['errors'] > 0        # cut: no summary, no footer
    assert repair(bag).repaired
    assert_doctor_clean(bag / 'killed.mcap')
    assert load_run(bag).metadata['fohssv.repaired']


def test_doctor_reports_the_faults_bags_used_to_have(tmp_path):
    path = tmp_path / 'old.mcap'
    with path.open('wb') as f:
        w = Writer(f)                    # default: every index type, attachments included
        w.start(profile='ros2')
        schema = w.register_schema('std_msgs/msg/Float64MultiArray', 'ros2msg', b'float64[] data')
        channel = w.register_channel('/state', 'cdr', schema)
        w.add_message(channel, log_time=0, publish_time=0, data=b'\x00\x01\x00\x00' + bytes(4))
        w.add_metadata('fohssv', {'a': '1'})
        w.add_metadata('fohssv', {'b': '2'})
        w.finish()
    codes = {(f['severity'], f['code']) for f in doctor(path)[1]}
    assert ('error', 'SUMMARY_OFFSET_WITHOUT_GROUP') in codes
    assert ('warning', 'METADATA_NAME_DUPLICATE') in codes


def test_check_rejects_a_damaged_summary_as_the_doctor_does(tmp_path):
    """A byte flipped in the summary section (channels, statistics, indexes, offsets): the
    doctor finds an error, and so must ``check`` (the footer's summary CRC covers it)."""
    bag = tmp_path / 'run'
    write_bag(bag, n=200, flush_every=50)
    mcap = bag / 'run.mcap'
    data = mcap.read_bytes()
    assert check(bag).ok, check(bag).problems
    summary_start = int.from_bytes(data[-8 - 20:-8 - 12], 'little')
    footer = len(data) - 8 - 29
    by_crc = 0
    # the first schema record, the middle of the summary, the last summary-offset record
    positions = (summary_start + 12, (summary_start + footer) // 2, footer - 5)
    for k, pos in enumerate(positions):
        damaged = tmp_path / f'd{k}'
        damaged.mkdir()
        shutil.copy(bag / 'metadata.yaml', damaged / 'metadata.yaml')
        flipped = bytearray(data)
        flipped[pos] ^= 0x5A
        (damaged / 'run.mcap').write_bytes(bytes(flipped))
        assert doctor(damaged / 'run.mcap')[0]['errors'] > 0, pos
        report = check(damaged)
        assert not report.ok, pos
        by_crc += any('summary CRC mismatch' in p for p in report.problems)
    assert by_crc >= 2      # a damaged record length can make the summary unreadable
