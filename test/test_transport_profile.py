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

from conftest import REPO_ROOT
import pytest
from ros_graph import CloudSource, Graph

PROFILE = REPO_ROOT / 'config' / 'fastdds_large_clouds.xml'
NAMESPACE = {'dds': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
#: An organized 300k-point frame as the soak and the pipeline benchmark send it (13.3 MB).
FRAME_BYTES = 13_257_009
#: The variable ROS 2 Jazzy's Fast DDS (2.x) reads its profile from.
PROFILE_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
SHARED_MEMORY = Path('/dev/shm')


def _transports() -> tuple[dict[str, ElementTree.Element], list[str], ElementTree.Element]:
    """Return the declared transports by id, the default participant's and the participant."""
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
    used = [
        element.text or ''
        for element in participants[0].iterfind(
            'dds:rtps/dds:userTransports/dds:transport_id', NAMESPACE
        )
    ]
    return declared, used, participants[0]


def _segment_size() -> int:
    transports, used, _ = _transports()
    shared = [
        transports[name]
        for name in used
        if transports[name].findtext('dds:type', namespaces=NAMESPACE) == 'SHM'
    ]
    return int(shared[0].findtext('dds:segment_size', namespaces=NAMESPACE) or 0)


def test_the_profile_holds_whole_frames_in_shared_memory_and_keeps_udp():
    transports, used, participant = _transports()
    assert set(used) <= set(transports), 'every used transport is declared'
    kinds = {
        transports[name].findtext('dds:type', namespaces=NAMESPACE): transports[name]
        for name in used
    }
    # Other machines (RViz on a laptop) still need the network.
    assert set(kinds) == {'SHM', 'UDPv4'}
    assert (
        participant.findtext('dds:rtps/dds:useBuiltinTransports', namespaces=NAMESPACE) == 'false'
    )
    shared = kinds['SHM']
    segment = int(shared.findtext('dds:segment_size', namespaces=NAMESPACE) or 0)
    message = int(shared.findtext('dds:maxMessageSize', namespaces=NAMESPACE) or 0)
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
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and not _largest_new(before):
                time.sleep(0.05)
            assert _largest_new(before) >= _segment_size(), (
                f'no new segment of {_segment_size()} bytes: Fast DDS did not take {PROFILE.name}'
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
