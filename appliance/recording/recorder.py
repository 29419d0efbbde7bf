"""MCAP recorder: one writer thread fed by a bounded queue that never blocks its producers.

Producers (camera threads, pairer, anemometer thread, result collector, health) call
:meth:`Recorder.record`, which only puts the message on a queue and returns at once. When the
queue is full (by message count or by queued bytes) the message is dropped and counted per
topic: acquisition never waits for the disk. The default queue holds 4096 messages / 256 MB,
which is > 25 s of raw 2 x 30 Hz 320x240 uint16 frames; the writer itself needs ~3 ms per
pair with zstd (DESIGN.md), so the queue stays nearly empty in normal operation.

The writer thread owns the files:

- ``ogiflow-<UTC start>-<sequence>.mcap.active`` while open; on close the summary is written,
  the file fsynced and renamed to ``.mcap``. A ``.active`` file left behind was cut by a crash:
  ``ogiflow recover`` rewrites it (:func:`unfinished_files` lists them).
- Rotation by size (``rotate_mb``) and by time (``rotate_s``); every new file registers its
  schemas and channels again and carries the metadata records again.
- Disk quota (``quota_gb``): after each rotation and at start, the oldest *closed* files of our
  own naming pattern are deleted until the total (including the open file) fits.
- Every ``fsync_s`` the open chunk is closed and the file fsynced: a power cut loses at most
  that much.
- Metadata records in every file: ``recording`` (software version, host name, start time,
  file sequence) and whatever the caller passes (:func:`file_metadata` builds ``config`` with
  the YAML text of the effective configuration and ``calibration``).
"""

from __future__ import annotations

import logging
import os
import queue
import re
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType, Writer

from appliance import __version__
from appliance.config import RecordingConfig
from appliance.recording.schemas import MessageSchema

__all__ = [
    "FILE_PATTERN",
    "ChannelTable",
    "Recorder",
    "RecorderStats",
    "closed_files",
    "unfinished_files",
]

log = logging.getLogger("ogiflow.recorder")

#: Names of the appliance's own recordings (closed, or still open with ``.active``).
FILE_PATTERN = re.compile(r"^ogiflow-(\d{8}T\d{6}\d{3}Z)-(\d{4,})\.mcap(\.active)?$")

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}

#: Bound on queued payload bytes (in addition to the message count).
DEFAULT_QUEUE_BYTES = 256 * 1024 * 1024


def _file_key(path: Path) -> tuple[str, int]:
    m = FILE_PATTERN.match(path.name)
    assert m is not None
    return m.group(1), int(m.group(2))


def closed_files(directory: Path) -> list[Path]:
    """The appliance's closed recordings in ``directory``, oldest first."""
    if not directory.is_dir():
        return []
    found = [p for p in directory.iterdir()
             if FILE_PATTERN.match(p.name) and not p.name.endswith(".active") and p.is_file()]
    return sorted(found, key=_file_key)


def unfinished_files(directory: Path) -> list[Path]:
    """``.mcap.active`` files in ``directory``: recordings cut by a crash (oldest first).

    Call before starting a :class:`Recorder` on the same directory (it would not touch them,
    but they need ``ogiflow recover``).
    """
    if not directory.is_dir():
        return []
    found = [p for p in directory.iterdir() if FILE_PATTERN.match(p.name)
             and p.name.endswith(".active") and p.is_file()]
    return sorted(found, key=_file_key)


@dataclass
class RecorderStats:
    """Counters of the recorder (a copy; safe to read from any thread)."""

    messages_written: int = 0
    messages_dropped: int = 0
    drops_by_topic: dict[str, int] = field(default_factory=dict)
    bytes_written: int = 0
    files_closed: int = 0
    files_deleted: int = 0
    write_errors: int = 0
    last_error: str = ""
    current_file: str = ""
    queue_depth: int = 0
    queue_peak: int = 0


@dataclass
class _Item:
    topic: str
    schema: MessageSchema
    payload: bytes
    log_time_ns: int
    publish_time_ns: int


class ChannelTable:
    """Schema and channel ids of one MCAP ``Writer``, each registered on first use."""

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        self.schemas: dict[tuple[str, str, bytes], int] = {}
        self.channels: dict[tuple[str, int], int] = {}

    def channel_for(self, topic: str, schema: MessageSchema) -> int:
        skey = (schema.name, schema.encoding, schema.data)
        sid = self.schemas.get(skey)
        if sid is None:
            sid = self.writer.register_schema(schema.name, schema.encoding, schema.data)
            self.schemas[skey] = sid
        cid = self.channels.get((topic, sid))
        if cid is None:
            cid = self.writer.register_channel(topic, schema.message_encoding, sid)
            self.channels[(topic, sid)] = cid
        return cid


