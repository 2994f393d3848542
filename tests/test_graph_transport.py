"""Issue 21, class 5: localhost at the transport, not only at discovery. A running plant (and
its controller) binds no UDP socket on an address other than loopback: the package's Fast DDS
profile (config/fastdds_localhost.xml) is applied by the nodes themselves, here with the
profile variables removed from the environment (as in a shell without env.sh). The sockets are
read from /proc/<pid>/net/udp through the process's socket inodes, independently of Fast DDS.
FOHSSV_DDS_NETWORK=open leaves Fast DDS's defaults: the same check then finds a socket on
0.0.0.0 (the check can fail).

A user's own rclpy process started in a shell that sourced env.sh binds loopback only too:
env.sh exports ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET with the profile (rmw_fastrtps adds a UDP
transport on every interface for LOCALHOST, profile or not); with an explicit LOCALHOST, which
env.sh keeps (and says so), the same process binds outside loopback."""

from __future__ import annotations

import ipaddress
import os
import socket
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from test_graph_support import plant_args, stop_all

import rosproc

pytestmark = pytest.mark.graph


def _inodes(pid: int) -> set[str]:
    out = set()
    for fd in Path(f'/proc/{pid}/fd').iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith('socket:['):
            out.add(target[8:-1])
    return out


def udp_addresses(pid: int) -> list[str]:
    """The local IPv4 addresses of the UDP sockets process ``pid`` holds."""
    inodes = _inodes(pid)
    found = []
    for line in Path(f'/proc/{pid}/net/udp').read_text().splitlines()[1:]:
        fields = line.split()
        if fields[9] in inodes:
            addr_hex = fields[1].split(':')[0]
            found.append(socket.inet_ntoa(struct.pack('<I', int(addr_hex, 16))))
    return found


def _outside(addresses: list[str]) -> list[str]:
    # a multicast group (239.255.0.1, joined on the loopback interface) is not an interface
    return [a for a in addresses if not ipaddress.ip_address(a).is_loopback
            and not ipaddress.ip_address(a).is_multicast]


def _sockets_of_a_waiting_plant(**extra: str) -> list[str]:
    env = {k: v for k, v in rosproc.ros_env().items()
           if k not in ('FASTDDS_DEFAULT_PROFILES_FILE', 'FASTRTPS_DEFAULT_PROFILES_FILE')}
    env.update(extra)
    plant = rosproc.start('fohssv_sim', 'plant', plant_args(model='delay-free', duration=0.0),
                          env=env)
    try:
        rosproc.wait_for(lambda: plant.poll() is not None or len(udp_addresses(plant.pid)) >= 3,
                         90, what='the plant to open its sockets')
        return udp_addresses(plant.pid)
    finally:
        stop_all(plant)


def test_a_plant_binds_udp_on_loopback_only():
    addresses = _sockets_of_a_waiting_plant()
    assert addresses and not _outside(addresses), addresses


def test_fohssv_dds_network_open_leaves_fast_dds_defaults():
    addresses = _sockets_of_a_waiting_plant(FOHSSV_DDS_NETWORK='open')
    assert _outside(addresses), addresses


ROOT = Path(__file__).resolve().parents[1]
#: A user's own node: a subscriber, as anyone writes one after `source env.sh`.
_OWN_NODE = ('import os, time, rclpy; from std_msgs.msg import String; rclpy.init(); '
             'n = rclpy.create_node("mine"); '
             'n.create_subscription(String, "chatter", lambda m: None, 10); '
             'print("RANGE=" + os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"], flush=True); '
             'time.sleep(120)')


def _sockets_of_an_env_sh_process(*exports: str) -> tuple[list[str], str, str]:
    """(UDP addresses, stdout's first line, stderr) of an rclpy process started by a clean
    shell that exported ``exports`` and then sourced env.sh."""
    env = {'PATH': '/usr/local/bin:/usr/bin:/bin', 'HOME': os.environ.get('HOME', '/root'),
           'ROS_DOMAIN_ID': str(rosproc.unique_domain_id())}
    script = ''.join(f'export {e}; ' for e in exports) + (
        f'source "{ROOT}/env.sh" && exec python -c \'{_OWN_NODE}\'')
    proc = subprocess.Popen(['bash', '-c', script], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        line = proc.stdout.readline()         # after rclpy.init and the node: exec kept the pid
        rosproc.wait_for(lambda: proc.poll() is not None or len(udp_addresses(proc.pid)) >= 3,
                         90, what='the process to open its sockets')
        addresses = udp_addresses(proc.pid)
    finally:
        proc.kill()
        _, err = proc.communicate(timeout=30)
    return addresses, line.strip(), err


def test_an_rclpy_process_after_env_sh_binds_udp_on_loopback_only():
    addresses, line, err = _sockets_of_an_env_sh_process()
    assert line == 'RANGE=SUBNET', (line, err)
    assert addresses and not _outside(addresses), addresses
    assert 'fohssv:' not in err, err                 # nothing to say about the defaults


def test_env_sh_keeps_an_explicit_localhost_and_says_what_it_costs():
    addresses, line, err = _sockets_of_an_env_sh_process('ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST')
    assert line == 'RANGE=LOCALHOST', (line, err)
    assert 'fohssv: keeping your ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST' in err, err
    assert _outside(addresses), addresses            # rmw_fastrtps's own any-interface UDP


#: A process that makes a participant and a reliable writer (where the default DataWriter
#: profile applies) and exits.
_WRITER = ('import rclpy; from std_msgs.msg import String; rclpy.init(); '
           'n = rclpy.create_node("writer"); n.create_publisher(String, "chatter", 10); '
           'print("made", flush=True)')


def _fast_dds_errors(profile: Path) -> tuple[str, str]:
    env = rosproc.ros_env(FASTDDS_DEFAULT_PROFILES_FILE=str(profile))
    env.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
    out = subprocess.run([sys.executable, '-c', _WRITER], env=env,
                         capture_output=True, text=True, timeout=120)
    return out.stdout, out.stderr


def test_the_package_profile_loads_without_a_fast_dds_error(tmp_path):
    """Fast DDS drops a whole profile file it cannot parse (transports included) and says so
    on stderr; the installed profile, with its DataWriter timing, loads cleanly. A copy with
    the writer timing misspelt (the camel case of older documentation) shows the check sees
    such an error."""
    from fohssv_sim.ros.startup import localhost_profile

    ours = Path(localhost_profile())
    assert 'nack_supression_duration' in ours.read_text()
    out, err = _fast_dds_errors(ours)
    assert out.strip() == 'made' and 'XMLPARSER' not in err, err
    bad = tmp_path / 'misspelt.xml'
    bad.write_text(ours.read_text().replace('nack_supression_duration', 'nackSupressionDuration'))
    out, err = _fast_dds_errors(bad)
    assert out.strip() == 'made' and 'XMLPARSER' in err and str(bad) in err, err
