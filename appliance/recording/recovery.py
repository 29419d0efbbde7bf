"""Rewrite an MCAP file cut by a crash into a valid, indexed one.

A file cut by SIGKILL or a power loss has no summary section and ends inside a record, so the
seeking reader refuses it. Every chunk that reached the disk completely is still intact (each
carries its length and a CRC of its uncompressed data); only the chunk being built in memory
and a record cut at the tail are lost. :func:`recover` walks the records from the start,
keeps every complete chunk whose CRC matches, the metadata and attachment records, and
writes them into a new file with a full summary (chunk and message indexes, statistics).
"""

from __future__ import annotations

import io
import logging
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from appliance.recording.files import unfinished_files

__all__ = ["MAGIC", "RecoveryReport", "default_output", "recover", "recover_unfinished"]

MAGIC = bytes([137, 77, 67, 65, 80, 48, 13, 10])
_RECORD_HEAD = struct.Struct("<BQ")


@dataclass
class RecoveryReport:
    """What :func:`recover` kept and lost.

    Attributes
    ----------
    chunks_kept, messages_kept
        Complete chunks (CRC checked) and the messages in them, plus messages stored outside
        chunks.
    chunks_corrupt
        Complete-length chunks whose data failed to decompress or failed the CRC (skipped).
    metadata_kept, attachments_kept
        Metadata and attachment records copied.
    truncated_bytes
        Bytes at the tail that did not form a complete record (the cut).
    input_was_complete
        True when the input already ended with a footer (nothing was cut).
    """

    source: Path
    output: Path
    chunks_kept: int = 0
    messages_kept: int = 0
    chunks_corrupt: int = 0
    #: Records outside chunks that could not be parsed (skipped).
    records_corrupt: int = 0
    metadata_kept: int = 0
    attachments_kept: int = 0
    truncated_bytes: int = 0
    input_was_complete: bool = False

    def summary(self) -> str:
        """One human line."""
        state = "complete input" if self.input_was_complete else (
            f"cut input, {self.truncated_bytes} trailing bytes dropped")
        return (f"{self.output}: kept {self.messages_kept} messages in {self.chunks_kept} "
                f"chunks, {self.metadata_kept} metadata, {self.attachments_kept} attachments; "
                f"{self.chunks_corrupt} corrupt chunks and {self.records_corrupt} corrupt "
                f"records skipped; {state}")


def default_output(source: Path) -> Path:
    """``x.mcap.active`` -> ``x.mcap``; ``x.mcap`` -> ``x.recovered.mcap``."""
    name = source.name
    if name.endswith(".mcap.active"):
        return source.with_name(name.removesuffix(".active"))
    if name.endswith(".mcap"):
        return source.with_name(name.removesuffix(".mcap") + ".recovered.mcap")
    return source.with_name(name + ".recovered.mcap")


def _parse(record_type: type, body: bytes, length: int | None = None) -> object:
    stream = ReadDataStream(io.BytesIO(body))
    if record_type is Message:
        return Message.read(stream, length)
    return record_type.read(stream)


class _Rewriter:
    """Copies schemas/channels/messages into a new writer, renumbering ids."""

    def __init__(self, out: BinaryIO, compression: CompressionType) -> None:
        self.writer = Writer(out, compression=compression)
        self.schemas_in: dict[int, Schema] = {}
        self.channels_in: dict[int, Channel] = {}
        self.schema_map: dict[int, int] = {}
        self.channel_map: dict[int, int] = {}
        self.started = False

    def start(self, header: Header | None) -> None:
        profile = header.profile if header else ""
        library = header.library if header else "ogiflow recover"
        self.writer.start(profile=profile, library=library)
        self.started = True

    def add(self, record: object) -> int:
        """Add one data record; returns 1 for a written message, else 0."""
        if isinstance(record, Schema):
            self.schemas_in[record.id] = record
        elif isinstance(record, Channel):
            self.channels_in[record.id] = record
        elif isinstance(record, Message):
            return self._message(record)
        return 0

    def _message(self, msg: Message) -> int:
        cid = self.channel_map.get(msg.channel_id)
        if cid is None:
            ch = self.channels_in.get(msg.channel_id)
            if ch is None:
                return 0  # channel record lost with an earlier corrupt chunk
            sid = 0
            if ch.schema_id != 0:
                sid = self.schema_map.get(ch.schema_id, 0)
                if sid == 0:
                    sc = self.schemas_in.get(ch.schema_id)
                    if sc is None:
                        return 0
                    sid = self.writer.register_schema(sc.name, sc.encoding, sc.data)
                    self.schema_map[ch.schema_id] = sid
            cid = self.writer.register_channel(ch.topic, ch.message_encoding, sid,
                                               dict(ch.metadata))
            self.channel_map[msg.channel_id] = cid
        self.writer.add_message(cid, msg.log_time, msg.data, msg.publish_time, msg.sequence)
        return 1


#: What a record with flipped bits can raise while it is parsed or decompressed
#: (RuntimeError: lz4.frame on corrupt data).
_CORRUPT = (McapError, ValueError, zlib.error, struct.error, EOFError, zstandard.ZstdError,
            RuntimeError, UnicodeDecodeError, IndexError, KeyError, OverflowError, MemoryError)


