"""What the daemon's workers share: registration shifts and differential images, the same
results as each worker computing its own."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from processing.chain import ChainState, compute_scene_flow
from tests.plane_sequence import GEOMETRY, PARAMS, sequence, triple
from tests.scene_flow_plane import SIZE


def test_shift_memo_answers_only_the_exact_frame_pair() -> None:
    from processing.chain.shifts import LocalShiftMemo

    memo = LocalShiftMemo(capacity=4)
    memo.put(0, 1.0, 2.0, (0.1, 0.0), False)
    memo.put(1, 1.0, 2.0, (0.0, 0.0), True)
    state = ChainState(shifts=memo)
    assert state.known_shifts((0.0, 1.0, 2.0)) == ((None, ((0.1, 0.0), False)),
                                                   (None, ((0.0, 0.0), True)))
    assert state.known_shifts((1.0, 2.0, 3.0)) == ((((0.1, 0.0), False), None),
                                                   (((0.0, 0.0), True), None))
    assert state.known_shifts((2.0, 3.0, 4.0)) == ((None, None), (None, None))
    assert state.shifts_reused == 4
    for k in range(8):  # bounded: the oldest entries go
        memo.put(0, 10.0 + k, 11.0 + k, (0.0, 0.0), False)
    assert memo.get(0, 1.0, 2.0) is None and memo.get(0, 17.0, 18.0) is not None


@pytest.mark.parametrize("shared", ["local", "multiprocessing"])
def test_two_workers_sharing_shifts_give_identical_results_with_half_the_estimates(
        shared: str) -> None:
    """Two states at stride 2 (the daemon's two workers) with one shift memo: every triple
    after the first takes one shift per camera from the other worker, and every result
    (fields, rejections) is bit-identical to workers that estimate all their shifts."""
    import multiprocessing

    from appliance.runtime.shiftshare import SharedShiftMemo, create_shift_table
    from processing.chain.shifts import LocalShiftMemo

    left, right, times = sequence(8)
    rng = np.random.default_rng(3)
    # sub-pixel camera jitter on both cameras (what registration removes)
    from processing.preprocess.translation import warp_translation
    left = [np.rint(warp_translation(f.astype(np.float32), tuple(rng.uniform(-0.3, 0.3, 2))))
            .astype(np.uint16) for f in left]
    right = [np.rint(warp_translation(f.astype(np.float32), tuple(rng.uniform(-0.3, 0.3, 2))))
             .astype(np.uint16) for f in right]
    seq = (left, right, times)
    params = dataclasses.replace(PARAMS, register=True)
    memo = (LocalShiftMemo() if shared == "local"
            else SharedShiftMemo(create_shift_table(multiprocessing.get_context("spawn"))))
    together = [ChainState(stride=2, shifts=memo) for _ in range(2)]
    apart = [ChainState(stride=2) for _ in range(2)]
    for k in range(6):
        a = compute_scene_flow(*triple(seq, k), GEOMETRY, params, together[k % 2])
        b = compute_scene_flow(*triple(seq, k), GEOMETRY, params, apart[k % 2])
        assert a.shifts_left == b.shifts_left and a.shifts_right == b.shifts_right
        assert a.rejected_shifts == b.rejected_shifts
        for f in ("flow", "disparity", "disparity_change", "velocity"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert sum(s.shifts_reused for s in together) == 2 * 5  # one per camera, triples 1-5
    assert sum(s.shifts_reused for s in apart) == 0


@pytest.mark.parametrize("register", [False, True])
def test_two_workers_sharing_differences_give_identical_results(register: bool) -> None:
    """Two states at stride 2 with one shared image table (the daemon's two workers, a
    spawn context's shared memory): where t1 stayed on its grid (registration off, or every
    shift of the moving plane rejected) each triple after the first takes D(t0) of both
    cameras from the other worker, and every result is bit-identical to workers that
    differentiate every pair themselves."""
    import multiprocessing

    from appliance.runtime.imageshare import SharedImages, create_image_table
    from processing.chain.shifts import LocalShiftMemo

    seq = sequence(9)
    params = dataclasses.replace(PARAMS, register=register, max_jitter_px=1e-6)
    table = create_image_table(multiprocessing.get_context("spawn"), (SIZE[1], SIZE[0]))
    memo = LocalShiftMemo()
    together = [ChainState(stride=2, shifts=memo, images=SharedImages(table))
                for _ in range(2)]
    apart = [ChainState(stride=2, shifts=memo) for _ in range(2)]
    for k in range(7):
        a = compute_scene_flow(*triple(seq, k), GEOMETRY, params, together[k % 2])
        b = compute_scene_flow(*triple(seq, k), GEOMETRY, params, apart[k % 2])
        for f in ("diff_left", "diff_right"):
            for x, y in zip(getattr(a, f), getattr(b, f), strict=True):
                np.testing.assert_array_equal(x, y)
        for f in ("flow", "disparity", "disparity_change", "velocity", "gas_mask"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert sum(s.differences_reused for s in together) == 6 * 2  # triples 1-6, both cameras
    assert sum(s.differences_reused for s in apart) == 0


def test_shared_images_answer_the_exact_key_and_keep_the_newest() -> None:
    """A shared table returns copies for the exact key and image count only, ignores
    images it cannot hold, and a new entry replaces the one written longest ago; a worker
    process reads what another wrote."""
    import multiprocessing

    from appliance.runtime.imageshare import SLOTS, SharedImages, create_image_table
    from processing.chain.images import difference_key

    def key(camera: int, t: float, settings: tuple = (1.0, None, 2.0)) -> tuple:
        return difference_key(camera, t, t + 1.0, (0.0, 0.0), settings)

    ctx = multiprocessing.get_context("spawn")
    table = create_image_table(ctx, (5, 4))  # W x H
    share = SharedImages(table)
    a = np.arange(20, dtype=np.float32).reshape(4, 5)
    share.put(key(0, 1.0), (a, a + 1))
    got = share.get(key(0, 1.0), 2)
    assert got is not None
    np.testing.assert_array_equal(got[0], a)
    np.testing.assert_array_equal(got[1], a + 1)
    got[0][:] = -1  # a copy: the table keeps its entry
    np.testing.assert_array_equal(share.get(key(0, 1.0), 2)[0], a)
    assert share.get(key(1, 1.0), 2) is None  # other camera
    assert share.get(key(0, 1.0, (1.0, None, 3.0)), 2) is None  # other settings
    assert share.get(key(0, 1.0), 1) is None  # other count
    share.put(key(0, 3.0), (np.zeros((5, 4), np.float32),))  # another size
    share.put(key(0, 4.0), (a.astype(np.float64),))  # another type
    assert share.get(key(0, 3.0), 1) is None and share.get(key(0, 4.0), 1) is None
    share.put(key(0, 5.0), (a,))
    for t in range(SLOTS - 1):  # the first entry is now the one written longest ago
        share.put(key(1, 10.0 + t), (a,))
    assert share.get(key(0, 1.0), 2) is None and share.get(key(0, 5.0), 1) is not None
    child = ctx.Process(target=_put_in_child, args=(table,))
    child.start()
    child.join(timeout=60)
    assert child.exitcode == 0
    got = share.get(difference_key(1, 99.0, 100.0, (0.5, 0.0), "x"), 1)
    assert got is not None and float(got[0].sum()) == 7.0 * 20


def _put_in_child(table) -> None:
    from appliance.runtime.imageshare import SharedImages
    from processing.chain.images import difference_key

    SharedImages(table).put(difference_key(1, 99.0, 100.0, (0.5, 0.0), "x"),
                            (np.full((4, 5), 7.0, np.float32),))


class _Lockstep:
    """An image table two worker threads share, where each triple's D(t1) is offered at
    the moment the other worker offers its own: the two compute their triples at the same
    time, as workers running flat out do."""

    def __init__(self, barrier: object) -> None:
        import threading

        self.table: dict[tuple, tuple[np.ndarray, ...]] = {}
        self.lock = threading.Lock()
        self.barrier = barrier

    def put(self, key: tuple, arrays: tuple[np.ndarray, ...]) -> None:
        with self.lock:
            self.table[key] = tuple(a.copy() for a in arrays)
        if key[0] == 1.0:  # the right camera's, the last of a triple
            self.barrier.wait()  # type: ignore[attr-defined]

    def get(self, key: tuple, count: int) -> tuple[np.ndarray, ...] | None:
        with self.lock:
            hit = self.table.get(key)
        return None if hit is None or len(hit) != count else tuple(a.copy() for a in hit)


def test_workers_computing_side_by_side_find_each_others_differences() -> None:
    """Two workers whose triples run side by side (each triple's D(t0) is the D(t1) the
    other computes at that moment) find it in every triple but the first: each looks
    D(t0) up again after sharing its D(t1). Results equal to the bit to workers that
    share nothing."""
    import threading

    seq = sequence(10)
    params = dataclasses.replace(PARAMS, register=False)
    share = _Lockstep(threading.Barrier(2, timeout=120))
    together = [ChainState(stride=2, images=share) for _ in range(2)]
    results: dict[int, object] = {}
    errors: list[BaseException] = []

    def work(offset: int) -> None:
        try:
            for k in range(offset, 8, 2):
                results[k] = compute_scene_flow(*triple(seq, k), GEOMETRY, params,
                                                together[offset])
        except BaseException as e:  # reported below, with the other thread released
            errors.append(e)
            share.barrier.abort()

    threads = [threading.Thread(target=work, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors, errors
    # the left worker's first triple has no predecessor; every other D(t0) was found
    assert [s.differences_reused for s in together] == [3 * 2, 4 * 2]
    apart = [ChainState(stride=2) for _ in range(2)]
    for k in range(8):
        b = compute_scene_flow(*triple(seq, k), GEOMETRY, params, apart[k % 2])
        for f in ("flow", "disparity", "disparity_change", "velocity", "gas_mask"):
            np.testing.assert_array_equal(getattr(results[k], f), getattr(b, f))
