"""keep_freed_memory: a node receiving large messages stops page-faulting them in."""

from __future__ import annotations

import subprocess
import sys

from helpers import interrupt

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
from sensor_msgs.msg import PointCloud2
rclpy.init()
node = rclpy.create_node('memory_' + role)
qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
if role == 'pub':
    pub = node.create_publisher(PointCloud2, 'cloud', qos)
    msg = PointCloud2(height=1, width=307200, point_step=32, row_step=9830400)
    msg.data = bytes(9830400)
    # stopped by the test's Ctrl-C: rclpy's handler shuts the context down (which also
    # frees a publish() waiting for a reader that left), then Python raises
    # KeyboardInterrupt; a publish() caught in between raises an RCLError instead.
    # Either way the publisher shuts down cleanly (see _faults).
    try:
        while rclpy.ok():
            pub.publish(msg)
            time.sleep(0.05)
    except KeyboardInterrupt:
        pass
    except Exception:
        if rclpy.ok():
            raise
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


#: glibc's initial mmap threshold (128 KiB), held fixed for the 'plain' subscriber.
GLIBC_INITIAL_THRESHOLD = '131072'


def _faults(mode: str, env: dict[str, str]) -> int:
    env = {k: v for k, v in env.items() if k not in USER_VARIABLES}
    subscriber_env = dict(env)
    if mode == 'plain':
        # glibc starts with a 128 KiB threshold and raises it after the first large free,
        # but not reliably: over seven runs it faulted 16737 to 143362 pages in, and once
        # in 16 runs under load only 2. Held at its initial value, the baseline is the
        # behaviour glibc starts with, every run.
        subscriber_env['MALLOC_MMAP_THRESHOLD_'] = GLIBC_INITIAL_THRESHOLD
    publisher = subprocess.Popen([sys.executable, '-c', SCRIPT, 'pub'], env=env)
    try:
        out = subprocess.run([sys.executable, '-c', SCRIPT, mode], capture_output=True,
                             text=True, env=subscriber_env, timeout=120, check=True)
    finally:
        interrupt(publisher)  # not a kill, which would leave its segment in /dev/shm
    assert publisher.returncode == 0  # it shut down cleanly (a kill gives -9)
    return int(out.stdout.split()[-1])


def test_a_raw_subscriber_of_large_messages_stops_page_faulting(
        ros_env: dict[str, str]) -> None:
    """20 messages of 9.8 MB (2400 pages each): glibc with its initial threshold faults
    about 2400 pages in per message, keep_freed_memory 1 or 2 in all."""
    plain, kept = _faults('plain', ros_env), _faults('keep', ros_env)
    assert kept < 500, (plain, kept)
    assert plain > 10 * kept, (plain, kept)


def test_a_user_malloc_setting_wins() -> None:
    for name in USER_VARIABLES:
        assert not keep_freed_memory({name: '1'})
