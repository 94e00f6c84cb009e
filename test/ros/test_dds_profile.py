"""The Fast DDS profile every depth_nodes process uses for large messages."""

from __future__ import annotations

import xml.etree.ElementTree as ET

from depth_nodes.ros.dds import PROFILE, PROFILE_VARIABLES, use_large_message_profile

NS = '{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}'


def test_profile_is_set_unless_the_user_chose_one_or_another_rmw() -> None:
    env: dict[str, str] = {}
    assert use_large_message_profile(env)
    assert env == dict.fromkeys(PROFILE_VARIABLES, str(PROFILE))
    mine = {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/mine.xml'}
    assert not use_large_message_profile(mine)
    assert mine == {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/mine.xml'}
    cyclone = {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'}
    assert not use_large_message_profile(cyclone)
    assert cyclone == {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'}
    assert use_large_message_profile({'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'})


def test_profile_is_the_default_participant_with_a_64_mib_shm_segment() -> None:
    root = ET.parse(PROFILE).getroot()
    (shm,) = [t for t in root.iter(f'{NS}transport_descriptor')
              if t.findtext(f'{NS}type') == 'SHM']
    assert int(shm.findtext(f'{NS}segment_size') or 0) == 64 * 1024 * 1024
    (participant,) = root.iter(f'{NS}participant')
    assert participant.get('is_default_profile') == 'true'
    used = [t.text for t in participant.iter(f'{NS}transport_id')]
    assert shm.findtext(f'{NS}transport_id') in used
    assert participant.findtext(f'{NS}rtps/{NS}useBuiltinTransports') == 'false'
