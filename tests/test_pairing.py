"""Stereo pairer: nearest-in-time, each frame once, never crossing, survives restarts."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from appliance.runtime.pairing import StereoPairer

P = 33_333_333


def _feed(pairer, events, now_offset=None):
    """Push (time, side, id) events in time order; ``now`` = time + offset when given."""
    pairs = []
    for t, side, k in sorted(events):
        now = None if now_offset is None else t + now_offset
        pairs += pairer.push(side, t, k, now_ns=now)
    return pairs


def test_regular_streams_pair_one_to_one_with_their_offset() -> None:
    left = [(i * P, "left", i) for i in range(100)]
    right = [(i * P + 5_000_000, "right", i) for i in range(100)]
    pairer = StereoPairer(P)
    pairs = _feed(pairer, left + right, now_offset=10_000_000) + pairer.flush()
    assert [(p.left, p.right) for p in pairs] == [(i, i) for i in range(100)]
    assert {p.residual_ns for p in pairs} == {5_000_000}
    assert pairer.stats.unpaired_left == pairer.stats.unpaired_right == 0


def test_pairs_are_emitted_without_waiting_when_the_offset_is_small() -> None:
    pairer = StereoPairer(P)
    assert pairer.push("left", 0, "L0") == []
    pairs = pairer.push("right", 3_000_000, "R0")
    assert [(p.left, p.right) for p in pairs] == [("L0", "R0")]


def test_dropped_frame_leaves_its_partner_unpaired() -> None:
    left = [(i * P, "left", i) for i in range(10)]
    right = [(i * P + 2_000_000, "right", i) for i in range(10) if i != 4]
    pairer = StereoPairer(P)
    pairs = _feed(pairer, left + right) + pairer.flush()
    assert [p.left for p in pairs] == [0, 1, 2, 3, 5, 6, 7, 8, 9]
    assert [(s, k) for s, _, k in pairer.take_unpaired()] == [("left", 4)]


def test_the_nearer_of_two_candidates_wins() -> None:
    # right frame at 20 ms: left 0 is 20 ms away (beyond 16.7), left 33.3 is 13.3 ms away
    pairer = StereoPairer(P)
    pairs = _feed(pairer, [(0, "left", "a"), (P, "left", "b"), (20_000_000, "right", "r")])
    pairs += pairer.flush()
    assert [(p.left, p.right) for p in pairs] == [("b", "r")]
    # right frame at 15 ms: left 0 is 15 ms, left 33.3 is 18.3 ms -> a
    pairer = StereoPairer(P)
    pairs = _feed(pairer, [(0, "left", "a"), (P, "left", "b"), (15_000_000, "right", "r")])
    pairs += pairer.flush()
    assert [(p.left, p.right) for p in pairs] == [("a", "r")]


def test_one_camera_stopping_and_restarting() -> None:
    """Right stops for 3 s, restarts with a new phase; left frames are released meanwhile."""
    pairer = StereoPairer(P, max_delay_ns=100_000_000)
    events = [(i * P, "left", ("L", i)) for i in range(300)]
    events += [(i * P + 4_000_000, "right", ("R", i)) for i in range(60)]
    events += [(i * P + 11_000_000, "right", ("R2", i)) for i in range(150, 300)]
    pairs = []
    released_during_gap = 0
    for t, side, k in sorted(events):
        pairs += pairer.push(side, t, k, now_ns=t + 12_000_000)
        if 60 * P < t < 150 * P:
            released_during_gap = pairer.stats.unpaired_left
    assert released_during_gap > 80  # released while the right camera was away
    assert pairer.pending("left") <= 5  # nothing piles up
    pairs += pairer.flush()
    assert len(pairs) == 60 + 150
    assert all(abs(p.residual_ns) <= P // 2 for p in pairs)
    assert pairer.stats.unpaired_left == 90


def test_frame_older_than_its_predecessor_is_counted_not_paired() -> None:
    pairer = StereoPairer(P)
    pairer.push("left", 100 * P, "new")
    pairer.push("left", 10 * P, "old")
    assert pairer.stats.out_of_order == 1
    assert [k for _, _, k in pairer.take_unpaired()] == ["old"]


def test_queue_is_bounded() -> None:
    pairer = StereoPairer(P, max_queue=16)
    for i in range(100):
        pairer.push("left", i * P, i)
    assert pairer.pending("left") == 16
    assert pairer.stats.unpaired_left == 84


times = st.lists(st.integers(0, 2_000_000_000), min_size=0, max_size=60, unique=True)


@settings(max_examples=200, deadline=None)
@given(left=times, right=times, lag=st.integers(0, 300_000_000))
def test_properties_on_random_streams(left: list[int], right: list[int], lag: int) -> None:
    """Each frame once, never crossing, within tolerance, all frames accounted for; feeding
    online (with a host clock) gives the same pairs as offline (everything known)."""
    events = [(t, "left", ("L", t)) for t in left] + [(t, "right", ("R", t)) for t in right]
    online = StereoPairer(P, max_delay_ns=lag, min_interval_ns=0)
    pairs = _feed(online, events, now_offset=lag) + online.flush()
    offline = StereoPairer(P, min_interval_ns=0)
    ref = _feed(offline, events) + offline.flush()
    assert [(p.left, p.right) for p in pairs] == [(p.left, p.right) for p in ref]
    lefts = [p.left_ns for p in pairs]
    rights = [p.right_ns for p in pairs]
    assert lefts == sorted(set(lefts)) and rights == sorted(set(rights))  # once, monotone
    assert all(abs(p.residual_ns) <= P // 2 for p in pairs)
    s = online.stats
    assert 2 * s.pairs + s.unpaired_left + s.unpaired_right == len(events)


gaps = st.lists(st.integers(3 * P // 4, 3 * P), min_size=0, max_size=60)


@settings(max_examples=200, deadline=None)
@given(
    lgaps=gaps,
    rgaps=gaps,
    l0=st.integers(0, P),
    r0=st.integers(0, P),
    lag=st.integers(0, 300_000_000),
)
def test_camera_like_streams_get_nearest_partners(
    lgaps: list[int], rgaps: list[int], l0: int, r0: int, lag: int
) -> None:
    """With frames of one camera at least 0.75 period apart (real cameras; this is the
    min_interval shortcut's premise), no frame left unpaired would have been a strictly
    nearer partner of a member of any pair, and online equals offline."""
    left = np.cumsum([l0, *lgaps]).tolist()
    right = np.cumsum([r0, *rgaps]).tolist()
    events = [(t, "left", ("L", t)) for t in left] + [(t, "right", ("R", t)) for t in right]
    online = StereoPairer(P, max_delay_ns=lag)
    pairs = _feed(online, events, now_offset=lag) + online.flush()
    offline = StereoPairer(P, min_interval_ns=0)
    ref = _feed(offline, events) + offline.flush()
    assert [(p.left, p.right) for p in pairs] == [(p.left, p.right) for p in ref]
    unpaired = online.take_unpaired()
    for p in pairs:
        d = abs(p.residual_ns)
        for side, t, _ in unpaired:
            member = p.left_ns if side == "right" else p.right_ns
            assert abs(t - member) >= d
