"""Issue 21, class 4: recording into a full filesystem ends in one line, exit 1 (an OS error,
docs/recording.md), no traceback from the exit handler, and leaves a bag that ``fohssv
repair`` restores once there is space. Needs root to mount a small tmpfs (skipped otherwise);
the states come from a publisher in the test process."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time

import pytest
import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray
from test_graph_support import plant_args, stop_all

from fohssv_sim.bag import load_run

import rosproc

pytestmark = pytest.mark.graph


@pytest.fixture
def small_disk(tmp_path):
    where = tmp_path / 'disk'
    where.mkdir()
    if os.geteuid() != 0 or subprocess.run(
            ['mount', '-t', 'tmpfs', '-o', 'size=200k', 'tmpfs', str(where)],
            capture_output=True).returncode != 0:
        pytest.skip('needs root to mount a small tmpfs')
    try:
        yield where
    finally:
        subprocess.run(['umount', '-l', str(where)], capture_output=True)


def test_a_full_disk_ends_in_one_line_and_the_bag_repairs(small_disk, tmp_path):
    domain = rosproc.unique_domain_id()
    env = rosproc.ros_env(domain)
    bag, log = small_disk / 'bag', tmp_path / 'recorder.log'
    rec = rosproc.start('fohssv_sim', 'recorder', [
        '--ros-args', '-p', f'bag_path:={bag}', '-p', 'plant_node:=none', '-p',
        'topics:=[state]'], env=env, log=log)
    ctx = rosproc.init_context(domain)          # the nodes' discovery settings
    node = rclpy.create_node('plant', context=ctx)
    try:
        pub = node.create_publisher(Float64MultiArray, 'state', QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=2000, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        rosproc.wait_for(lambda: pub.get_subscription_count() >= 1, 90, what='the recorder')
        k = 0
        deadline = time.monotonic() + 120
        while rec.poll() is None and time.monotonic() < deadline:   # about 3000 fill 200 KiB
            for _ in range(200):
                try:
                    pub.publish(Float64MultiArray(data=[k * 1e-4, 0.0, 0.0, 0.0, 0.0]))
                except Exception:  # noqa: BLE001 - RCLError: the reader is behind; slow down
                    time.sleep(0.05)
                    break
                k += 1
            time.sleep(0.02)
        code = rosproc.wait_exit(rec, 60)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        stop_all(rec)
    text = log.read_text()
    errors = [ln for ln in text.splitlines() if 'error' in ln.lower()]
    assert code == 1, text
    assert 'Traceback' not in text, text
    assert len(errors) == 1 and 'No space left on device' in errors[0], text
    assert f'fohssv repair {bag}' in errors[0]
    subprocess.run(['mount', '-o', 'remount,size=8m', str(small_disk)], check=True)
    fohssv = rosproc.executable('fohssv_sim', 'fohssv')
    repaired = subprocess.run([str(fohssv), 'repair', str(bag)], capture_output=True, text=True,
                              env=env, timeout=120)
    assert repaired.returncode == 0, repaired.stdout + repaired.stderr
    checked = subprocess.run([str(fohssv), 'check', str(bag)], capture_output=True, text=True,
                             env=env, timeout=120)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert load_run(bag).topics['/state'] > 1000


def _fill(disk) -> None:
    """Fill ``disk`` to its last byte."""
    fd = os.open(disk / 'filler', os.O_WRONLY | os.O_CREAT)
    try:
        while os.write(fd, b'\0' * 512):
            pass
    except OSError:
        pass
    finally:
        os.close(fd)


def _hosted_plant(bag, log):
    """A hosted lockstep run of 1 s at 1e-4 s (10 001 samples, about 2.5 MB of messages)
    recorded in-plant to ``bag``."""
    return rosproc.start('fohssv_sim', 'plant', plant_args(
        model='delay-free', mode='lockstep', duration=1.0, control_period=1e-4,
        controller='state_feedback', min_state_subscribers=0, end_linger=0.0,
        record=str(bag)), env=rosproc.ros_env(), log=log)


def test_inplant_recording_onto_a_full_disk_is_refused_and_leaves_nothing(small_disk,
                                                                          tmp_path):
    """Issue 51.5: the disk is full before the run: the plant refuses ``record`` in one line
    naming "No space left" (exit 2), and leaves no bag directory behind (a 0-byte bag.mcap
    blocked the path before)."""
    _fill(small_disk)
    bag, log = small_disk / 'bag', tmp_path / 'plant.log'
    plant = _hosted_plant(bag, log)
    try:
        code = rosproc.wait_exit(plant, 120)
    finally:
        stop_all(plant)
    text = log.read_text()
    assert code == 2, text
    assert 'Traceback' not in text, text
    lines = [ln for ln in text.splitlines() if 'No space left' in ln]
    assert len(lines) == 1 and 'record' in lines[0], text
    assert not bag.exists()


@pytest.mark.parametrize('late', [False, True], ids=['during-the-run', 'after-the-run'])
def test_inplant_recording_that_fills_the_disk_says_so_once_and_counts_the_rest(small_disk,
                                                                                 tmp_path,
                                                                                 late):
    """Issue 51.5: a small disk fills during the run: one line naming "No space left" (no
    writer traceback), the run goes on and ends with exit 8, and the summary's record_lost is
    exactly what the bag lacks (the run's 4 a sample: state, force, clock and a command for
    each sample but the last, and the views, counted against the bag repaired), wherever the
    disk filled: the writer keeps the records it released and its last flush mark in the
    ring's header, and the plant counts the bag's complete chunks after that mark. The disk
    holds one 1 MiB chunk of the bag, not all of it. ``late``: the writer is stopped
    (SIGSTOP) from its start until the run ended, so the disk fills after the run's end, as
    under load, where the writer (a batch job) drains the ring behind the run: the summary
    said record_lost 0 then, logged before the writer died (a CI run with three workers)."""
    subprocess.run(['mount', '-o', 'remount,size=1600k', str(small_disk)], check=True)
    bag, log = small_disk / 'bag', tmp_path / 'plant.log'
    plant = _hosted_plant(bag, log)
    try:
        if late:
            rosproc.wait_for(lambda: 'writer ready' in log.read_text(), 120, what='the writer')
            writer = int(re.search(r'writer process (\d+)', log.read_text()).group(1))
            os.kill(writer, signal.SIGSTOP)
            try:
                rosproc.wait_for(lambda: 'stopping cleanly' in log.read_text(), 120,
                                 what="the run's end")
            finally:
                os.kill(writer, signal.SIGCONT)
        code = rosproc.wait_exit(plant, 300)
    finally:
        stop_all(plant)
    text = log.read_text()
    assert code == 8, text
    assert 'Traceback' not in text, text
    lines = [ln for ln in text.splitlines() if 'No space left' in ln]
    assert len(lines) == 1 and 'in-plant recording: the writer process failed' in lines[0], text
    if late:
        assert text.index('stopping cleanly') < text.index('No space left'), text
    summary = rosproc.summary(text)
    # a view is 5 messages: pose, twist, wrench and two markers (the body, the cavity)
    made = (3 * summary['published_states'] + summary['hosted_commands']
            + 5 * summary['views'])
    subprocess.run(['mount', '-o', 'remount,size=8m', str(small_disk)], check=True)
    fohssv = rosproc.executable('fohssv_sim', 'fohssv')
    repaired = subprocess.run([str(fohssv), 'repair', str(bag)], capture_output=True,
                              text=True, timeout=120)
    assert repaired.returncode == 0, repaired.stdout + repaired.stderr
    held = sum(load_run(bag).topics.values())
    assert 0 < held < made
    assert summary['record_lost'] == made - held, (held, made, summary['record_lost'])
