"""keep_freed_memory: a node receiving large messages stops page-faulting them in."""

from __future__ import annotations

import subprocess
import sys

from conftest import interrupt
from depth_nodes.ros.memory import USER_VARIABLES, keep_freed_memory

#: Publisher (argv[1] == 'pub': 9.8 MB PointCloud2 messages at 20 Hz until killed) or raw
#: subscriber ('plain' or 'keep'), which prints the minor page faults it took while
#: receiving messages 5 to 24.
SCRIPT = '''
import resource, sys, time
from depth_nodes.ros.dds import use_large_message_profile
from depth_nodes.ros.memory import keep_freed_memory
use_large_message_profile()
role = sys.argv[1]
if role == 'keep':
    assert keep_freed_memory({})
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import PointCloud2
# Ctrl-C raises KeyboardInterrupt only: rclpy's own handler would shut the context down
# first, and a publish() caught between the two raised RCLError (a fresh-clone CI run)
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node('memory_' + role)
qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
if role == 'pub':
    pub = node.create_publisher(PointCloud2, 'cloud', qos)
    msg = PointCloud2(height=1, width=307200, point_step=32, row_step=9830400)
    msg.data = bytes(9830400)
    try:
        while True:
            pub.publish(msg)
            time.sleep(0.05)
    except KeyboardInterrupt:  # stopped by the test: shut down cleanly (see _faults)
        node.destroy_node()
        rclpy.try_shutdown()
        sys.exit(0)
faults = []
node.create_subscription(PointCloud2, 'cloud', lambda data: faults.append(
    resource.getrusage(resource.RUSAGE_SELF).ru_minflt), qos, raw=True)
deadline = time.monotonic() + 60
while len(faults) < 25 and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
assert len(faults) == 25, f'received {len(faults)} messages in 60 s'
print(faults[24] - faults[4])
node.destroy_node()
rclpy.shutdown()
'''


def _faults(mode: str, env: dict[str, str]) -> int:
    env = {k: v for k, v in env.items() if k not in USER_VARIABLES}
    publisher = subprocess.Popen([sys.executable, '-c', SCRIPT, 'pub'], env=env)
    try:
        out = subprocess.run([sys.executable, '-c', SCRIPT, mode], capture_output=True,
                             text=True, env=env, timeout=120, check=True)
    finally:
        interrupt(publisher)  # not a kill, which would leave its segment in /dev/shm
    assert publisher.returncode == 0  # it shut down cleanly (a kill gives -9)
    return int(out.stdout.split()[-1])


def test_a_raw_subscriber_of_large_messages_stops_page_faulting(
        ros_env: dict[str, str]) -> None:
    """20 messages of 9.8 MB (2400 pages each). Measured over seven runs: plain glibc
    faulted 16737 to 143362 pages in (its adaptive threshold sometimes catches up, often
    not), kept 1 or 2."""
    plain, kept = _faults('plain', ros_env), _faults('keep', ros_env)
    assert kept < 500, (plain, kept)
    assert plain > 10 * kept, (plain, kept)


def test_a_user_malloc_setting_wins() -> None:
    for name in USER_VARIABLES:
        assert not keep_freed_memory({name: '1'})
