"""Synchronous MCAP output for reprocessing: one file, written in place, finished atomically.

Offline there is no acquisition to protect, so results are written directly (no queue,
nothing can be dropped). The file grows as ``.<name>.part`` and becomes ``<name>`` only
when :meth:`McapSink.close` has written the summary: a file under the final name is always
complete and valid, and an interrupted run leaves at most a ``.part`` file (ignored and
overwritten on the next run). :meth:`McapSink.close` is also what ``ogiflow replay`` calls on
Ctrl-C, so what was processed so far ends up in a valid file.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from appliance import __version__
from appliance.recording.files import ChannelTable
from appliance.recording.schemas import WIND_SAMPLE, MessageSchema, encode_json


class McapSink:
    """An MCAP file with ``record()`` like :class:`~appliance.recording.recorder.Recorder`.

    Parameters
    ----------
    path : Path
        Final file name; the file is written as ``.<name>.part`` beside it until closed.
    metadata : mapping
        Metadata records ``{name: {key: value}}`` written first.
    chunk_size : int
        Uncompressed chunk size in bytes (the appliance's recorder uses 1 MiB too).
    """

    def __init__(self, path: Path, metadata: Mapping[str, Mapping[str, str]], *,
                 chunk_size: int = 1024 * 1024) -> None:
        self.path = Path(path)
        self.part = self.path.with_name(f".{self.path.name}.{os.getpid()}.part")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._stream = open(self.part, "wb")  # closed in close() or abort()
        self._writer = Writer(self._stream, chunk_size=chunk_size,
                              compression=CompressionType.ZSTD)
        self._writer.start(profile="", library=f"ogiflow {__version__}")
        for name, data in metadata.items():
            self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})
        self._table = ChannelTable(self._writer)
        self.messages = 0

    def record(self, topic: str, schema: MessageSchema, payload: bytes, log_time_ns: int,
               publish_time_ns: int | None = None) -> bool:
        """Write one message now (registers its schema and channel on first use)."""
        cid = self._table.channel_for(topic, schema)
        self._writer.add_message(cid, log_time=int(log_time_ns), data=payload,
                                 publish_time=int(publish_time_ns if publish_time_ns is not None
                                                  else log_time_ns))
        self.messages += 1
        return True

    def record_wind(self, samples: Iterable[Mapping[str, Any]], wall_offset_ns: int) -> None:
        """Copy raw wind samples (``/wind/raw``) as the appliance recorded them."""
        for m in samples:
            mono = int(m["t_mono_ns"])
            self.record("/wind/raw", WIND_SAMPLE, encode_json(WIND_SAMPLE, m, validate=False),
                        mono + wall_offset_ns, mono)

    def copy_from(self, path: Path) -> int:
        """Copy every message of another (complete) MCAP file; returns how many."""
        n = 0
        with open(path, "rb") as f:
            for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
                ms = MessageSchema(schema.name, schema.encoding, schema.data,
                                   channel.message_encoding) if schema is not None else None
                if ms is None:
                    raise ValueError(f"{path}: channel {channel.topic} has no schema")
                self.record(channel.topic, ms, message.data, message.log_time,
                            message.publish_time)
                n += 1
        return n

    def close(self) -> Path:
        """Finish (summary and index), fsync, and move to the final name."""
        try:
            self._writer.finish()
            self._stream.flush()
            os.fsync(self._stream.fileno())
        finally:
            self._stream.close()
        os.replace(self.part, self.path)
        return self.path

    def abort(self) -> None:
        """Drop the unfinished file."""
        self._stream.close()
        self.part.unlink(missing_ok=True)
