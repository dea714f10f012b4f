"""The input's take policy: probes of the frame rate choose how clouds are taken."""

from __future__ import annotations

from mvbb_ros.ros.take_policy import PROBE_MARGIN, STALE_WINDOW, TakePolicy
import pytest


class Clock:
    """A monotonic clock the test moves."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def stream(policy: TakePolicy, clock: Clock, seconds: float, free_hz: float, every_hz: float):
    """Run frames for `seconds` at the rate of the way of taking in force; return the modes."""
    modes = []
    end = clock.now + seconds
    while clock.now < end:
        clock.now += 1.0 / (every_hz if policy.every_cloud else free_hz)
        policy.frame_done()
        modes.append(policy.every_cloud)
    return modes


def test_it_takes_when_free_until_a_probe_says_otherwise():
    clock = Clock()
    policy = TakePolicy(clock, probe_every_s=20.0, probe_s=2.0)
    assert not policy.every_cloud and 'no probe yet' in policy.description()
    # Before the first probe: only when free, whatever the rates would be.
    assert not any(stream(policy, clock, 19.0, free_hz=15.0, every_hz=21.0))
    # A probe: 1 s settling and 2 s counting each way.
    stream(policy, clock, 8.0, free_hz=15.0, every_hz=21.0)
    assert policy.probes == 1 and policy.every_cloud
    probe = policy.last_probe
    assert probe is not None and probe.chose_every_cloud
    assert probe.every_cloud == pytest.approx(21.0, rel=0.1)
    assert probe.when_free == pytest.approx(15.0, rel=0.1)
    assert policy.description().startswith('every cloud as it arrives (last probe: 2')


def test_a_transport_that_keeps_up_keeps_taking_when_free():
    clock = Clock()
    policy = TakePolicy(clock, probe_every_s=20.0, probe_s=2.0)
    modes = stream(policy, clock, 96.0, free_hz=26.0, every_hz=22.0)  # probes at 20, 46, 72 s
    assert policy.probes == 3 and not policy.every_cloud
    # Every cloud is taken during the probes' first windows only: 3 s of every 26.
    share = sum(modes) / len(modes)
    assert 0.06 < share < 0.13, share


def test_taking_every_cloud_must_win_by_the_margin():
    clock = Clock()
    policy = TakePolicy(clock, probe_every_s=20.0, probe_s=2.0)
    stream(policy, clock, 30.0, free_hz=20.0, every_hz=20.0 * (1.0 + PROBE_MARGIN / 2))
    assert policy.probes == 1 and not policy.every_cloud  # a tie keeps the lower latency


def test_a_later_probe_goes_back_when_the_transport_changes():
    clock = Clock()
    policy = TakePolicy(clock, probe_every_s=20.0, probe_s=2.0)
    stream(policy, clock, 30.0, free_hz=15.0, every_hz=21.0)
    assert policy.every_cloud
    stream(policy, clock, 30.0, free_hz=26.0, every_hz=22.0)  # a larger segment, say
    assert policy.probes == 2 and not policy.every_cloud


def test_a_probe_window_across_a_pause_is_dropped():
    clock = Clock()
    policy = TakePolicy(clock, probe_every_s=20.0, probe_s=2.0)
    stream(policy, clock, 21.0, free_hz=20.0, every_hz=20.0)  # the first window has begun
    assert 'probing' in policy.description()
    clock.now += STALE_WINDOW * 2.0 + 1.0  # the stream pauses
    policy.frame_done()
    assert policy.probes == 0 and not policy.every_cloud
    assert 'probing' not in policy.description()


def test_disabled_it_always_takes_when_free():
    clock = Clock()
    policy = TakePolicy(clock, probe_every_s=20.0, probe_s=2.0)
    stream(policy, clock, 30.0, free_hz=15.0, every_hz=21.0)
    assert policy.every_cloud
    policy.enabled = False
    assert policy.frame_done() is True and not policy.every_cloud
    assert not any(stream(policy, clock, 60.0, free_hz=15.0, every_hz=21.0))
    assert policy.description() == 'when the frame worker is free (input_depth above 1)'
