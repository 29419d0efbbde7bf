"""The recorder's files: naming, listing, and one open MCAP file.

``ogiflow-<UTC start>-<sequence>.mcap.active`` while open; on close the summary is written, the
file fsynced and renamed to ``.mcap``. A ``.active`` file left behind was cut by a crash (or
by a full disk): :func:`appliance.recording.recovery.recover_unfinished` rewrites it.
"""

from __future__ import annotations

import os
import re
import socket
import time
from collections.abc import Callable, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import IO

from mcap.writer import CompressionType, Writer

from appliance import __version__
from appliance.config import RecordingConfig
from appliance.recording.schemas import MessageSchema

__all__ = ["FILE_PATTERN", "ChannelTable", "OpenFile", "closed_files", "new_path",
           "unfinished_files"]

#: Names of the appliance's own recordings (closed, or still open with ``.active``).
FILE_PATTERN = re.compile(r"^ogiflow-(\d{8}T\d{6}\d{3}Z)-(\d{4,})\.mcap(\.active)?$")

COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
               "none": CompressionType.NONE}


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


def new_path(directory: Path, sequence: int) -> Path:
    """A fresh ``.mcap.active`` path in ``directory`` with file number ``sequence``."""
    now = datetime.now(timezone.utc)
    stamp = now.strftime("%Y%m%dT%H%M%S") + f"{now.microsecond // 1000:03d}Z"
    return directory / f"ogiflow-{stamp}-{sequence:04d}.mcap.active"


class ChannelTable:
    """Schema and channel ids of one MCAP ``Writer``, each registered on first use (the
    recorder's files and the reprocess sink share it)."""

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


class OpenFile:
    """One open MCAP file and its per-file registrations."""

    def __init__(self, path: Path, rc: RecordingConfig, metadata: Mapping[str, Mapping[str, str]],
                 sequence: int, clock: Callable[[], float] = time.monotonic) -> None:
        self.path = path
        self.stream: IO[bytes] = open(path, "xb")  # closed in close()
        self.writer = Writer(self.stream, chunk_size=rc.chunk_kb * 1024,
                             compression=COMPRESSION[rc.compression])
        self.writer.start(profile="", library=f"ogiflow {__version__}")
        self.table = ChannelTable(self.writer)
        self._clock = clock
        self.opened_mono = clock()
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
        self.last_fsync = self._clock()

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