def _copy(rw: _Rewriter, opcode: int, body: bytes, length: int,
          report: RecoveryReport) -> None:
    """Copy one data record into the rewriter (raises one of ``_CORRUPT`` when broken)."""
    if opcode == Opcode.CHUNK:
        chunk: Chunk = _parse(Chunk, body)  # type: ignore[assignment]
        try:
            records = breakup_chunk(chunk, validate_crc=True)
        except _CORRUPT:
            report.chunks_corrupt += 1
            return
        report.chunks_kept += 1
        for rec in records:
            report.messages_kept += rw.add(rec)
    elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):
        rtype = {Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
                 Opcode.MESSAGE: Message}[opcode]
        report.messages_kept += rw.add(_parse(rtype, body, length))
    elif opcode == Opcode.METADATA:
        md: Metadata = _parse(Metadata, body)  # type: ignore[assignment]
        rw.writer.add_metadata(md.name, dict(md.metadata))
        report.metadata_kept += 1
    elif opcode == Opcode.ATTACHMENT:
        at: Attachment = _parse(Attachment, body)  # type: ignore[assignment]
        rw.writer.add_attachment(at.create_time, at.log_time, at.name, at.media_type,
                                 at.data)
        report.attachments_kept += 1


def recover(source: str | Path, output: str | Path | None = None, *,
            overwrite: bool = False) -> RecoveryReport:
    """Rewrite ``source`` (possibly cut) into a valid indexed MCAP file ``output``.

    Parameters
    ----------
    source
        The cut (or complete) MCAP file; never modified.
    output
        Where to write; default :func:`default_output`.
    overwrite
        Replace an existing ``output``.

    Returns
    -------
    RecoveryReport

    Raises
    ------
    ValueError
        ``source`` is not an MCAP file, or ``output`` exists (without ``overwrite``) or is the
        source itself.
    """
    src = Path(source)
    dst = Path(output) if output is not None else default_output(src)
    if dst.resolve() == src.resolve():
        raise ValueError(f"recover: output {dst} is the input file")
    if dst.exists() and not overwrite:
        raise ValueError(f"recover: output {dst} exists (use --force to replace it)")
    report = RecoveryReport(source=src, output=dst)
    tmp = dst.with_name(dst.name + ".tmp")
    try:
        with open(src, "rb") as fin:
            if fin.read(len(MAGIC)) != MAGIC:
                raise ValueError(f"recover: {src} is not an MCAP file (bad magic)")
            with open(tmp, "wb") as fout:
                rw: _Rewriter | None = None
                header: Header | None = None
                compression = CompressionType.ZSTD
                size = os.fstat(fin.fileno()).st_size
                while True:
                    head = fin.read(_RECORD_HEAD.size)
                    if len(head) < _RECORD_HEAD.size:
                        report.truncated_bytes += len(head)
                        break
                    opcode, length = _RECORD_HEAD.unpack(head)
                    if length > size - fin.tell():  # cut, or a corrupt length field:
                        # never allocate what the file cannot hold
                        report.truncated_bytes += size - fin.tell() + len(head)
                        break
                    body = fin.read(length)
                    if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                        report.input_was_complete = True
                        break
                    if opcode == Opcode.HEADER:
                        try:
                            header = _parse(Header, body)  # type: ignore[assignment]
                        except _CORRUPT:
                            report.records_corrupt += 1
                        continue
                    if rw is None:
                        rw = _Rewriter(fout, compression)
                        rw.start(header)
                    try:
                        _copy(rw, opcode, body, length, report)
                    except _CORRUPT:
                        report.records_corrupt += 1
                    # Indexes and other records are rebuilt by the writer or not needed.
                if rw is None:
                    rw = _Rewriter(fout, compression)
                    rw.start(header)
                rw.writer.finish()
                fout.flush()
    except BaseException:
        tmp.unlink(missing_ok=True)  # no half-written output
        raise
    tmp.replace(dst)
    return report


def recover_unfinished(directory: str | Path, *, remove_source: bool = True
                       ) -> list[RecoveryReport]:
    """Recover every ``ogiflow-*.mcap.active`` file left in ``directory`` by a crash.

    Call at daemon start, before the recorder opens its first file. Each cut file becomes the
    ``.mcap`` it would have been. The cut original is removed only after the output has been
    read back with the seeking reader (its complete chunks are all in the output; the cut
    tail cannot be decoded anyway); with ``remove_source=False`` it is kept.

    Returns
    -------
    list of RecoveryReport
        One per recovered file, oldest first. A file that cannot be recovered is left in place
        and logged; it does not stop the others.
    """
    log = logging.getLogger("ogiflow.recovery")
    reports = []
    for path in unfinished_files(Path(directory)):
        try:
            report = recover(path, default_output(path))
            with open(report.output, "rb") as f:
                summary = make_reader(f).get_summary()
            if summary is None or summary.statistics is None or (
                    summary.statistics.message_count != report.messages_kept):
                raise ValueError(f"{report.output}: read-back does not match what was written")
        except (OSError, ValueError) as exc:
            log.error("could not recover %s: %s", path, exc)
            continue
        if remove_source:
            path.unlink()
        log.warning("recovered %s", report.summary())
        reports.append(report)
    return reports
