"""MCAP recorder: one writer thread fed by a bounded queue that never blocks its producers.

Producers (camera threads, pairer, anemometer thread, result collector, health) call
:meth:`Recorder.record`, which only puts the message on a queue and returns at once. When the
queue is full (by message count or by queued bytes) the message is dropped and counted per
topic: acquisition never waits for the disk. The default queue holds 4096 messages / 256 MB,
which is > 25 s of raw 2 x 30 Hz 320x240 uint16 frames; the writer itself needs ~3 ms per
pair with zstd (docs/design.md), so the queue stays nearly empty in normal operation.

The writer thread owns the files (naming and the open file: :mod:`.files`):

- Rotation by size (``rotate_mb``) and by time (``rotate_s``); every new file registers its
  schemas and channels again and carries the metadata records again.
- Disk quota (``quota_gb``): after each rotation and at start, the oldest *closed* files of our
  own naming pattern are deleted until the total (including the open file) fits (:mod:`.quota`).
- Every ``fsync_s`` the open chunk is closed and the file fsynced: a power cut loses at most
  that much.
- A write error (a full disk, an I/O error) *pauses* recording: the file is finished if it
  can be, else left ``.active``; messages are dropped and counted; :meth:`Recorder.stats`
  says ``paused`` and why. Once ``MIN_FREE_BYTES`` are free again (checked every
  ``RETRY_S``) a cut file is recovered into a readable one and recording resumes in a new
  file. The daemon keeps running throughout.
"""

from __future__ import annotations

import errno
import logging
import queue
import shutil
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from appliance.config import RecordingConfig
from appliance.recording.files import (
    COMPRESSION,
    FILE_PATTERN,
    OpenFile,
    closed_files,
    new_path,
    unfinished_files,
)
from appliance.recording.quota import delete_oldest_over_quota
from appliance.recording.recovery import recover_unfinished
from appliance.recording.schemas import MessageSchema
from appliance.threads import NamedThread

__all__ = [
    "FILE_PATTERN",
    "Recorder",
    "RecorderStats",
    "closed_files",
    "unfinished_files",
]

log = logging.getLogger("ogiflow.recorder")

#: Bound on queued payload bytes (in addition to the message count).
DEFAULT_QUEUE_BYTES = 256 * 1024 * 1024
#: Free space needed before a paused recorder opens a new file, bytes.
MIN_FREE_BYTES = 64 * 1024 * 1024
#: Seconds between attempts to resume a paused recording.
RETRY_S = 1.0


@dataclass
class RecorderStats:
    """Counters of the recorder (a copy; safe to read from any thread)."""

    messages_written: int = 0
    messages_dropped: int = 0
    drops_by_topic: dict[str, int] = field(default_factory=dict)
    bytes_written: int = 0
    files_closed: int = 0
    files_deleted: int = 0
    files_recovered: int = 0
    #: Messages that were in the open chunk of a file cut by a write error (not recoverable).
    messages_lost_in_cut_files: int = 0
    write_errors: int = 0
    last_error: str = ""
    current_file: str = ""
    queue_depth: int = 0
    queue_peak: int = 0
    #: True while a write error keeps the recorder from writing (messages are dropped).
    paused: bool = False


@dataclass
class _Item:
    topic: str
    schema: MessageSchema
    payload: bytes
    log_time_ns: int
    publish_time_ns: int


