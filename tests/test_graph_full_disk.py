"""Issue 21, class 4: recording into a full filesystem ends in one line, exit 1 (an OS error,
docs/recording.md), no traceback from the exit handler, and leaves a bag that ``fohssv
repair`` restores once there is space. Needs root to mount a small tmpfs (skipped otherwise);
the states come from a publisher in the test process."""

from __future__ import annotations

import os
import subprocess
import time

import pytest
import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray
from test_graph_support import stop_all

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
