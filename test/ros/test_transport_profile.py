"""
config/fastdds_large_clouds.xml: the Fast DDS profile for publishers of large clouds.

A camera driver that loads it writes whole frames into a shared-memory segment instead of
hundreds of 512 KiB fragments (docs/performance.md, the soak). Checked here: what the file
says, that Fast DDS takes it (the publisher's segment has the profile's size), and that a
frame-sized cloud published with it reaches the node.
"""

from __future__ import annotations

from pathlib import Path
import time
import xml.etree.ElementTree as ElementTree

import pytest
from support.data import REPO_ROOT
from support.ros_graph import CloudSource, Graph

PROFILE = REPO_ROOT / 'config' / 'fastdds_large_clouds.xml'
NAMESPACE = {'dds': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
#: An organized 300k-point frame as the soak and the pipeline benchmark send it (13.3 MB).
FRAME_BYTES = 13_257_009
#: The variable ROS 2 Jazzy's Fast DDS (2.x) reads its profile from.
PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
SHARED_MEMORY = Path('/dev/shm')


def _used_transports() -> tuple[dict[str, ElementTree.Element], ElementTree.Element]:
    """Return the default participant's transports by type, and that participant."""
    root = ElementTree.parse(PROFILE).getroot()
    declared = {
        element.findtext('dds:transport_id', namespaces=NAMESPACE): element
        for element in root.iterfind(
            'dds:transport_descriptors/dds:transport_descriptor', NAMESPACE
        )
    }
    participants = [
        element
        for element in root.iterfind('dds:participant', NAMESPACE)
        if element.get('is_default_profile') == 'true'
    ]
    assert len(participants) == 1, 'one default participant profile'
    names = [
        element.text or ''
        for element in participants[0].iterfind(
            'dds:rtps/dds:userTransports/dds:transport_id', NAMESPACE
        )
    ]
    assert set(names) <= set(declared), 'every used transport is declared'
    kinds = {
        declared[name].findtext('dds:type', namespaces=NAMESPACE): declared[name] for name in names
    }
    return kinds, participants[0]


def _shared_memory(field: str) -> int:
    """Return a number of the default participant's shared-memory transport (bytes)."""
    kinds, _ = _used_transports()
    return int(kinds['SHM'].findtext(f'dds:{field}', namespaces=NAMESPACE) or 0)


def test_the_profile_holds_whole_frames_in_shared_memory_and_keeps_udp():
    kinds, participant = _used_transports()
    # Other machines (RViz on a laptop) still need the network.
    assert set(kinds) == {'SHM', 'UDPv4'}
    assert (
        participant.findtext('dds:rtps/dds:useBuiltinTransports', namespaces=NAMESPACE) == 'false'
    )
    segment = _shared_memory('segment_size')
    message = _shared_memory('maxMessageSize')
    assert message >= FRAME_BYTES + 4096, 'a frame with its header goes in one piece'
    assert segment >= 4 * message, 'four frames in flight'


def _segments() -> dict[str, int]:
    """Return Fast DDS's shared-memory segments (not its ports) and their sizes in bytes."""
    return {
        path.name: path.stat().st_size
        for path in SHARED_MEMORY.glob('fastrtps_*')
        if not path.name.startswith('fastrtps_port') and not path.name.endswith('_el')
    }


def _largest_new(before: dict[str, int]) -> int:
    """Return the size of the largest segment not in `before` (0 when none)."""
    return max((size for name, size in _segments().items() if name not in before), default=0)


@pytest.mark.ros
@pytest.mark.skipif(
    not SHARED_MEMORY.is_dir(), reason='no /dev/shm: Fast DDS has no shared memory'
)
def test_a_publisher_with_the_profile_gets_its_segment_and_its_frames_reach_the_node():
    graph = Graph()
    try:
        before = _segments()
        with CloudSource('reliable', environment={PROFILE_VARIABLE: str(PROFILE)}) as source:
            # The segment's file holds the profile's bytes and the allocator's own (the
            # defaults give 549,408 bytes here).
            # The source may make a default-sized segment first: wait for the large one.
            segment = _shared_memory('segment_size')
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and _largest_new(before) < segment:
                time.sleep(0.05)
            assert _largest_new(before) >= segment, (
                f'no new segment of {segment} bytes: Fast DDS did not take {PROFILE.name}'
            )
            assert graph.spin_until(
                lambda: graph.node.cloud_input.matched >= 1 and source.subscription_count() >= 1,
                timeout_s=60.0,
            ), 'the source and the node did not match'
            points = FRAME_BYTES // 16  # create_cloud_xyz: 16 bytes a point
            for sec in (1, 2):
                source.publish(sec, points)
                assert graph.wait_for_answer(sec, 60.0), f'frame {sec} of {points} points lost'
    finally:
        graph.close()