class Recorder:
    """Record messages of any topic to rotating MCAP files from one writer thread.

    Parameters
    ----------
    rc
        The ``recording`` section of the configuration.
    metadata
        Extra metadata records written at the start of every file, ``{name: {key: value}}``
        (see :func:`appliance.recording.metadata.file_metadata`).
    queue_bytes
        Bound on queued payload bytes (default 256 MB), besides ``rc.queue_size`` messages.
    on_error
        Called with the text of each write error (from the writer thread).
    clock
        Monotonic seconds for rotation, fsync and retry times (tests inject one).

    Use as a context manager or call :meth:`start` and :meth:`close`.
    """

    def __init__(self, rc: RecordingConfig,
                 metadata: Mapping[str, Mapping[str, str]] | None = None,
                 *, queue_bytes: int = DEFAULT_QUEUE_BYTES,
                 on_error: Callable[[str], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if rc.compression not in COMPRESSION:
            raise ValueError(f"recording.compression: unknown {rc.compression!r}")
        self._rc = rc
        self._dir = Path(rc.dir)
        self._metadata = {k: dict(v) for k, v in (metadata or {}).items()}
        self._queue: queue.SimpleQueue[_Item] = queue.SimpleQueue()
        self._max_items = rc.queue_size
        self._max_bytes = queue_bytes
        self._lock = threading.Lock()
        self._queued_items = 0
        self._queued_bytes = 0
        self._stats = RecorderStats()
        self._drops: Counter[str] = Counter()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._file: OpenFile | None = None
        self._sequence = 0
        self._retry_at = 0.0
        self._on_error = on_error
        self._clock = clock
        self._accepting = False
        self._cut: dict[Path, int] = {}  # file cut by a write error -> messages written to it

    # ------------------------------------------------------------------ producer side

    def record(self, topic: str, schema: MessageSchema, payload: bytes, log_time_ns: int,
               publish_time_ns: int | None = None) -> bool:
        """Queue one message for writing; never blocks.

        Parameters
        ----------
        topic
            Channel topic, e.g. ``/cam/left/raw`` (see :data:`appliance.recording.schemas.TOPICS`).
        schema
            Its schema; registered once per file on first use.
        payload
            Serialized message (protobuf or JSON bytes, per ``schema.message_encoding``).
        log_time_ns, publish_time_ns
            MCAP log time (when recorded; UNIX ns) and publish time (when captured; defaults
            to ``log_time_ns``).

        Returns
        -------
        bool
            False when the message was dropped (queue full or recorder closed); counted.
        """
        size = len(payload)
        with self._lock:
            if (not self._accepting or self._queued_items >= self._max_items
                    or self._queued_bytes + size > self._max_bytes):
                self._drops[topic] += 1
                return False
            self._queued_items += 1
            self._queued_bytes += size
            if self._queued_items > self._stats.queue_peak:
                self._stats.queue_peak = self._queued_items
        self._queue.put(_Item(topic, schema, payload, int(log_time_ns),
                              int(publish_time_ns if publish_time_ns is not None
                                  else log_time_ns)))
        return True

    def stats(self) -> RecorderStats:
        """A snapshot of the counters."""
        with self._lock:
            s = RecorderStats(**{k: getattr(self._stats, k) for k in
                                 self._stats.__dataclass_fields__})
            s.drops_by_topic = dict(self._drops)
            s.messages_dropped = sum(self._drops.values())
            s.queue_depth = self._queued_items
        return s

    @property
    def current_file(self) -> Path | None:
        """Path of the file being written (``.active``), if any."""
        f = self._file
        return f.path if f is not None else None

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> Recorder:
        """Create the directory, apply the quota, open the first file and start the thread.

        Raises
        ------
        OSError
            When the directory cannot be created or the first file cannot be opened: a
            recorder that cannot record must fail at start, not silently later.
        """
        self._dir.mkdir(parents=True, exist_ok=True)
        self._open_new()
        self._enforce_quota()
        self._accepting = True
        self._thread = NamedThread(target=self._run, name="mcap-recorder", daemon=True)
        self._thread.start()
        return self

    def close(self, timeout: float = 5.0) -> bool:
        """Stop accepting, write what is queued, finish the file. Returns False on timeout."""
        with self._lock:
            self._accepting = False
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.error("recorder: writer did not finish within %.1f s", timeout)
                return False
        elif self._file is not None:
            self._close_file()
        return True

    def __enter__(self) -> Recorder:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ writer thread

    def _run(self) -> None:
        tick = min(0.2, self._rc.fsync_s / 2)
        while True:
            try:
                item: _Item | None = self._queue.get(timeout=tick)
            except queue.Empty:
                item = None
                if self._stop.is_set():
                    break
            try:
                if item is not None:
                    with self._lock:
                        self._queued_items -= 1
                        self._queued_bytes -= len(item.payload)
                    self._write(item)
                self._housekeeping()
            except Exception as exc:  # never let the writer thread die: count, log, go on
                log.exception("recorder: unexpected error")
                self._pause(f"unexpected {type(exc).__name__}: {exc}")
                if item is not None:
                    self._drop(item.topic)
        if self._file is not None:
            try:
                self._close_file()
            except OSError as exc:
                self._pause(f"closing {self._file.path.name if self._file else ''}: {exc}")

    def _drop(self, topic: str) -> None:
        with self._lock:
            self._drops[topic] += 1

    def _write(self, item: _Item) -> None:
        if self._file is None and not self._resume():
            self._drop(item.topic)
            return
        f = self._file
        assert f is not None
        try:
            cid = f.channel_for(item.topic, item.schema)
            f.writer.add_message(cid, item.log_time_ns, item.payload, item.publish_time_ns,
                                 sequence=f.messages)
            f.messages += 1
            with self._lock:
                self._stats.messages_written += 1
        except OSError as exc:
            self._drop(item.topic)
            self._pause(f"writing {f.path.name}: {_describe(exc)}")

    def _housekeeping(self) -> None:
        f = self._file
        if f is None:
            return
        now = self._clock()
        try:
            if (f.size() >= self._rc.rotate_mb * 1e6
                    or now - f.opened_mono >= self._rc.rotate_s):
                self._close_file()
                self._open_new()
                self._enforce_quota()
            elif now - f.last_fsync >= self._rc.fsync_s:
                f.sync()
        except OSError as exc:
            self._pause(f"rotating/syncing {f.path.name}: {_describe(exc)}")

    # ------------------------------------------------------------------ pause / resume

    def _pause(self, text: str) -> None:
        """Stop writing after an error: finish the file if possible, else leave it cut
        (``.active``) for :meth:`_resume` to recover; retry after ``RETRY_S``."""
        with self._lock:
            self._stats.write_errors += 1
            self._stats.last_error = text
            self._stats.paused = True
            self._stats.current_file = ""
        log.error("recorder: %s; recording paused", text)
        if self._on_error is not None:
            self._on_error(text)
        f, self._file = self._file, None
        self._retry_at = self._clock() + RETRY_S
        if f is None:
            return
        try:
            f.close()  # a full disk may still take the summary (it is small)
        except (OSError, ValueError):
            self._cut[f.path] = f.messages
            try:
                f.stream.close()
            except OSError:
                pass

    def _resume(self) -> bool:
        """While paused: once space is back, recover cut files and open a new one."""
        now = self._clock()
        if now < self._retry_at:
            return False
        self._retry_at = now + RETRY_S
        try:
            if shutil.disk_usage(self._dir).free < MIN_FREE_BYTES:
                return False
            self._recover_cut_files()
            self._open_new()
        except OSError as exc:
            with self._lock:
                self._stats.last_error = f"cannot resume in {self._dir}: {_describe(exc)}"
            return False
        with self._lock:
            self._stats.paused = False
        log.warning("recorder: space is back; recording resumed in %s", self._file.path.name
                    if self._file else "?")
        return True

    def _recover_cut_files(self) -> None:
        reports = recover_unfinished(self._dir)
        lost = sum(self._cut.pop(r.source, r.messages_kept) - r.messages_kept for r in reports)
        with self._lock:
            self._stats.files_recovered += len(reports)
            self._stats.messages_lost_in_cut_files += lost

    # ------------------------------------------------------------------ files

    def _open_new(self) -> None:
        while True:
            self._sequence += 1
            path = new_path(self._dir, self._sequence)
            if not path.exists() and not path.with_name(path.name[:-7]).exists():
                break
        self._file = OpenFile(path, self._rc, self._metadata, self._sequence, self._clock)
        with self._lock:
            self._stats.current_file = str(path)
        log.info("recording to %s", path)

    def _close_file(self) -> None:
        f = self._file
        self._file = None
        if f is None:
            return
        final = f.close()
        size = final.stat().st_size
        with self._lock:
            self._stats.files_closed += 1
            self._stats.bytes_written += size
            self._stats.current_file = ""
        log.info("closed %s (%d messages, %.1f MB)", final.name, f.messages, size / 1e6)

    def _enforce_quota(self) -> None:
        if self._rc.quota_gb is None:
            return
        open_size = self._file.size() if self._file is not None else 0
        deleted = delete_oldest_over_quota(self._dir, self._rc.quota_gb, open_size)
        with self._lock:
            self._stats.files_deleted += deleted


def _describe(exc: OSError) -> str:
    name = errno.errorcode.get(exc.errno or 0, "")
    return f"{exc} ({name})" if name and name not in str(exc) else str(exc)
