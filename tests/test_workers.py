"""How the daemon's workers share the stream of triples."""

from __future__ import annotations

from appliance.runtime.workers import share_of_stream


def test_two_workers_take_every_other_triple_one_or_many_take_all() -> None:
    assert share_of_stream(0, 2) == (2, 0)
    assert share_of_stream(1, 2) == (2, 1)
    assert share_of_stream(0, 1) == (1, 0)
    # beyond two workers no state could prove succession (no shared frame): all phases
    assert [share_of_stream(i, 3) for i in range(3)] == [(1, 0)] * 3
