"""Preallocated ring buffer of stereo pairs in shared memory, between acquisition and workers.

The acquisition side (one writer, in the daemon process) copies each stereo pair into the next
slot and never blocks: when the ring is full it overwrites the oldest pair. Worker processes
attach to the same shared memory by name and read the images in place - no pickling, no copy
unless they ask for one.

Readers take the newest ``k`` consecutive pairs (the method needs t0, t1, t2: paper Sec. 3);
windows are claimed under a lock shared by the readers (the writer never takes it), so two
workers never process the same window, and each take reports how many windows were skipped
since the previous take (processing fell behind; raw recording is unaffected).

Slots are lent out explicitly as a :class:`PairLease`. Each slot carries a generation counter
written like a seqlock: odd while the writer copies into it, ``2 * seq + 2`` once pair ``seq``
is complete. A lease remembers the generations it saw; :meth:`PairLease.intact` tells whether
the writer has since overwritten any of its slots, so a reader can discard a result computed
from torn data (or :meth:`PairLease.copy` first, then check).

Shared layout: an int64 header (head, last claimed window end, overwrites), a structured
metadata array of ``capacity`` records, then ``capacity`` left and ``capacity`` right images.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.synchronize
from dataclasses import dataclass
from multiprocessing import resource_tracker, shared_memory
from typing import Any

import numpy as np

__all__ = ["LEFT", "MAX_STRIDE", "META_DTYPE", "RIGHT", "PairLease", "PairRing", "RingHandle",
           "RingStats"]

#: Per-slot metadata (all int64; ns times are ``time.monotonic_ns()`` / UNIX ns).
META_DTYPE = np.dtype([
    ("gen", "<i8"),            # seqlock generation: odd = being written, 2*seq+2 = complete
    ("seq", "<i8"),            # ring write sequence number (0, 1, 2, ...)
    ("pair_index", "<i8"),     # the pairer's pair index
    ("left_seq", "<i8"),       # camera frame sequence numbers
    ("right_seq", "<i8"),
    ("t_left_mono_ns", "<i8"),
    ("t_right_mono_ns", "<i8"),
    ("t_wall_ns", "<i8"),
    ("cameras", "<i8"),        # which images the slot holds: LEFT | RIGHT bits
])
#: Bits of the ``cameras`` metadata: the slot holds the left / the right camera's image
#: (a pair holds both; while a camera is lost, or at a single-camera site, only one).
LEFT, RIGHT = 1, 2
_META_FIELDS = tuple(n for n in META_DTYPE.names if n not in ("gen", "seq"))  # type: ignore[union-attr]
_HEAD, _CLAIMED, _OVERWRITES = 0, 1, 2
_PHASE_CLAIMED = 3  # words 3 .. 3 + MAX_STRIDE - 1: last window end taken per phase
#: Largest stride of :meth:`PairRing.take_newest`.
MAX_STRIDE = 4
_HEADER_WORDS = 8


@dataclass(frozen=True)
class RingHandle:
    """Everything a worker process needs to attach (picklable; pass it as a Process argument).

    The lock is a ``multiprocessing`` lock: pass the handle when starting the process.
    """

    name: str
    capacity: int
    shape: tuple[int, int]
    dtype: str
    lock: Any


@dataclass(frozen=True)
class RingStats:
    """Counters of the ring (read without locking; approximate under concurrent writes)."""

    capacity: int
    written: int
    occupancy: int  # pairs newer than the last claimed window (the processing backlog)
    overwrites: int
    last_claimed: int


class PairLease:
    """Views into ``k`` consecutive slots lent to a reader.

    Attributes
    ----------
    seqs
        Ring sequence numbers of the pairs, oldest first.
    left, right
        Lists of (H, W) read-only views into shared memory, oldest first. Valid only while
        :meth:`intact` is true; do not keep them past :meth:`release`.
    meta
        One dict per pair with the fields of :data:`META_DTYPE` (pair_index, times, ...).
    skipped
        Windows skipped since the previous take by any reader (processing behind).
    """

    def __init__(self, ring: PairRing, slots: list[int], gens: list[int], skipped: int) -> None:
        self._ring = ring
        self._slots = slots
        self._gens = gens
        self.skipped = skipped
        self.seqs = [(g - 2) // 2 for g in gens]
        self.left = [ring._view(ring._left, s) for s in slots]
        self.right = [ring._view(ring._right, s) for s in slots]
        self.meta = [{f: int(ring._meta[f][s]) for f in _META_FIELDS} for s in slots]
        self._released = False

    def intact(self) -> bool:
        """True when no slot of this lease has been overwritten since it was lent."""
        if self._released:
            raise RuntimeError("lease already released")
        gen = self._ring._meta["gen"]
        return all(int(gen[s]) == g for s, g in zip(self._slots, self._gens, strict=True))

    def copy(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Copy the images out: ((k, H, W), (k, H, W)), or None if overwritten meanwhile."""
        left = np.stack(self.left)
        right = np.stack(self.right)
        return (left, right) if self.intact() else None

    def release(self) -> bool:
        """Give the slots back; returns :meth:`intact` at this moment (False: torn data)."""
        ok = self.intact()
        self._released = True
        self.left = []
        self.right = []
        self._ring._leases -= 1
        return ok