class _OpenFile:
    """One open MCAP file and its per-file registrations."""

    def __init__(self, path: Path, rc: RecordingConfig, metadata: Mapping[str, Mapping[str, str]],
                 sequence: int) -> None:
        self.path = path
        self.stream: IO[bytes] = open(path, "xb")  # closed in close()
        self.writer = Writer(self.stream, chunk_size=rc.chunk_kb * 1024,
                             compression=_COMPRESSION[rc.compression])
        self.writer.start(profile="", library=f"ogiflow {__version__}")
        self.table = ChannelTable(self.writer)
        self.opened_mono = time.monotonic()
        self.last_fsync = self.opened_mono
        self.messages = 0
        now = datetime.now(timezone.utc)
        self.writer.add_metadata("recording", {
            "software": "ogiflow",
            "software_version": __version__,
            "host": socket.gethostname(),
            "start_time_utc": now.isoformat(),
            "start_time_ns": str(time.time_ns()),
            "file_sequence": str(sequence),
        })
        for name, data in metadata.items():
            self.writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def channel_for(self, topic: str, schema: MessageSchema) -> int:
        return self.table.channel_for(topic, schema)

    def size(self) -> int:
        return self.stream.tell()

    def sync(self) -> None:
        """Close the open chunk, flush and fsync (data survives a power cut)."""
        # Writer.flush() (closes the open chunk) exists from mcap 1.6 on; pyproject asks for it.
        self.writer.flush()
        self.stream.flush()
        os.fsync(self.stream.fileno())
        self.last_fsync = time.monotonic()

    def close(self) -> Path:
        """Finish the file (summary, index), fsync, rename ``.active`` away; return final path."""
        try:
            self.writer.finish()
            self.stream.flush()
            os.fsync(self.stream.fileno())
        finally:
            self.stream.close()
        final = self.path.with_name(self.path.name.removesuffix(".active"))
        os.replace(self.path, final)
        _fsync_dir(final.parent)
        return final


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some file systems refuse fsync on directories; the rename is still done
    finally:
        os.close(fd)


class Recorder:
    """Record messages of any topic to rotating MCAP files from one writer thread.

    Parameters
    ----------
    rc
        The ``recording`` section of the configuration.
    metadata
        Extra metadata records written at the start of every file, ``{name: {key: value}}``
        (see :func:`file_metadata`).
    queue_bytes
        Bound on queued payload bytes (default 256 MB), besides ``rc.queue_size`` messages.

    Use as a context manager or call :meth:`start` and :meth:`close`.
    """

    def __init__(self, rc: RecordingConfig,
                 metadata: Mapping[str, Mapping[str, str]] | None = None,
                 *, queue_bytes: int = DEFAULT_QUEUE_BYTES,
                 on_error: Callable[[str], None] | None = None) -> None:
        if rc.compression not in _COMPRESSION:
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
        self._file: _OpenFile | None = None
        self._sequence = 0
        self._retry_at = 0.0
        self._on_error = on_error
        self._accepting = False

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
        self._thread = threading.Thread(target=self._run, name="mcap-recorder", daemon=True)
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
                self._error(f"unexpected {type(exc).__name__}: {exc}")
                if item is not None:
                    with self._lock:
                        self._drops[item.topic] += 1
                self._abandon_file()
        if self._file is not None:
            self._close_file()

    def _write(self, item: _Item) -> None:
        if self._file is None:
            if time.monotonic() < self._retry_at:
                with self._lock:
                    self._drops[item.topic] += 1
                return
            try:
                self._open_new()
            except OSError as exc:
                self._error(f"cannot open a new recording in {self._dir}: {exc}")
                with self._lock:
                    self._drops[item.topic] += 1
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
            self._error(f"writing {f.path.name}: {exc}")
            with self._lock:
                self._drops[item.topic] += 1
            self._abandon_file()

    def _housekeeping(self) -> None:
        f = self._file
        if f is None:
            return
        now = time.monotonic()
        try:
            if (f.size() >= self._rc.rotate_mb * 1e6
                    or now - f.opened_mono >= self._rc.rotate_s):
                self._close_file()
                self._open_new()
                self._enforce_quota()
            elif now - f.last_fsync >= self._rc.fsync_s:
                f.sync()
        except OSError as exc:
            self._error(f"rotating/syncing {f.path.name}: {exc}")
            self._abandon_file()

    # ------------------------------------------------------------------ files

    def _new_path(self) -> Path:
        while True:
            now = datetime.now(timezone.utc)
            stamp = now.strftime("%Y%m%dT%H%M%S") + f"{now.microsecond // 1000:03d}Z"
            self._sequence += 1
            path = self._dir / f"ogiflow-{stamp}-{self._sequence:04d}.mcap.active"
            if not path.exists() and not path.with_name(path.name[:-7]).exists():
                return path

    def _open_new(self) -> None:
        path = self._new_path()
        self._file = _OpenFile(path, self._rc, self._metadata, self._sequence)
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

    def _abandon_file(self) -> None:
        """After a write error: drop the broken file handle (left as .active for recovery)."""
        f = self._file
        self._file = None
        self._retry_at = time.monotonic() + 1.0
        if f is not None:
            try:
                f.stream.close()
            except OSError:
                pass

    def _enforce_quota(self) -> None:
        if self._rc.quota_gb is None:
            return
        limit = self._rc.quota_gb * 1e9
        files = closed_files(self._dir)
        open_size = self._file.size() if self._file is not None else 0
        total = open_size + sum(p.stat().st_size for p in files)
        while total > limit and files:
            oldest = files.pop(0)
            size = oldest.stat().st_size
            try:
                oldest.unlink()
            except OSError as exc:
                self._error(f"quota: cannot delete {oldest.name}: {exc}")
                break
            total -= size
            with self._lock:
                self._stats.files_deleted += 1
            log.warning("quota %.3g GB: deleted oldest recording %s (%.1f MB)",
                        self._rc.quota_gb, oldest.name, size / 1e6)

    def _error(self, text: str) -> None:
        with self._lock:
            self._stats.write_errors += 1
            self._stats.last_error = text
        log.error("recorder: %s", text)
        if self._on_error is not None:
            self._on_error(text)


def recorder_stats_dict(stats: RecorderStats) -> dict[str, Any]:
    """Plain dict of a :class:`RecorderStats` (for health snapshots)."""
    return dict(stats.__dict__)
