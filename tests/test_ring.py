"""Shared-memory ring of stereo pairs: never blocks, newest windows, skip counts, torn reads."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest

from appliance.runtime.ring import PairRing, RingHandle

SHAPE = (24, 32)


def _pair(i: int) -> tuple[np.ndarray, np.ndarray]:
    left = np.full(SHAPE, i, np.uint16)
    return left, left + 1000


def _fill(ring: PairRing, start: int, stop: int) -> None:
    for i in range(start, stop):
        left, right = _pair(i)
        ring.write(left, right, pair_index=i, t_left_mono_ns=10 * i, t_right_mono_ns=10 * i + 3)


def test_newest_window_and_metadata() -> None:
    with PairRing.create(8, SHAPE) as ring:
        assert ring.take_newest(3) is None  # empty
        _fill(ring, 0, 2)
        assert ring.take_newest(3) is None  # fewer than 3 pairs
        _fill(ring, 2, 5)
        lease = ring.take_newest(3)
        assert lease is not None
        assert lease.seqs == [2, 3, 4]
        assert [int(a[0, 0]) for a in lease.left] == [2, 3, 4]
        assert [int(a[0, 0]) for a in lease.right] == [1002, 1003, 1004]
        assert [m["pair_index"] for m in lease.meta] == [2, 3, 4]
        assert lease.meta[0]["t_right_mono_ns"] == 23 and lease.meta[0]["t_wall_ns"] == -1
        assert lease.skipped == 2  # windows ending at pairs 2 and 3 were never taken
        assert not lease.left[0].flags.writeable  # readers cannot scribble on the ring
        assert ring.outstanding_leases == 1
        assert lease.release()
        assert ring.outstanding_leases == 0
        assert ring.take_newest(3) is None  # nothing new
        _fill(ring, 5, 6)
        lease = ring.take_newest(3)
        assert lease is not None and lease.seqs == [3, 4, 5] and lease.skipped == 0
        lease.release()


def test_writer_overwrites_oldest_and_counts() -> None:
    with PairRing.create(4, SHAPE) as ring:
        _fill(ring, 0, 10)  # nobody reads: 6 pairs overwritten
        st = ring.stats()
        assert (st.written, st.overwrites, st.occupancy) == (10, 6, 4)
        lease = ring.take_newest(3)
        assert lease is not None and lease.seqs == [7, 8, 9] and lease.skipped == 7
        assert [int(a[0, 0]) for a in lease.left] == [7, 8, 9]
        lease.release()
        assert ring.stats().occupancy == 0


def test_lease_detects_overwrite_while_reading() -> None:
    with PairRing.create(4, SHAPE) as ring:
        _fill(ring, 0, 3)
        lease = ring.take_newest(3)
        assert lease is not None and lease.intact()
        copied = lease.copy()
        assert copied is not None and copied[0][:, 0, 0].tolist() == [0, 1, 2]
        _fill(ring, 3, 5)  # the writer laps the reader: slot of pair 0 now holds pair 4
        assert not lease.intact()
        assert lease.copy() is None
        assert not lease.release()
        with pytest.raises(RuntimeError):
            lease.intact()


def test_bad_input_raises() -> None:
    with pytest.raises(ValueError, match="capacity must be >= 3"):
        PairRing.create(2, SHAPE)
    with PairRing.create(4, SHAPE) as ring:
        with pytest.raises(ValueError, match=r"left image is \(24, 31\)"):
            ring.write(np.zeros((24, 31), np.uint16), np.zeros(SHAPE, np.uint16))
        with pytest.raises(ValueError, match="float32"):
            ring.write(np.zeros(SHAPE, np.uint16), np.zeros(SHAPE, np.float32))
        with pytest.raises(ValueError, match="unknown metadata"):
            ring.write(*_pair(0), colour=3)
        with pytest.raises(ValueError, match=r"k must be in 1\.\.capacity-1 = 3, got 4"):
            ring.take_newest(4)


def _worker(handle: RingHandle, out: multiprocessing.Queue) -> None:
    ring = PairRing.attach(handle)
    lease = ring.take_newest(3)
    assert lease is not None
    result = ([int(a.sum()) for a in lease.left], lease.seqs, lease.skipped, lease.release())
    del lease
    ring.close()
    out.put(result)


def test_worker_process_reads_in_place_and_claims_are_shared() -> None:
    ctx = multiprocessing.get_context("spawn")
    with PairRing.create(8, SHAPE, ctx=ctx) as ring:
        _fill(ring, 0, 6)
        out = ctx.Queue()
        proc = ctx.Process(target=_worker, args=(ring.handle(), out))
        proc.start()
        sums, seqs, skipped, intact = out.get(timeout=60)
        proc.join(30)
        assert proc.exitcode == 0
        assert seqs == [3, 4, 5] and skipped == 3 and intact
        assert sums == [i * SHAPE[0] * SHAPE[1] for i in (3, 4, 5)]
        # The worker claimed that window: this process sees nothing new until a new pair.
        assert ring.take_newest(3) is None
        _fill(ring, 6, 7)
        lease = ring.take_newest(3)
        assert lease is not None and lease.seqs == [4, 5, 6] and lease.skipped == 0
        lease.release()
        # The ring survived the worker's exit (it detached, it did not unlink).
        assert ring.stats().written == 7


def test_writer_never_waits_for_readers() -> None:
    """Readers serialise their claims on a lock; the writer never takes it."""
    import threading

    with PairRing.create(4, SHAPE) as ring:
        with ring._lock:  # a reader stuck inside take_newest()
            t = threading.Thread(target=_fill, args=(ring, 0, 100))
            t.start()
            t.join(30)
            assert not t.is_alive()
        assert ring.stats().written == 100


def test_strided_takes_split_the_triples_between_two_readers() -> None:
    """Stride 2: phase 0 gets windows ending at even pairs, phase 1 at odd ones."""
    img = np.zeros((4, 5), np.uint16)
    with PairRing.create(16, (4, 5)) as ring:
        for i in range(4):
            ring.write(img, img, pair_index=i)
        a = ring.take_newest(3, stride=2, phase=1)  # newest end 3
        assert a is not None and a.seqs == [1, 2, 3] and a.skipped == 0
        a.release()
        b = ring.take_newest(3, stride=2, phase=0)  # newest even end 2
        assert b is not None and b.seqs == [0, 1, 2] and b.skipped == 0
        b.release()
        assert ring.take_newest(3, stride=2, phase=0) is None
        ring.write(img, img, pair_index=4)
        c = ring.take_newest(3, stride=2, phase=0)
        assert c is not None and c.seqs == [2, 3, 4] and c.skipped == 0
        c.release()
        for i in range(5, 10):
            ring.write(img, img, pair_index=i)
        # phase 1 last took end 3; ends 5 and 7 were never taken, 9 is the newest
        d = ring.take_newest(3, stride=2, phase=1)
        assert d is not None and d.seqs == [7, 8, 9] and d.skipped == 2
        d.release()
        with pytest.raises(ValueError, match="stride"):
            ring.take_newest(3, stride=2, phase=2)


def test_in_order_takes_stay_consecutive_while_the_lag_is_small() -> None:
    img = np.zeros((4, 5), np.uint16)
    with PairRing.create(16, (4, 5)) as ring:
        for i in range(3):
            ring.write(img, img, pair_index=i)
        a = ring.take_newest(3, max_lag=4)
        assert a is not None and a.seqs == [0, 1, 2]
        a.release()
        for i in range(3, 7):
            ring.write(img, img, pair_index=i)  # newest is 6, the next window ends at 3
        b = ring.take_newest(3, max_lag=4)
        assert b is not None and b.seqs == [1, 2, 3] and b.skipped == 0
        b.release()
        for i in range(7, 12):
            ring.write(img, img, pair_index=i)  # the next window (end 4) lags 7 > 4
        c = ring.take_newest(3, max_lag=4)
        assert c is not None and c.seqs == [9, 10, 11] and c.skipped == 7
        c.release()
        # with two phases each reader's windows follow each other in order
        d = ring.take_newest(3, stride=2, phase=1, max_lag=4)
        assert d is not None and d.seqs == [9, 10, 11]
        d.release()
        for i in range(12, 16):
            ring.write(img, img, pair_index=i)
        e = ring.take_newest(3, stride=2, phase=1, max_lag=4)
        assert e is not None and e.seqs == [11, 12, 13] and e.skipped == 0
        e.release()
        with pytest.raises(ValueError, match="max_lag"):
            ring.take_newest(3, max_lag=16)
