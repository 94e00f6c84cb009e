"""The Fast DDS profile depth_nodes processes use for their large messages.

Fast DDS's shared-memory transport defaults to a 512 KiB segment; images, disparity images
and point clouds are larger, and best-effort subscriptions (REP 2003) then lose messages
under load (measured: most frames of a 640x480 pipeline in separate processes). The
profile ``fastdds_large_messages.xml`` next to this module sets a 64 MiB segment.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping
from pathlib import Path

#: The packaged profile.
PROFILE = Path(__file__).resolve().parent / 'fastdds_large_messages.xml'
#: Variables through which Fast DDS 2.x (Jazzy) and 3.x find a profile file.
PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def use_large_message_profile(env: MutableMapping[str, str] | None = None) -> bool:
    """Point Fast DDS at :data:`PROFILE` in ``env`` (default: this process's environment,
    so call it before ``rclpy.init``).

    Nothing changes when a profile file is configured already (the user's choice wins),
    when ``RMW_IMPLEMENTATION`` names another middleware, or when the file is missing.

    Returns:
        Whether the profile was set.
    """
    env = os.environ if env is None else env
    if any(env.get(name) for name in PROFILE_VARIABLES) or not PROFILE.is_file():
        return False
    if not env.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp').startswith('rmw_fastrtps'):
        return False
    for name in PROFILE_VARIABLES:
        env[name] = str(PROFILE)
    return True
