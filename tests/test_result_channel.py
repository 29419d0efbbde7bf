"""Results from worker processes to the daemon when a worker is killed at the worst moment.

Real spawned processes and real pipes; every wait is bounded.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.connection as mpc
import os
import signal
import time
from typing import Any

import numpy as np

from appliance.runtime.pool import free_if_orphaned
from appliance.runtime.result_channel import ResultReceiver, ResultSender

CTX = multiprocessing.get_context("spawn")
BIG = 3_000_000  # bytes: far more than a pipe holds (64 KiB), as a result with full fields


def _send(conn: Any, sizes: list[int], sent: Any) -> None:
    sender = ResultSender(conn, maxsize=4)
    for n in sizes:
        assert sender.put(np.full(n, 7, np.uint8), timeout=10.0)
    sent.set()
    sender.close(timeout=30.0)


def _start(receiver: ResultReceiver, sizes: list[int]) -> tuple[Any, Any]:
    sent = CTX.Event()
    with receiver.pipe() as pipe:
        proc = CTX.Process(target=_send, args=(pipe, sizes, sent), daemon=True)
        proc.start()
    return proc, sent


def _collect(receiver: ResultReceiver, n: int, timeout_s: float = 60.0) -> list[np.ndarray]:
    got: list[np.ndarray] = []
    t_end = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < t_end:
        got += receiver.get(timeout=0.1)
    return got


def _read_until_closed(receiver: ResultReceiver, timeout_s: float = 30.0) -> list[np.ndarray]:
    got: list[np.ndarray] = []
    t_end = time.monotonic() + timeout_s
    while receiver.open_pipes and time.monotonic() < t_end:
        got += receiver.get(timeout=0.1)
    return got


def test_results_of_two_workers_arrive_whole_and_the_pipes_close_with_them() -> None:
    receiver = ResultReceiver(CTX)
    try:
        (a, sent_a), (b, sent_b) = _start(receiver, [10, BIG]), _start(receiver, [20, 30])
        got = _collect(receiver, 4)
        assert sent_a.is_set() and sent_b.is_set()
        assert sorted(x.size for x in got) == [10, 20, 30, BIG]
        assert all(int(x.min()) == 7 == int(x.max()) for x in got)
        for p in (a, b):
            p.join(30)
            assert p.exitcode == 0
        assert _read_until_closed(receiver) == []  # the ends of file
        assert receiver.open_pipes == 0
    finally:
        receiver.close()


def test_a_worker_killed_halfway_through_a_result_does_not_stop_the_next_one() -> None:
    """The daemon does not read while a worker writes a 3 MB result; the worker is killed with
    the result half in its pipe. Reading then drops that pipe (no torn result, no hang), and
    a new worker's results arrive."""
    receiver = ResultReceiver(CTX)
    try:
        dead, sent = _start(receiver, [BIG])
        assert sent.wait(60)
        # Bytes in the pipe while the daemon reads nothing: the write has begun, and it
        # cannot have ended (the pipe holds 64 KiB of the 3 MB).
        assert mpc.wait(receiver._readers, timeout=30)
        os.kill(dead.pid, signal.SIGKILL)
        dead.join(30)
        assert dead.exitcode == -signal.SIGKILL
        new, sent_new = _start(receiver, [5, 6])
        got = _collect(receiver, 2)
        assert sent_new.is_set()
        assert sorted(x.size for x in got) == [5, 6]
        new.join(30)
        assert _read_until_closed(receiver) == []
        assert receiver.open_pipes == 0
    finally:
        receiver.close()


def test_a_full_buffer_is_reported_not_waited_on() -> None:
    """The daemon reads nothing: the worker's sender buffers ``maxsize`` results beyond the
    one being written, then ``put`` gives up after its timeout (the worker counts it)."""
    reader, writer = CTX.Pipe(duplex=False)
    sender = ResultSender(writer, maxsize=2)
    try:
        outcomes = [sender.put(np.zeros(BIG, np.uint8), timeout=0.5) for _ in range(5)]
        assert outcomes[:3] == [True] * 3 and outcomes[3:] == [False, False]
    finally:
        reader.close()  # the daemon is gone: the sender's write fails and its thread ends
        sender.close(timeout=5.0)
    assert writer.closed


def test_a_result_that_cannot_be_pickled_is_dropped_alone() -> None:
    reader, writer = CTX.Pipe(duplex=False)
    sender = ResultSender(writer, maxsize=4)
    try:
        assert sender.put(lambda: None, timeout=1.0)  # no pickle for a lambda
        assert sender.put(np.arange(3), timeout=1.0)
        assert reader.poll(30)
        assert reader.recv().tolist() == [0, 1, 2]
    finally:
        sender.close(timeout=5.0)
        reader.close()


def _hold(lock: Any) -> None:
    lock.acquire()  # and exit without releasing it


def test_a_lock_held_by_a_dead_process_is_given_back() -> None:
    lock = CTX.Lock()
    assert free_if_orphaned(lock, wait_s=0.1) is False  # nobody held it
    proc = CTX.Process(target=_hold, args=(lock,))
    proc.start()
    proc.join(30)
    assert proc.exitcode == 0
    assert lock.acquire(timeout=0.2) is False  # the dead process's
    assert free_if_orphaned(lock, wait_s=0.2) is True
    assert lock.acquire(timeout=0.2) is True
    lock.release()