class PairRing:
    """A ring of ``capacity`` stereo pairs of (H, W) images in shared memory.

    Create it in the daemon with :meth:`create`, pass :meth:`handle` to worker processes, and
    :meth:`attach` there. The creator calls :meth:`unlink` at shutdown (``with`` does it).
    """

    def __init__(self, shm: shared_memory.SharedMemory, capacity: int, shape: tuple[int, int],
                 dtype: np.dtype, lock: Any, owner: bool) -> None:
        if capacity < 3:
            raise ValueError(f"ring capacity must be >= 3 (t0, t1, t2), got {capacity}")
        self._shm = shm
        self.capacity = capacity
        self.shape = (int(shape[0]), int(shape[1]))
        self.dtype = np.dtype(dtype)
        self._lock = lock
        self._owner = owner
        self._leases = 0
        buf = shm.buf
        off = 0
        self._header = np.ndarray((_HEADER_WORDS,), "<i8", buf, off)
        off += self._header.nbytes
        self._meta = np.ndarray((capacity,), META_DTYPE, buf, off)
        off += self._meta.nbytes
        img_bytes = capacity * self.shape[0] * self.shape[1] * self.dtype.itemsize
        self._left = np.ndarray((capacity, *self.shape), self.dtype, buf, off)
        self._right = np.ndarray((capacity, *self.shape), self.dtype, buf, off + img_bytes)

    @staticmethod
    def nbytes(capacity: int, shape: tuple[int, int], dtype: Any) -> int:
        """Shared memory size for a ring of this geometry."""
        img = shape[0] * shape[1] * np.dtype(dtype).itemsize
        return 8 * _HEADER_WORDS + capacity * META_DTYPE.itemsize + 2 * capacity * img

    @classmethod
    def create(cls, capacity: int, shape: tuple[int, int], dtype: Any = np.uint16,
               ctx: Any = None) -> PairRing:
        """Allocate a new ring (the writer side). ``ctx``: multiprocessing context for the lock."""
        if capacity < 3:
            raise ValueError(f"ring capacity must be >= 3 (t0, t1, t2), got {capacity}")
        if len(shape) != 2 or min(shape) < 1:
            raise ValueError(f"ring image shape must be (H, W), got {shape}")
        shm = shared_memory.SharedMemory(create=True, size=cls.nbytes(capacity, shape, dtype))
        lock = (ctx or multiprocessing.get_context("spawn")).Lock()
        ring = cls(shm, capacity, shape, np.dtype(dtype), lock, owner=True)
        ring._header[:] = 0
        ring._header[_CLAIMED] = -1
        ring._header[_PHASE_CLAIMED:_PHASE_CLAIMED + MAX_STRIDE] = -1
        ring._meta["gen"] = 0
        return ring

    @classmethod
    def attach(cls, handle: RingHandle, *, shared_tracker: bool = False) -> PairRing:
        """Attach to an existing ring by handle (the reader side, in a worker process).

        ``shared_tracker``: True for a process started by ``multiprocessing`` from the
        creator, which shares the creator's resource tracker. Otherwise (an independent
        process) Python < 3.13 registers the attached segment with the process's own tracker,
        which would unlink the ring when the reader exits, so the registration is dropped;
        doing that in a child that shares the creator's tracker would instead drop the
        creator's registration.
        """
        shm = shared_memory.SharedMemory(name=handle.name)
        if not shared_tracker:
            try:
                resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]
            except (AttributeError, KeyError, ValueError):
                pass
        return cls(shm, handle.capacity, handle.shape, np.dtype(handle.dtype), handle.lock,
                   owner=False)

    @property
    def reader_lock(self) -> Any:
        """The readers' lock (``multiprocessing.Lock``): the daemon gives it back if a reader
        died holding it (:func:`appliance.runtime.pool.free_if_orphaned`)."""
        return self._lock

    def handle(self) -> RingHandle:
        """The picklable description for :meth:`attach`."""
        return RingHandle(self._shm.name, self.capacity, self.shape, self.dtype.str, self._lock)

    # ------------------------------------------------------------------ writer

    def write(self, left: np.ndarray | None, right: np.ndarray | None, **meta: int) -> int:
        """Copy one stereo pair into the next slot; never blocks. Returns its sequence number.

        Parameters
        ----------
        left, right
            (H, W) arrays of the ring's shape and dtype; one of them None for a frame of
            one camera alone (the slot's ``cameras`` bits say which it holds; the other
            image of the slot is left as it was). 8-bit frames are widened into a 16-bit
            ring (the counts do not change).
        **meta
            Any of pair_index, left_seq, right_seq, t_left_mono_ns, t_right_mono_ns, t_wall_ns.

        Raises
        ------
        ValueError
            Wrong image shape or dtype, no image, or an unknown metadata field.
        """
        if left is None and right is None:
            raise ValueError("ring.write: no image")
        for side, img in (("left", left), ("right", right)):
            if img is None:
                continue
            if img.shape != self.shape or not (img.dtype == self.dtype or (
                    img.dtype == np.uint8 and self.dtype == np.uint16)):
                raise ValueError(f"ring.write: {side} image is {img.shape} {img.dtype}, the ring "
                                 f"holds {self.shape} {self.dtype}")
        unknown = set(meta) - set(_META_FIELDS)
        if unknown:
            raise ValueError(f"ring.write: unknown metadata {sorted(unknown)}")
        meta["cameras"] = (LEFT if left is not None else 0) | (RIGHT if right is not None else 0)
        seq = int(self._header[_HEAD])
        slot = seq % self.capacity
        if seq >= self.capacity:
            lost = seq - self.capacity  # the pair being overwritten
            if lost > int(self._header[_CLAIMED]):
                self._header[_OVERWRITES] += 1  # never part of a processed window's end
        m = self._meta
        m["gen"][slot] = 2 * seq + 1  # odd: being written
        if left is not None:
            self._left[slot] = left
        if right is not None:
            self._right[slot] = right
        m["seq"][slot] = seq
        for f in _META_FIELDS:
            m[f][slot] = int(meta.get(f, -1))
        m["gen"][slot] = 2 * seq + 2  # complete
        self._header[_HEAD] = seq + 1
        return seq

    # ------------------------------------------------------------------ readers

    def take_newest(self, k: int = 3, *, stride: int = 1, phase: int = 0,
                    max_lag: int | None = None) -> PairLease | None:
        """Lend the newest ``k`` consecutive pairs if their window was not taken yet.

        Parameters
        ----------
        k : int
            Window length (3 for a triple).
        stride, phase : int
            Take only windows whose last pair's sequence number is ``phase`` modulo
            ``stride`` (1 <= stride <= MAX_STRIDE, 0 <= phase < stride). Two workers with
            stride 2 and phases 0 and 1 then see every other triple each, so that each can
            start from its own previous triple (:mod:`processing.chain.state`); ``skipped``
            counts the windows of this phase that were never taken.
        max_lag : int, optional
            Hand windows out in order instead: the one right after this phase's last
            window, as long as it ends at most ``max_lag`` pairs behind the newest pair;
            beyond that, the newest (the windows in between are skipped). A reader that
            starts each triple from its previous one stays warm this way while it lags a
            little, instead of jumping to the newest window and starting cold.

        Returns
        -------
        PairLease or None
            None when fewer than ``k`` pairs exist or no new window of this phase arrived
            since the last take.
        """
        if not 1 <= k <= self.capacity - 1:
            raise ValueError(f"k must be in 1..capacity-1 = {self.capacity - 1}, got {k}")
        if max_lag is not None and not 0 <= max_lag <= self.capacity - k - 1:
            raise ValueError(f"max_lag must be in 0..capacity-k-1 = {self.capacity - k - 1}, "
                             f"got {max_lag}")
        if not (1 <= stride <= MAX_STRIDE and 0 <= phase < stride):
            raise ValueError(f"need 1 <= stride <= {MAX_STRIDE} and 0 <= phase < stride, "
                             f"got stride {stride}, phase {phase}")
        word = _CLAIMED if stride == 1 else _PHASE_CLAIMED + phase
        with self._lock:
            head = int(self._header[_HEAD])
            newest = head - 1
            end = newest - (newest - phase) % stride  # newest window end of this phase
            claimed = int(self._header[word])
            first = k - 1 + (phase - (k - 1)) % stride  # first window end of this phase
            if end < first or end <= claimed:
                return None
            if max_lag is not None and claimed >= first and newest - (claimed + stride) <= max_lag:
                end = claimed + stride  # the next window of this phase, in order
            skipped = (end - max(claimed, first - stride)) // stride - 1
            self._header[word] = end
            self._header[_CLAIMED] = max(int(self._header[_CLAIMED]), end)
        seqs = list(range(end - k + 1, end + 1))
        slots = [s % self.capacity for s in seqs]
        gens = [2 * s + 2 for s in seqs]
        self._leases += 1
        lease = PairLease(self, slots, gens, skipped)
        return lease

    def _view(self, images: np.ndarray, slot: int) -> np.ndarray:
        view = images[slot]
        view.flags.writeable = False
        return view

    # ------------------------------------------------------------------ state

    def stats(self) -> RingStats:
        """Counters: pairs written, backlog, overwrites of pairs no window ended on (after
        :meth:`close`, those it had then: the final report reads them)."""
        if self._header is None:
            return self._final
        written = int(self._header[_HEAD])
        claimed = int(self._header[_CLAIMED])
        backlog = max(0, min(self.capacity, written - 1 - claimed))
        return RingStats(self.capacity, written, backlog, int(self._header[_OVERWRITES]),
                         claimed)

    @property
    def outstanding_leases(self) -> int:
        """Leases of this process not yet released."""
        return self._leases

    def close(self) -> None:
        """Detach from the shared memory (views become invalid)."""
        self._final = self.stats()
        self._header = self._meta = self._left = self._right = None  # type: ignore[assignment]
        self._shm.close()

    def unlink(self) -> None:
        """Free the shared memory (creator only, after every process detached)."""
        if not self._owner:
            raise RuntimeError("only the creator of a ring unlinks it")
        self._shm.unlink()

    def __enter__(self) -> PairRing:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
        if self._owner:
            self.unlink()
