"""Reading the appliance's own MCAP logs message by message, tolerating a cut end.

A file cut by a crash or power loss fails the seeking (indexed) reader, but the
non-seeking reader returns every completed chunk (docs/design.md). Readers here stop at the
cut, remember that they did (``truncated``), and let the caller say so to the user.
"""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mcap.exceptions import InvalidMagic, McapError
from mcap.reader import NonSeekingReader
from mcap.records import Chunk, DataEnd, Message, Metadata
from mcap.stream_reader import StreamReader
from zstandard import ZstdError


class _Bounded:
    """A file that refuses reads longer than what is left: a corrupt record length must
    end the read (the mcap reader then raises EndOfFile), not allocate terabytes."""

    def __init__(self, f: Any, size: int) -> None:
        self._f = f
        self._size = size

    def read(self, n: int = -1) -> bytes:
        if n is not None and n > self._size - self._f.tell():
            return b""
        return self._f.read(n)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


class LogReader:
    """Iterate ``(topic, log_time_ns, publish_time_ns, payload)`` in file order.

    Attributes
    ----------
    truncated : bool
        After iteration: the file ended inside a record (everything before was read).
    bytes_read : int
        Position in the file, for progress bars.
    """

    def __init__(self, path: str | Path, topics: Iterable[str] | None = None) -> None:
        self.path = Path(path)
        self.topics = None if topics is None else list(topics)
        self.truncated = False
        self.size = self.path.stat().st_size if self.path.exists() else 0
        self._stream: Any = None

    @property
    def bytes_read(self) -> int:
        return 0 if self._stream is None or self._stream.closed else self._stream.tell()

    def __iter__(self) -> Iterator[tuple[str, int, int, bytes]]:
        try:
            self._stream = open(self.path, "rb")
        except OSError as exc:
            raise ValueError(f"cannot open {self.path}: {exc.strerror}") from None
        try:
            reader = NonSeekingReader(_Bounded(self._stream, self.size))
            try:
                for _schema, channel, msg in reader.iter_messages(topics=self.topics,
                                                                  log_time_order=False):
                    yield channel.topic, msg.log_time, msg.publish_time, msg.data
            except InvalidMagic:
                raise ValueError(f"{self.path}: not an MCAP file") from None
            except (McapError, struct.error, EOFError, zlib.error, ZstdError, RuntimeError,
                    UnicodeDecodeError, OverflowError):
                # Cut, or corrupt from here on (a flipped bit in a chunk or a length):
                # everything before was read. RuntimeError: lz4 on corrupt data.
                self.truncated = True
        finally:
            self._stream.close()


def iter_json(
    path: str | Path, topics: Iterable[str]
) -> tuple[LogReader, Iterator[tuple[str, Any]]]:
    """A :class:`LogReader` and an iterator of ``(topic, decoded JSON)`` over it."""
    reader = LogReader(path, topics)

    def gen() -> Iterator[tuple[str, Any]]:
        for topic, _log, _pub, data in reader:
            yield topic, json.loads(data)

    return reader, gen()


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """Metadata records of an appliance log (written at the start of every file).

    Reads records until the first data chunk, so it is cheap on large files and works on
    files cut by a crash.
    """
    out: dict[str, dict[str, str]] = {}
    try:
        with open(path, "rb") as f:
            for record in StreamReader(f, skip_magic=False).records:
                if isinstance(record, Metadata):
                    out[record.name] = dict(record.metadata)
                elif isinstance(record, (Chunk, Message, DataEnd)):
                    break
    except OSError as exc:
        raise ValueError(f"cannot open {path}: {exc.strerror}") from None
    except InvalidMagic:
        raise ValueError(f"{path}: not an MCAP file") from None
    except (McapError, struct.error, EOFError):
        pass
    return out
